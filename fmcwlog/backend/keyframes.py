"""The back end's nodes: front-end keyframes, one every ``node_distance`` m or ``node_angle_deg``,
and the odometry edge between two consecutive ones.

A node keeps what the front end made of its sweep: the pose in ``<method>/odom`` at the sweep's
stamp, the deskewed static points in base_link (full density: the final map is rebuilt from
them; in a temporary file once no local edge reads them, :class:`~fmcwlog.backend.point_store.PointStore`,
so that memory does not grow with the log), and the registration's covariance (``σ² H⁻¹`` of
the scan-to-map ICP, in the map frame).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry import between, rot2
from .params import BackendParams
from .point_store import PointStore


class Node:
    """index: position in the graph; stamp_ns: the sweep's stamp; frontend_pose: (3,) the front
    end's pose (m, m, rad); points: (N, 2) float32 static points in base_link (m), in memory or,
    once :meth:`spill` moved them, read back from a :class:`PointStore` (the same values);
    covariance: (3, 3) the registration's, in the map frame (m², rad²), None where none ran;
    path_m: distance travelled by then (m)."""

    __slots__ = ("index", "stamp_ns", "frontend_pose", "_points", "_store", "_where", "covariance", "path_m")

    def __init__(self, index: int, stamp_ns: int, frontend_pose: np.ndarray, points: np.ndarray,
                 covariance: np.ndarray | None, path_m: float):
        self.index, self.stamp_ns, self.frontend_pose = index, stamp_ns, frontend_pose
        self._points: np.ndarray | None = points
        self._store: PointStore | None = None
        self._where = (0, 0)
        self.covariance, self.path_m = covariance, path_m

    @property
    def points(self) -> np.ndarray:
        if self._points is not None:
            return self._points
        assert self._store is not None
        return self._store.get(self._where)

    def spill(self, store: PointStore) -> None:
        """Move the points into ``store`` (once); :attr:`points` reads them back."""
        if self._points is not None:
            self._where, self._store, self._points = store.put(self._points), store, None


class NodePoints(Sequence):
    """The points of ``nodes`` (each (N_i, 2) float32, base_link), read one node at a time where they
    are asked for: those in a :class:`PointStore` are not all brought back into memory at once."""

    def __init__(self, nodes: Sequence[Node]):
        self._nodes = nodes

    def __len__(self) -> int:
        return len(self._nodes)

    def __getitem__(self, i):  # an int only
        return self._nodes[i].points


def is_new_node(last: Node | None, pose: np.ndarray, p: BackendParams) -> bool:
    """Whether a keyframe at ``pose`` has moved far enough from the last node to become one."""
    if last is None:
        return True
    d = between(last.frontend_pose, pose)
    return bool(np.hypot(d[0], d[1]) >= p.node_distance or abs(d[2]) >= np.radians(p.node_angle_deg))


def to_local(covariance: np.ndarray, yaw: float) -> np.ndarray:
    """A covariance over (x, y of a parent frame, yaw) as one over (x, y of a frame turned by
    ``yaw``, yaw): gtsam's Pose2 tangent space of a relative pose whose rotation is ``yaw``."""
    a = np.eye(3)
    a[:2, :2] = rot2(yaw).T
    return a @ covariance @ a.T


_REGULARISER = np.diag([1e-4, 1e-4, 1.0])  # information of 100 m, 100 m, 1 rad: keeps a free axis invertible


def match_covariance(information: np.ndarray, pairs: int, relative: np.ndarray, p: BackendParams,
                     sigma_xy_floor: float, sigma_yaw_floor: float) -> np.ndarray:
    """Covariance (3, 3) of a scan match in gtsam's tangent space at its ``relative`` pose (3,),
    from the match's information ``information`` (3, 3; Σ JᵀJ over its ``pairs`` pairs).

    The residuals of one match are not independent (the same few corners and door jambs fix the
    along-wall position of every pair), so it is weighed as ``effective_pairs`` pairs of
    ``residual_sigma``; a weak regulariser keeps a free direction invertible, and the floors
    (m, rad) are added to the standard deviations' squares.
    """
    scale = min(1.0, p.effective_pairs / max(pairs, 1))
    cov = np.linalg.inv(information * scale / p.residual_sigma**2 + _REGULARISER)
    cov = cov + np.diag([sigma_xy_floor**2] * 2 + [sigma_yaw_floor**2])
    return to_local(cov, float(relative[2]))


def odometry_covariance(a: Node, b: Node, p: BackendParams) -> np.ndarray:
    """Covariance (3, 3) of the front end's motion from node ``a`` to ``b``, in ``a``'s frame.

    The front end drifts with the path: ``σ_xy = floor + k·d``, ``σ_yaw = floor + k·d + k'·|Δyaw|``
    (the ``odom_sigma_*`` parameters); the two registrations' covariances (``σ² H⁻¹``, which
    show the directions a scene leaves free, such as a corridor's axis) are added, turned into
    ``a``'s frame.
    """
    rel = between(a.frontend_pose, b.frontend_pose)
    d = float(np.hypot(rel[0], rel[1]))
    s_xy = p.odom_sigma_xy_floor + p.odom_sigma_xy_per_m * d
    s_yaw = p.odom_sigma_yaw_floor + p.odom_sigma_yaw_per_m * d + p.odom_sigma_yaw_per_rad * abs(float(rel[2]))
    cov = np.diag([s_xy**2, s_xy**2, s_yaw**2])
    for node in (a, b):
        if node.covariance is not None:
            cov = cov + to_local(node.covariance, float(a.frontend_pose[2]))
    return cov
