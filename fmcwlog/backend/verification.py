"""Verification of a loop-closure candidate: scan-to-submap matching and three tests.

1. A correlative search (:mod:`fmcwlog.kernels.correlative`) of the query node's points on a
   likelihood grid of the candidate's submap, around the relative pose the current estimate
   gives; its best mean likelihood must reach ``min_score``.
2. Point-to-line ICP from the search's best pose (:mod:`.registration`); at least
   ``min_inlier_fraction`` of the query's points must then lie within ``inlier_distance`` of
   the submap (overlap, not only a good score on a few points).
3. Uniqueness: the search's best *separate* peak must score below ``max_ambiguity`` of the
   best, unless it lies in a direction the scene leaves free. Free directions come from the
   ICP's information (lengths and angles made commensurable with a lever of ``LEVER`` m): an
   eigenvalue below ``DEGENERACY_RATIO`` of the largest is a direction no normal of the scene
   constrains, such as a corridor's axis. There a near-equal second peak is expected, and the
   closure is kept with a covariance that leaves that direction free (its information
   dropped), rather than rejected. A near-equal peak in a determined direction (two look-alike
   corridors side by side, a row of identical doors) rejects it: the scene cannot tell which.

The closure's covariance is ``(H_det·n/(K σ²) + Λ₀)⁻¹`` plus floors, ``H_det`` the ICP's
information with its free directions marginalised out (:func:`leave_free`), ``K`` its pairs, ``n`` = ``effective_pairs`` (the
residuals of one match are not independent: the same few corners fix every pair's along-wall
position), ``σ`` = ``residual_sigma``, ``Λ₀`` a weak regulariser (100 m, 1 rad standard
deviations) that keeps it invertible.

Which motion is left free: a free direction is found as an eigenvector of the lever-scaled ``H``,
but that eigenvector is tilted by whatever weak structure the scene has (a door jamb, the far end
of a corridor), and leaving *it* free would tell the graph that sliding along a corridor also
turns the robot (in the 240 s ``long-corridor`` a median 0.3°, up to 2°, per metre of slide). A
slide along a corridor turns nothing: each free direction is snapped to a pure translation (or,
where its rotation dominates, a pure rotation) and marginalised out of ``H`` (its Schur
complement), so the closure states the other directions whatever the graph makes of that one.
On the 240 s ``long-corridor`` (``fmcwlog record --scenario long-corridor --duration 240``;
closures from the front ends' own keyframes replayed through the back end) the back-end ATE is
2.3 cm this way, against 12.1 cm with the eigenvector left free.

Where the scene leaves a direction free, the search puts the pose anywhere along it, so the other
directions are measured again with that one held where the estimate puts it (in ``long-corridor``
the search slid the pose a median 1.5 m along the axis from an estimate 0.14 m off). Only where the
estimate is trusted, in searches that were not widened: after a drift that widened the search
window, the estimate itself is metres off along the axis, and held there the closure's yaw is
measured against the wrong stretch of wall. On MIT Killian (``bench/killian_log.py`` gives the log
and the commands) holding in every search gives a relations error of 0.167 m, holding only in
unwidened searches 0.034-0.035 m (the case in full: docs/design/back-end.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import transform_points, wrap_angle
from ..kernels import compiled
from ..kernels.correlative import CorrelativeParams, correlative_match, grid_for, subsample
from .keyframes import match_covariance
from .params import BackendParams
from .registration import Submap, build_submap, register_point_to_line

LEVER = 5.0  # m: a yaw error of 1 rad is weighed as 5 m of translation when finding free directions
DEGENERACY_RATIO = 0.02


@dataclass
class Verdict:
    """The outcome for one candidate. ``accepted``: passed the three tests; ``test``: the test that
    rejected it (``points``, ``score``, ``pairs``, ``inliers``, ``ambiguity``); ``reason``: why, in words;
    ``relative``: the query node's pose in the candidate's frame (3,); ``covariance``: (3, 3) in
    gtsam's tangent space at ``relative``; ``free_directions``: how many the scene left free;
    the tests' figures: ``score``, ``second_score``, ``inlier_fraction``."""

    accepted: bool
    test: str
    reason: str
    relative: np.ndarray | None = None
    covariance: np.ndarray | None = None
    free_directions: int = 0
    score: float = 0.0
    second_score: float = 0.0
    inlier_fraction: float = 0.0


