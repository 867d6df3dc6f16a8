"""The back end's parameters: nodes, odometry edges, loop-closure candidates, verification, kernel.

Nested in :class:`fmcwlog.frontend.params.FrontEndParams` as ``backend`` (``--set
backend.closure_radius=4``, a ``[backend]`` table in a config file), so ``run.json`` records
them with the rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..config import Checked, param
from ..kernels.correlative import CorrelativeParams
from .registration import LineICPParams


def _closure_search() -> CorrelativeParams:
    # Drift between a closure's two ends is larger than between two sweeps: a wider window, a
    # 10 cm grid (a closure only needs the ICP's basin; the ICP refines) with a 40 cm coarse step.
    return CorrelativeParams(linear_window=1.5, angular_window_deg=15.0, resolution=0.1, coarse_factor=4,
                             sigma=0.1, max_points=250, max_rotations=91, peak_separation=0.4,
                             peak_separation_deg=5.0)


@dataclass(frozen=True)
class BackendParams(Checked):
    """Parameters of the pose-graph back end (:mod:`fmcwlog.backend`).

    Nodes and odometry edges:
    node_distance, node_angle_deg: a front-end keyframe becomes a node after this much motion
        since the last node (m, deg; > 0).
    odom_sigma_xy_per_m, odom_sigma_yaw_per_m: standard deviation of the front end's relative
        motion between two nodes per metre travelled (m/m, rad/m; > 0).
    odom_sigma_yaw_per_rad: the same per radian turned (rad/rad, > 0).
    odom_sigma_xy_floor, odom_sigma_yaw_floor: their floors (m, rad; > 0).

    Local edges (:mod:`.local_edges`): each new node matched, point to line, against the nodes
    just before it, beside the front end's edge:
    local_links: against each of the last this many nodes (0: none).
    local_gate, local_gate_deg: a match that moved farther than this from the front end's
        relative pose gives no edge (m, deg).
    local_sigma_xy_floor, local_sigma_yaw_floor: floors added to a local edge's covariance (m, rad).
    local_query_voxel, local_submap_voxel: the new node's points are thinned to this voxel as the
        query, an earlier node's as the submap it is matched against (m).
    local_max_iterations, local_tolerance: the local matches' ICP stops after this many
        iterations or once a step moves less than this (m, and rad × 1 m); ``icp`` otherwise.

    Loop-closure candidates (:mod:`.candidates`):
    closure_radius: a node within this distance (m) of the query node in the current estimate...
    closure_min_path: ...and at least this much path (m) before it is a candidate (≥ 0; the
        front end's local map already covers the recent path).
    closure_every: a node queries for closures after this much path (m) since the last query.
    closure_every_closed: ...or after this much (m, ≥ ``closure_every`` to matter) where the last
        query added closures, each within ``optimize_gap`` of the estimate: a stretch already tied
        to an earlier pass where the estimate had it needs fewer ties (as Cartographer samples its
        constraints); each costs a verification. A drifting front end's closures disagree and
        keep every query (the baseline's ATE on a 20-minute ten-lap corridor rose by 39 % when
        any closure thinned them).
    closure_settle: ...and only where no closure disagreed with the estimate over the last this
        much path (m): a drifting front end's closures, even with the tail pulled along
        (``closure_pull``), disagree every metre or two and keep every query (on the 20-minute
        corridor its ATE rose 9 % when an agreeing query alone thinned them).
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
    residual_sigma: standard deviation of a point-to-line residual (m) that scales the ICP's
        information into the closure's.
    effective_pairs: a match weighs as this many independent pairs at most (≥ 1).
    closure_sigma_xy_floor, closure_sigma_yaw_floor: floors added to a closure's covariance
        (m, rad): errors the residuals do not show (a sparse submap's own error).
    min_pairs: fewer point-to-line pairs reject the closure.

    Optimisation (:mod:`.graph`):
    cauchy_scale: scale of the Cauchy kernel on closures, in standard deviations; a closure whose
        whitened error ends above it weighs less than half and is counted as not accepted.
    optimize_every: re-optimise after this many new nodes once a closure has been added (≥ 1)...
    optimize_gap, optimize_gap_deg: ...but a closure that moved less than this from the relative pose
        the current estimate gave (m, deg; in the directions it determines) calls for none: the
        estimate is already as good as the later searches (windows of a metre and more) need; the
        last solve takes every closure. Both 0: every closure calls for one.
    tied_window, tied_window_deg: the correlative search's half-widths (m, deg; at most ``search``'s)
        for a query right after one whose closure pulled the tail (``closure_pull``) onto an earlier
        pass: the estimate is then off by the drift of a metre or two, and the search costs a
        fraction of the full window's (the 20-minute ten-lap corridor: closure verification 4.3 -> 3.4 s
        for the improved method, 8.7 -> 7.2 s for the baseline; ATE 0.566 -> 0.565 cm and 0.199 -> 0.201
        m). ``tied_window`` 0: always ``search``'s.
    tied_after_agreement: the same narrower search for a query right after one whose closures all
        agreed with the estimate (each within ``optimize_gap``, :meth:`~.pipeline.PoseGraphBackend._disagrees`):
        there the estimate is already within a gap of the earlier pass, as after a pull. False: only
        after a pull.
    closure_pull: between re-solves, each accepted closure moves the query node, the newest, this
        share (0-1) of the way to where the closure puts it (in the directions the closure
        determines, weighed against ``optimize_gap``), and the nodes after it follow by odometry:
        the trajectory's tail stays attached to the earlier pass, as Cartographer's and KISS-SLAM's
        do, so odometry drift does not pile up into disagreeing closures and re-solves between them.
        0 (the default): the estimate moves only at a re-solve. Half the way took the 20-minute
        ten-lap corridor's re-solves from 25 to 1 (back end 11.8 -> 6.4 s CPU, ATE unchanged), but
        on MIT Killian Court (``bench/killian_log.py``: 2.1 h, large loops closed after 150 m of
        odometry drift) the improved method's relations went from 0.033 to 0.171 m: the tail, pulled
        onto one closure at a time, left the last solve a start it could not recover from.
    optimize_tolerance: such a re-optimisation stops once a Levenberg-Marquardt iteration lowers the
        graph's error by less than this fraction of it (0-1); the last one, in
        :meth:`~.pipeline.PoseGraphBackend.finish`, runs to gtsam's default (1e-5).
    optimize_share: re-optimise after this share of the graph's nodes instead, where that is more
        than ``optimize_every`` (0-1): a re-solve costs more the larger the graph, so a share keeps
        their total about linear in the log's length. A twentieth: at a tenth a drifting method's 50
        re-solves of the 20-minute ten-lap corridor took 1.5 s CPU instead of 2.5 s, but MIT Killian
        Court's improved relations went from 0.033 to 0.10 m.
    solver: ``batch`` re-solves the whole graph with Levenberg-Marquardt each time; ``isam2`` hands
        gtsam's ISAM2 what was added since the last time and solves the whole graph once in
        :meth:`~.pipeline.PoseGraphBackend.finish`: less CPU, but its Bayes tree is held and grows
        with the log (:mod:`.graph` gives the figures), so ``batch`` is the default.
    isam2_steps: ISAM2 updates (Gauss-Newton steps on the affected part) per re-optimisation (≥ 1).
    isam2_relinearize: ISAM2 relinearises a node whose estimate moved more than this since its last
        linearisation (m and rad, > 0).
    """

    node_distance: float = param(0.5, "m", gt=0.0, le=100.0)
    node_angle_deg: float = param(15.0, "deg", gt=0.0, le=180.0)
    # standard deviations: 0 would be an infinitely certain edge (a division by zero)
    odom_sigma_xy_per_m: float = param(0.01, "m/m", gt=0.0, le=10.0)
    odom_sigma_yaw_per_m: float = param(0.003, "rad/m", gt=0.0, le=10.0)
    odom_sigma_yaw_per_rad: float = param(0.01, "rad/rad", gt=0.0, le=10.0)
    odom_sigma_xy_floor: float = param(0.002, "m", gt=0.0, le=10.0)
    odom_sigma_yaw_floor: float = param(0.0005, "rad", gt=0.0, le=math.pi)
    local_links: int = param(4, "nodes", ge=0, le=100)
    local_gate: float = param(0.1, "m", gt=0.0, le=10.0)
    local_gate_deg: float = param(2.0, "deg", gt=0.0, le=180.0)
    local_sigma_xy_floor: float = param(0.002, "m", gt=0.0, le=10.0)
    local_sigma_yaw_floor: float = param(0.0005, "rad", gt=0.0, le=math.pi)
    local_query_voxel: float = param(0.05, "m", gt=0.0, le=1.0)
    local_submap_voxel: float = param(0.05, "m", gt=0.0, le=1.0)
    local_max_iterations: int = param(20, "", ge=1, le=1000)
    local_tolerance: float = param(1e-4, "m", gt=0.0, le=1.0)
    closure_radius: float = param(3.0, "m", gt=0.0, le=100.0)
    closure_min_path: float = param(15.0, "m", ge=0.0, le=10_000.0)
    closure_every: float = param(1.0, "m", gt=0.0, le=1000.0)
    closure_every_closed: float = param(2.0, "m", gt=0.0, le=1000.0)
    max_candidates: int = param(2, "", ge=1, le=100)
    candidate_spacing: float = param(3.0, "m", ge=0.0, le=1000.0)
    submap_nodes: int = param(4, "nodes", ge=0, le=100)
    drift_per_m: float = param(0.01, "m/m", ge=0.0, le=1.0)
    drift_deg_per_m: float = param(0.05, "deg/m", ge=0.0, le=10.0)
    # the widened search replaces search.linear_window / angular_window_deg: the same upper ends
    max_window: float = param(5.0, "m", gt=0.0, le=20.0)
    max_window_deg: float = param(30.0, "deg", gt=0.0, le=180.0)
    wide_every: float = param(5.0, "m", ge=0.0, le=1000.0)
    search: CorrelativeParams = field(default_factory=_closure_search)
    icp: LineICPParams = field(default_factory=LineICPParams)
    min_score: float = param(0.5, "", ge=0.0, le=1.0)
    inlier_distance: float = param(0.1, "m", gt=0.0, le=10.0)
    min_inlier_fraction: float = param(0.6, "", ge=0.0, le=1.0)
    max_ambiguity: float = param(0.9, "", ge=0.0, le=1.0)
    residual_sigma: float = param(0.03, "m", gt=0.0, le=10.0)
    effective_pairs: float = param(25.0, "pairs", ge=1.0, le=1e6)
    closure_sigma_xy_floor: float = param(0.01, "m", gt=0.0, le=10.0)
    closure_sigma_yaw_floor: float = param(0.002, "rad", gt=0.0, le=math.pi)
    min_pairs: int = param(30, "pairs", ge=1, le=100_000)
    cauchy_scale: float = param(3.0, "sigma", gt=0.0, le=100.0)
    optimize_every: int = param(10, "nodes", ge=1, le=100_000)
    optimize_gap: float = param(0.1, "m", ge=0.0, le=100.0)
    optimize_gap_deg: float = param(1.0, "deg", ge=0.0, le=180.0)
    closure_settle: float = param(10.0, "m", ge=0.0, le=10_000.0)
    tied_window: float = param(0.5, "m", ge=0.0, le=20.0)
    tied_window_deg: float = param(5.0, "deg", gt=0.0, le=180.0)
    closure_pull: float = param(0.0, "", ge=0.0, le=1.0)
    tied_after_agreement: bool = True
    optimize_tolerance: float = param(1e-3, "", gt=0.0, le=1.0)
    optimize_share: float = param(0.05, "", ge=0.0, le=1.0)
    solver: str = param("batch", choices=("batch", "isam2"))
    isam2_steps: int = param(3, "", ge=1, le=100)
    isam2_relinearize: float = param(0.001, "m, rad", gt=0.0, le=10.0)
