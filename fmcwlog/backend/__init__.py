"""The pose-graph back end: verified loop closures for either front end.

Estimation, like :mod:`fmcwlog.frontend`: it reads only what a front end made of the sensor data
(never ground truth, never the simulator; ``tests/test_layers.py`` checks it). One module per idea:

- ``params``        :class:`BackendParams`, nested in the front end's parameters as ``backend``
- ``keyframes``     nodes (front-end keyframes) and the odometry edge between two of them
- ``candidates``    loop-closure candidates: near in the estimate, far back along the path
- ``registration``  point-to-line ICP of a scan against a submap, with its information
- ``verification``  correlative search, ICP, and the inlier, score and uniqueness tests
- ``graph``         the pose graph, optimised with gtsam under a Cauchy kernel on closures
- ``pipeline``      :class:`PoseGraphBackend`: the above, sweep by sweep, and the corrected outputs
"""

from .params import BackendParams
from .pipeline import BackendResult, PoseGraphBackend

__all__ = ["BackendParams", "BackendResult", "PoseGraphBackend"]