def split_information(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The information ``h`` (3, 3) over (x, y, yaw) without its free directions, and those
    directions as columns (3, F) in lever-scaled coordinates (module docstring)."""
    s = np.diag([1.0, 1.0, 1.0 / LEVER])  # to (m, m, m of arc at the lever)
    hs = s @ h @ s
    w, v = np.linalg.eigh(0.5 * (hs + hs.T))
    free = w < DEGENERACY_RATIO * max(float(w[-1]), 1e-300)
    kept = (v[:, ~free] * w[~free]) @ v[:, ~free].T
    si = np.linalg.inv(s)
    return si @ kept @ si, v[:, free]


def leave_free(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The information ``h`` (3, 3) over (x, y, yaw) with its free directions (found by
    :func:`split_information`) each snapped to a pure translation or a pure rotation and
    marginalised out (a Schur complement: what ``h`` says of the other directions with those
    unknown), and those snapped directions as orthonormal columns (3, F), in lever-scaled
    coordinates (a pure translation or rotation reads the same in both)."""
    _, free = split_information(h)
    if free.shape[1] == 0:
        return h, free
    cols = [np.array([f[0], f[1], 0.0]) / np.hypot(f[0], f[1]) if np.hypot(f[0], f[1]) >= abs(f[2])
            else np.array([0.0, 0.0, 1.0]) for f in free.T]
    axes = np.linalg.qr(np.array(cols).T)[0][:, :np.linalg.matrix_rank(np.array(cols))]
    he = h @ axes
    kept = h - he @ np.linalg.pinv(axes.T @ he, rcond=1e-12, hermitian=True) @ he.T  # none there: nothing to take
    return 0.5 * (kept + kept.T), axes


def _in_free_directions(delta: np.ndarray, free: np.ndarray) -> bool:
    """Whether a pose difference (3,) lies (to 90 %) in the span of the free directions."""
    if free.shape[1] == 0:
        return False
    d = np.array([delta[0], delta[1], delta[2] * LEVER])
    n = float(np.linalg.norm(d))
    return n == 0.0 or float(np.linalg.norm(free.T @ d)) >= 0.9 * n


def verify(query_xy: np.ndarray, submap_xy: np.ndarray, prior: np.ndarray, p: BackendParams,
           search: CorrelativeParams | None = None) -> Verdict:
    """Verify that ``query_xy`` (N, 2, m, query node's base_link) matches ``submap_xy`` (M, 2, m, the
    candidate's base_link frame) near ``prior`` (3,, the query's pose in that frame, m, m, rad); ``search``:
    the correlative search's window (default ``p.search``; the pipeline widens it with the drift).
    A closure that fails a test is a :class:`Verdict` naming the test and why; nothing is raised."""
    search = search or p.search
    if len(query_xy) < p.min_pairs or len(submap_xy) < p.min_pairs:
        return Verdict(False, "points", f"{len(query_xy)} query and {len(submap_xy)} submap points")
    found = correlative_match(grid_for(reachable(submap_xy, query_xy, prior, search), search), query_xy, prior, search)
    base = Verdict(False, "", "", score=found.score, second_score=found.second_score)
    if found.score < p.min_score:
        return _reject(base, "score", f"search score {found.score:.2f} < {p.min_score}")
    sub = build_submap(submap_xy, p.icp)
    icp = register_point_to_line(query_xy, sub, found.pose, p.icp)
    if icp.pairs < p.min_pairs:
        return _reject(base, "pairs", f"{icp.pairs} point-to-line pairs < {p.min_pairs}")
    base.inlier_fraction = inlier_fraction(query_xy, sub, icp.pose, p.inlier_distance)
    if base.inlier_fraction < p.min_inlier_fraction:
        return _reject(base, "inliers", f"inlier fraction {base.inlier_fraction:.2f} < {p.min_inlier_fraction}")
    _, free = split_information(icp.hessian)
    if free.shape[1] and search.linear_window <= p.search.linear_window:
        # the scene leaves a direction free, so the search put the pose anywhere along it; measure
        # the other directions where the estimate puts that one (far structures seen from a pose
        # slid along a corridor would otherwise tilt the yaw), but only where the estimate is
        # trusted: not after a drift that widened the search (module docstring)
        icp = register_point_to_line(query_xy, sub, icp.pose, p.icp, (prior, _hold(free, icp.hessian)))
    determined, free = leave_free(icp.hessian)
    if found.second_pose is not None and found.second_score >= p.max_ambiguity * found.score:
        delta = found.second_pose - found.pose
        delta[2] = wrap_angle(delta[2])
        if not _in_free_directions(delta, free):
            return _reject(base, "ambiguity", f"a separate peak scores {found.second_score / found.score:.2f} of the best")
    base.accepted, base.test, base.reason = True, "", "accepted"
    base.relative = icp.pose
    base.covariance = match_covariance(determined, icp.pairs, icp.pose, p, p.closure_sigma_xy_floor,
                                       p.closure_sigma_yaw_floor)
    base.free_directions = int(free.shape[1])
    return base


def reachable(submap_xy: np.ndarray, query_xy: np.ndarray, prior: np.ndarray, search: CorrelativeParams) -> np.ndarray:
    """The submap's points (M', 2) that can bear on ``search``'s scores of ``query_xy`` around ``prior``:
    those within the box the searched query points sweep over the window (``prior``'s placement,
    grown by the linear window, the arc of the yaw samples at the farthest point's range and two cells),
    grown by the reach of the likelihood's float32 (``sqrt(240)·σ``, past which it is 0). A grid
    over these alone scores every pose the same (the likelihood grid's distance transform finds
    the same nearest point wherever it matters) at about two thirds of the cells; the ICP still
    matches the whole submap."""
    if not len(query_xy):
        return submap_xy
    src = subsample(query_xy, search.max_points)  # the points the search scores, placed as it does
    placed = transform_points(prior, src)
    ranges = np.hypot(src[:, 0], src[:, 1])
    # the yaw samples reach past the window by at most one step, max(resolution / r90, 2·window /
    # (max_rotations - 1)), r90 the ranges' 90th percentile (no less than the value just below it)
    r90 = max(float(np.partition(ranges, int(0.9 * (len(ranges) - 1)))[int(0.9 * (len(ranges) - 1))]), search.resolution)
    window = np.radians(search.angular_window_deg)
    turn = window + max(search.resolution / r90, 2 * window / (search.max_rotations - 1))
    pad = search.linear_window + float(ranges.max()) * turn + np.sqrt(240.0) * search.sigma + 2 * search.resolution
    lo, hi = placed.min(axis=0) - pad, placed.max(axis=0) + pad
    keep = ((submap_xy >= lo) & (submap_xy <= hi)).all(axis=1)
    return submap_xy if keep.all() else submap_xy[keep]


def inlier_fraction(query_xy: np.ndarray, sub: Submap, pose: np.ndarray, bound: float) -> float:
    """The fraction of ``query_xy`` (N, 2, m, the query's frame) that, placed at ``pose`` (3,) in the
    submap's frame, has a submap point closer than ``bound`` (m). Where the compiled core is selected,
    a grid over the submap answers, without building the submap's KD-tree: the ICP's grid (kept in
    ``sub.grids`` per gate) where its gate is at least ``bound`` (a point's nearest distance does not
    depend on the gate it was found under), else one built for ``bound``; the tree otherwise (the
    same nearest distances, the same strict bound)."""
    module = compiled.core()
    if module is None:
        d, _ = sub.tree.query(transform_points(pose, query_xy), k=1, distance_upper_bound=bound)
        return float(np.isfinite(d).mean())
    wide = [gate for gate in sub.grids if gate >= bound]
    if wide:
        grid = sub.grids[min(wide)]
    else:
        grid = sub.grids[bound] = module.TargetGrid(np.ascontiguousarray(sub.points, float), bound)
    n = len(query_xy)
    moved, index, dist = np.empty((n, 2)), np.empty(n, np.int64), np.empty(n)
    x, y, th = np.asarray(pose, float).tolist()
    module.nearest(grid, np.ascontiguousarray(query_xy, float), x, y, th, moved, index, dist)
    return float((dist < bound).mean())


def _hold(free: np.ndarray, h: np.ndarray) -> np.ndarray:
    """An information (3, 3) that holds the free directions (lever-scaled columns) as firmly as the
    scene holds its best-determined one."""
    s = np.diag([1.0, 1.0, 1.0 / LEVER])
    scaled = s @ h @ s
    strength = float(np.linalg.eigvalsh(0.5 * (scaled + scaled.T))[-1])
    si = np.linalg.inv(s)
    return si @ (strength * free @ free.T) @ si


def _reject(v: Verdict, test: str, reason: str) -> Verdict:
    v.test, v.reason = test, reason
    return v
