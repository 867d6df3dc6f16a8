"""Names the log format fixes (docs/log-format.md): topics, metadata records and frames.

Names only: reading what is under ``/ground_truth/`` or in ``fmcwlog.world`` is
evaluation's business (:mod:`fmcwlog.evaluation.ground_truth`), never estimation's.
"""

POINTS_TOPIC = "/fmcw/points"
TICKS_TOPIC = "/wheel/ticks"
GT_ODOM_TOPIC = "/ground_truth/odom"
GT_LABELS_TOPIC = "/ground_truth/point_labels"
GT_TF_TOPIC = "/ground_truth/tf"  # the true pose as a transform map -> base_link, for viewers
GROUND_TRUTH_PREFIX = "/ground_truth/"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"

CALIBRATION_KEY = "fmcwlog.calibration"
WORLD_KEY = "fmcwlog.world"
SIM_KEY = "fmcwlog.sim"
IMPORT_KEY = "fmcwlog.import"

MAP_FRAME = "map"
BASE_FRAME = "base_link"
LIDAR_FRAME = "lidar"
# The true pose as a tree of its own on /tf (map -> ground_truth/base_link): a frame under ground_truth/
# is ground truth wherever it appears, and no estimate names or looks one up
GT_BASE_FRAME = "ground_truth/base_link"
