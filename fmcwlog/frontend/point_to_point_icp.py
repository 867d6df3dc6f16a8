"""The baseline: classic point-to-point ICP in SE(2), the paper's "before improvement".

Frames and units as in :mod:`fmcwlog.frontend.icp`. The same correspondence
search and distance gate as :mod:`fmcwlog.frontend.robust_icp`, but unit
weights, no rejection, no kernel, solved in closed form each iteration (2-D
Kabsch / Arun SVD: the optimal rotation from the cross-covariance of the
centred pairs). The centring there is part of the least-squares solution, not
a pre-alignment. The front end registers a thinned source (one point per voxel, the
standard practice of ICP pipelines such as KISS-ICP; :mod:`fmcwlog.frontend.methods`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..geometry import transform_points, wrap_angle
from ..kernels import compiled
from ..kernels.nearest import NearestPairs
from .icp import ICPParams, ICPResult, gauss_newton_step, step_is_small

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree


def closed_form_pose(source_pts: np.ndarray, target_pts: np.ndarray) -> np.ndarray:
    """Least-squares pose (3,) with ``target ≈ R source + t`` for given pairs (2-D Kabsch).

    ``θ = atan2(Σ p'×q', Σ p'·q')`` on centred pairs, ``t = q̄ - R p̄``.
    """
    # every reduction in its original form and memory layout (the bits depend on them: axis-0 sums
    # add row by row, whole-array sums pairwise); methods, not np.* wrappers, and scalar arithmetic
    # in place of small arrays: ~2x fewer µs of call overhead an iteration
    n = len(source_pts)
    pc, qc = source_pts.sum(axis=0), target_pts.sum(axis=0)
    pc /= n
    qc /= n
    p, q = source_pts - pc, target_pts - qc
    cross = p[:, 0] * q[:, 1]
    cross -= p[:, 1] * q[:, 0]
    p *= q
    th = np.arctan2(cross.sum(), p.sum())
    c, s = np.cos(th), np.sin(th)
    (px, py), (qx, qy) = pc.tolist(), qc.tolist()
    return np.array((qx - (c * px - s * py), qy - (s * px + c * py), th))


def register_point_to_point(
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams = ICPParams(),
    inlier_distance: float | None = None,
) -> ICPResult:
    """Baseline: classic point-to-point ICP, all gated pairs, unit weights, closed form.

    Same correspondence search and gate as :func:`register`; no GMMSC, no Huber.
    Each iteration solves the pose exactly for the current pairs (2-D Kabsch).
    ``inlier_distance``: as :func:`~.robust_icp.register`'s (the compiled kernel counts those inliers).
    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call, the
    same pairs and iterations; ``target_tree`` a :class:`~fmcwlog.kernels.compiled.MapIndex` lends
    it its grid), else :func:`register_point_to_point_numpy`.
    """
    core = compiled.core()
    if core is None:
        return register_point_to_point_numpy(source_xy, target_tree, target_xy, initial_pose, params)
    source = np.ascontiguousarray(source_xy, dtype=float)
    grid = compiled.target_grid(core, target_tree, target_xy, params.max_correspondence_distance)
    x, y, th = np.asarray(initial_pose, dtype=float).tolist()
    count = inlier_distance is not None and 0.0 < inlier_distance <= params.max_correspondence_distance
    pose, iterations, n_kept, converged, rmse, (h00, h02, h11, h12, h22), inliers = core.point_to_point_icp(
        grid, source, x, y, th, params.max_iterations, params.translation_tol, params.rotation_tol,
        params.min_correspondences, inlier_distance if count else -1.0)
    h = np.array(((h00, 0.0, h02), (0.0, h11, h12), (h02, h12, h22)))
    search = compiled.CompiledNearest(core, source, target_tree, grid, params.max_correspondence_distance)
    final = np.array(pose)
    if count and inlier_distance is not None:
        search.counted = (final, inlier_distance, inliers)
    return ICPResult(final, iterations, n_kept, converged, rmse, h, 0, None, search)


def register_point_to_point_numpy(
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams = ICPParams(),
) -> ICPResult:
    """:func:`register_point_to_point` in numpy: the reference the compiled kernel is tested against."""
    pose = np.asarray(initial_pose, dtype=float).copy()
    h = np.zeros((3, 3))
    n_kept, rmse, converged = 0, float("nan"), False
    last_distances = None  # of the last pairs used: the RMS is taken once, after the loop
    search = NearestPairs(source_xy, target_tree, target_xy, params.max_correspondence_distance, params.workers)
    iterations = 0
    for iterations in range(1, params.max_iterations + 1):  # noqa: B007 (the count is returned)
        c = search.pairs(pose)
        if c.distances.size < params.min_correspondences:
            break
        src = source_xy.take(c.source_idx, axis=0)
        new = closed_form_pose(src, c.target)
        step = new - pose
        step[2] = wrap_angle(step[2])
        pose = new
        n_kept, last_distances, used = int(c.distances.size), c.distances, (src, c.target)
        if step_is_small(step, params):
            converged = True
            break
    if last_distances is not None:
        rmse = float(np.sqrt(np.mean(last_distances**2)))
    if n_kept:  # information matrix of the last pairs used, at the final pose (unit weights)
        _, h = gauss_newton_step(transform_points(pose, used[0]), used[1], pose, np.ones(n_kept))
    return ICPResult(pose, iterations, n_kept, converged, rmse, h, 0, None, search)
