"""The pose-graph back end: verified loop closures for either front end.

Estimation, like :mod:`fmcwlog.frontend`: it reads only what a front end made of the sensor data
(never ground truth, never the simulator, never a file format; ``tests/test_layers.py`` checks
it). One module per idea:

- ``params``        :class:`BackendParams`, the ``backend`` table of a run's parameters
- ``keyframes``     nodes (front-end keyframes) and the odometry edge between two of them
- ``point_store``   the nodes' points kept in a temporary file until needed
- ``candidates``    loop-closure candidates: near in the estimate, far back along the path
- ``registration``  point-to-line ICP of a scan against a submap, with its information
- ``local_edges``   edges between nearby nodes, matched against each other
- ``verification``  correlative search, ICP, and the inlier, score and uniqueness tests
- ``graph``         the pose graph, optimised with gtsam under a Cauchy kernel on closures
- ``pipeline``      :class:`PoseGraphBackend`: the above, sweep by sweep, and the corrected outputs
"""

from __future__ import annotations

from .params import BackendParams
from .pipeline import BackendResult, PoseGraphBackend

__all__ = ["BackendParams", "BackendResult", "PoseGraphBackend"]
