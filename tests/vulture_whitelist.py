"""Names vulture (``tests/unit/test_dead_code.py``) would call unused, each with why it stays.

Read by vulture, never imported. A name that is not here and that vulture reports is dead code: delete it.
"""

# ruff: noqa
# fmt: off

# callbacks and attributes that libraries read
_.relinearizeSkip  # fmcwlog/backend/graph.py: gtsam reads it (an ISAM2Params attribute set by name)
file  # fmcwlog/cli/console.py: warnings.showwarning's signature
_.showwarning  # fmcwlog/cli/console.py: the warnings module calls it
import_carmen_cmd  # fmcwlog/cli/import_carmen.py: a click command, registered by its decorator
calibrate_cmd  # fmcwlog/cli/calibrate.py: a click command, named in fmcwlog.cli.COMMANDS and loaded by name
process_cmd  # fmcwlog/cli/process.py: a click command, named in fmcwlog.cli.COMMANDS and loaded by name
record_cmd  # fmcwlog/cli/record.py: a click command, named in fmcwlog.cli.COMMANDS and loaded by name
report_cmd  # fmcwlog/cli/report.py: a click command, named in fmcwlog.cli.COMMANDS and loaded by name
compare_cmd  # fmcwlog/cli/compare.py: a click command, named in fmcwlog.cli.COMMANDS and loaded by name
run_cmd  # fmcwlog/cli/run.py: a click command, named in fmcwlog.cli.COMMANDS and loaded by name
_.get_command  # fmcwlog/cli/__init__.py: click.Group's hook, which click calls
_.format_commands  # fmcwlog/cli/__init__.py: click.Group's hook, which click calls
_.current_item  # fmcwlog/cli/process.py: click's progress bar reads it
current_item  # fmcwlog/cli/progress.py: click's progress bar reads it
current_item  # fmcwlog/cli/progress.py: click's progress bar reads it
segments  # fmcwlog/frontend/methods.py: whether a method judges points moving; tests/test_layers.py checks it against types.SEGMENTING_METHODS
segments  # fmcwlog/frontend/methods.py: whether a method judges points moving; tests/test_layers.py checks it against types.SEGMENTING_METHODS
_.repeated_stamps  # fmcwlog/frontend/motion_prior.py: read by the tests and kept for callers: how many stamps repeated
_.repeated_stamps  # fmcwlog/frontend/motion_prior.py: read by the tests and kept for callers: how many stamps repeated
_.repeated_stamps  # fmcwlog/frontend/motion_prior.py: read by the tests and kept for callers: how many stamps repeated

# dataclass fields: part of a result or of a record serialised with dataclasses.asdict
residuals  # fmcwlog/backend/registration.py
duration_s  # fmcwlog/evaluation/fleet.py
distance_m  # fmcwlog/evaluation/fleet.py
distance_from  # fmcwlog/evaluation/fleet.py
ms_per_sweep  # fmcwlog/evaluation/fleet.py
feature_avg_rel_error_pct  # fmcwlog/evaluation/fleet.py
path_lengths  # fmcwlog/evaluation/metrics.py
true_m  # fmcwlog/evaluation/metrics.py
measured_m  # fmcwlog/evaluation/metrics.py
trans_mean_m  # fmcwlog/evaluation/relations.py
trans_std_m  # fmcwlog/evaluation/relations.py
rot_mean_deg  # fmcwlog/evaluation/relations.py
rot_std_deg  # fmcwlog/evaluation/relations.py
short_n  # fmcwlog/evaluation/relations.py
short_trans_mean_m  # fmcwlog/evaluation/relations.py
short_rot_mean_deg  # fmcwlog/evaluation/relations.py
long_n  # fmcwlog/evaluation/relations.py
long_trans_mean_m  # fmcwlog/evaluation/relations.py
long_rot_mean_deg  # fmcwlog/evaluation/relations.py
path_length_m  # fmcwlog/evaluation/relations.py
well_conditioned  # fmcwlog/frontend/egomotion.py
n_gmm_fits  # fmcwlog/frontend/icp.py
wheelbase  # fmcwlog/sim/config.py; describes the robot (rear-axle kinematics do not use it)

# library functions and properties for users and the tests' independent checks
sensor_velocity_from_base_twist  # fmcwlog/frontend/egomotion.py
base_twist_from_sensor_velocity  # fmcwlog/frontend/egomotion.py
_.keyframes  # fmcwlog/frontend/keyframe_map.py
integrate_arcs  # fmcwlog/frontend/odometry.py
UNITS  # fmcwlog/frontend/self_calibration.py
pointcloud_message  # fmcwlog/io/messages.py
pointcloud_columns  # fmcwlog/io/messages.py: a decoded PointCloud2's columns, checked (bench/, tests/; sweeps reads through its cached layout)
path_message  # fmcwlog/io/messages.py
find_correspondences  # fmcwlog/kernels/nearest.py
_.cell_of  # fmcwlog/kernels/occupancy.py
_.path_length  # fmcwlog/sim/movers.py
