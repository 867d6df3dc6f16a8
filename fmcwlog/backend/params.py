"""The back end's parameters: nodes, odometry edges, loop-closure candidates, verification, kernel.

Nested in :class:`fmcwlog.frontend.params.FrontEndParams` as ``backend`` (``--set
backend.closure_radius=4``, a ``[backend]`` table in a config file), so ``run.json`` records
them with the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..frontend.correlative import CorrelativeParams
from .registration import LineICPParams


def _closure_search() -> CorrelativeParams:
    # Drift between a closure's two ends is larger than between two sweeps: a wider window, a
    # 10 cm grid (a closure only needs the ICP's basin; the ICP refines) with a 40 cm coarse step.
    return CorrelativeParams(linear_window=1.5, angular_window_deg=15.0, resolution=0.1, coarse_factor=4,
                             sigma=0.1, max_points=250, max_rotations=91, peak_separation=0.4,
                             peak_separation_deg=5.0)


@dataclass(frozen=True)
class BackendParams:
    """Parameters of the pose-graph back end (:mod:`fmcwlog.backend`).

    Nodes and odometry edges:
    node_distance, node_angle_deg: a front-end keyframe becomes a node after this much motion
        since the last node (m, deg; > 0).
    odom_sigma_xy_per_m, odom_sigma_yaw_per_m: standard deviation of the front end's relative
        motion between two nodes per metre travelled (m/m, rad/m; > 0).
    odom_sigma_yaw_per_rad: the same per radian turned (rad/rad, > 0).
    odom_sigma_xy_floor, odom_sigma_yaw_floor: their floors (m, rad; > 0).

    Loop-closure candidates (:mod:`.candidates`):
    closure_radius: a node within this distance (m) of the query node in the current estimate...
    closure_min_path: ...and at least this much path (m) before it is a candidate (≥ 0; the
        front end's local map already covers the recent path).
    closure_every: a node queries for closures after this much path (m) since the last query.
    max_candidates: at most this many candidates per query (≥ 1), nearest first, spread apart by
        ``candidate_spacing`` m of path.
    submap_nodes: the candidate's submap holds the nodes within this many of it (each side).

    Drift: the estimate between the two ends of a loop is only as good as the path since the last
    closure, so the candidates' radius and the search's window grow with it:
    drift_per_m, drift_deg_per_m: the front end's assumed drift per metre of path since the
        query's last closure (m/m, deg/m; ≥ 0): once it exceeds the search's linear or angular
        window, the window is widened to it and ``closure_radius`` by as much...
    max_window, max_window_deg: ...up to these (m, deg).
    wide_every: a widened search runs at most every this many metres of path (m): it costs ten
        times a narrow one.

    Verification (:mod:`.verification`):
    search: the correlative search around the estimated relative pose (before widening).
    icp: the point-to-line ICP after it.
    min_score: the search's best mean likelihood must reach this (0-1).
    inlier_distance, min_inlier_fraction: after the ICP, this fraction of the query's points must
        lie within ``inlier_distance`` m of the submap's (0-1).
    max_ambiguity: a separate peak scoring above this fraction of the best one, in a direction the
        scene determines, rejects the closure (0-1); along a direction it leaves free (a corridor's
        axis) it does not: the closure's covariance then leaves that direction free.
    free_direction_chi2: a peak this cheap (Mahalanobis², 3 dof) under the match's information is
        in a free direction.
    residual_sigma: standard deviation of a point-to-line residual (m) that scales the ICP's
        information into the closure's.
    effective_pairs: a match weighs as this many independent pairs at most (≥ 1).
    closure_sigma_xy_floor, closure_sigma_yaw_floor: floors added to a closure's covariance
        (m, rad): errors the residuals do not show (a sparse submap's own error).
    min_pairs: fewer point-to-line pairs reject the closure.

    Optimisation (:mod:`.graph`):
    cauchy_scale: scale of the Cauchy kernel on closures, in standard deviations; a closure whose
        whitened error ends above it weighs less than half and is counted as not accepted.
    optimize_every: re-optimise after this many new nodes once a closure has been added (≥ 1).
    """

    node_distance: float = 0.5
    node_angle_deg: float = 15.0
    odom_sigma_xy_per_m: float = 0.01
    odom_sigma_yaw_per_m: float = 0.003
    odom_sigma_yaw_per_rad: float = 0.01
    odom_sigma_xy_floor: float = 0.002
    odom_sigma_yaw_floor: float = 0.0005
    closure_radius: float = 3.0
    closure_min_path: float = 15.0
    closure_every: float = 1.0
    max_candidates: int = 2
    candidate_spacing: float = 3.0
    submap_nodes: int = 4
    drift_per_m: float = 0.01
    drift_deg_per_m: float = 0.05
    max_window: float = 5.0
    max_window_deg: float = 30.0
    wide_every: float = 5.0
    search: CorrelativeParams = field(default_factory=_closure_search)
    icp: LineICPParams = field(default_factory=LineICPParams)
    min_score: float = 0.5
    inlier_distance: float = 0.1
    min_inlier_fraction: float = 0.6
    max_ambiguity: float = 0.9
    free_direction_chi2: float = 9.0
    residual_sigma: float = 0.03
    effective_pairs: float = 25.0
    closure_sigma_xy_floor: float = 0.01
    closure_sigma_yaw_floor: float = 0.002
    min_pairs: int = 30
    cauchy_scale: float = 3.0
    optimize_every: int = 10
