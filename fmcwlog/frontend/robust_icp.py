"""Robust ICP in SE(2) (paper §4.3, eq. 22-26): GMMSC weights × Huber kernel, point-to-line residuals
on the map's lines.

Frames and units as in :mod:`fmcwlog.frontend.icp`.

:func:`register`: Gauss-Newton on ``(x, y, θ)`` minimising
eq. 22 ``Σ w_ij ρ(‖R p_i + t - q_j‖)`` with ``w_ij`` the GMMSC weights
(eq. 20-21, :mod:`fmcwlog.frontend.gmmsc`) and ρ the Huber kernel applied as
iteratively reweighted least squares (weight 1 for ``|r| ≤ δ``, ``δ/|r|``
beyond).

Departures from Wang et al. (the physics notes, docs/physics.md, give the corrections):

- The step is the Gauss-Newton step ``Δ = -(JᵀWJ)⁻¹ JᵀWe`` (``e = R p + t - q``: eq. 24 with
  the opposite sign; ``J`` of eq. 25); eq. 26 as printed, ``H⁻¹ Σ wᵢ eᵢ``, drops the ``Jᵀ``.
  ``W`` is the product of the GMMSC and the Huber weights.
- The paper's steps 1-2 (centroid pre-alignment) are not done: they are unnecessary with a
  good odometry prior, which is the start, and harmful when moving objects pull the centroid.
- The coarse match is the nearest neighbours in the local map under the prior, not FPFH/SHOT
  features (§4.2): for a planar scan with an odometry prior that is the usual coarse match.
- Where the paired map point lies on a line (:mod:`fmcwlog.kernels.normals`: a PCA of its
  ``line_neighbours`` nearest map points), the pair gives one residual along the line's normal,
  ``n · (R p + t - q)`` (:func:`~.icp.gauss_newton_step_lines`), not eq. 22's two; the weights are
  still those of the point-to-point distance. Against a map of one point per voxel the point-to-point
  residual pulls the pose along walls toward the voxels' samples (docs/methods.md);
  ``ICPParams.residual = "point_to_point"`` restores eq. 22.

Two additions, both measured on the tests' room scans: GMMSC starts only once
Huber-only steps are small (fitting the mixture to misaligned distances
rejects whole walls and stalls the pose), and successive collinear GN steps
are extrapolated (point-to-point ICP converges linearly; this about halves
the iterations at unchanged accuracy; ``ICPParams.extrapolate=False`` turns it off).
"""

from __future__ import annotations

from functools import lru_cache
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..geometry import wrap_angle
from ..kernels import compiled
from ..kernels.nearest import Correspondences, NearestPairs
from ..kernels.normals import compiled_lines, target_normals
from .gmmsc import DistanceMixture, gmmsc_weights
from .icp import ICPParams, ICPResult, gauss_newton_step, gauss_newton_step_lines, step_is_small

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree


def huber_weights(r: np.ndarray, delta: float) -> np.ndarray:
    """IRLS weights of the Huber kernel: 1 for ``|r| ≤ δ``, ``δ/|r|`` otherwise."""
    a = np.abs(r)
    return np.where(a <= delta, 1.0, delta / np.maximum(a, 1e-300))


def median(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a finite 1-D array, bit for bit (the same partition, and the mean of
    the middle two as ``(a + b) / 2``) without ``np.median``'s overhead (~10 µs a call, 4 a sweep)."""
    n = x.size
    h = n // 2
    if n == 0:
        return float("nan")
    if n % 2:
        return float(np.partition(x, h)[h])
    part = np.partition(x, (h - 1, h))
    return float((part[h - 1] + part[h]) / 2)


def _kept(c: Correspondences, keep: np.ndarray | None, gmm_weights: np.ndarray | None, p: ICPParams
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Distances, moved source, target points, weights ``W = GMM × Huber`` and target indices of the
    pairs ``keep`` (None: all of them, GMMSC not yet on: no copies, and a GMM weight of 1 is no product)."""
    if keep is None or gmm_weights is None:
        d = c.distances
        return (d, c.moved, c.target, huber_weights(d, p.huber_delta) if p.use_huber else np.ones(d.size),
                c.target_idx)
    d = c.distances[keep]
    w = gmm_weights[keep] * huber_weights(d, p.huber_delta) if p.use_huber else gmm_weights[keep]
    return d, c.moved[keep], c.target[keep], w, c.target_idx[keep]


def _target_lines(tree: object, target_xy: np.ndarray, p: ICPParams) -> tuple[np.ndarray, np.ndarray] | None:
    """The target points' unit normals (M, 2) and line flags (M,) where ``p`` asks for point-to-line
    residuals (None otherwise); kept by ``tree`` per map state where it is a ``MapIndex``."""
    if not p.point_to_line:
        return None
    return target_normals(tree, target_xy, p.line_neighbours, 1.0 / p.line_eigen_ratio)


def _extrapolation_factor(delta: np.ndarray, prev: np.ndarray, p: ICPParams) -> float:
    """Besl-McKay style acceleration of point-to-point ICP's linear convergence.

    Point-to-point steps shrink geometrically (ratio ≈ the fraction of points on
    surfaces parallel to the error, which "anchor" it). When two successive GN
    steps are nearly collinear (cosine > ``extrapolation_min_cos``, rotation
    scaled by ``extrapolation_lever`` m) and shrink by ``ρ < 1``, the remaining
    geometric series ``ρ/(1-ρ)`` is added, capped at ``max_extrapolation``.
    The convergence test still uses the plain GN step.
    """
    a = np.array([delta[0], delta[1], delta[2] * p.extrapolation_lever])
    b = np.array([prev[0], prev[1], prev[2] * p.extrapolation_lever])
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0:
        return 1.0
    rho = na / nb
    if a @ b / (na * nb) < p.extrapolation_min_cos or rho >= 0.98:
        return 1.0
    return 1.0 + min(rho / (1.0 - rho), p.max_extrapolation)


def register(
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams = ICPParams(),
    mixture: DistanceMixture | None = None,
    prior_pose: np.ndarray | None = None,
    prior_information: np.ndarray | None = None,
    inlier_distance: float | None = None,
) -> ICPResult:
    """Robust ICP: GMMSC weights × Huber weights, Gauss-Newton on SE(2) (eq. 22-26).

    ``source_xy`` (N, 2), m, in the source frame (the de-skewed sweep); ``target_xy`` (M, 2),
    m, in the target frame, and ``target_tree`` its ``cKDTree``; ``initial_pose`` (3,) the
    source-to-target pose to start from (m, m, rad; the odometry prior). Returns an
    :class:`~fmcwlog.frontend.icp.ICPResult`; raises nothing of its own: fewer than
    ``min_correspondences`` pairs end the iterations (``converged`` False).

    Each iteration: nearest neighbours under the current pose (distance gate),
    weights, one GN step ``Δ = -(JᵀWJ)⁻¹ JᵀWe``; stop when the step is below
    tolerance. Two phases, in the paper's order (coarse match, then GMMSC, then
    ICP): Huber-only iterations until the step falls below the ``gmm_start_*``
    tolerances, then the distance mixture is fit once at that pose and every
    following iteration drops pairs with inlier posterior below ``w_th`` and
    weights the rest by posterior × Huber. Fitting the mixture while far from
    the solution is harmful: the distances then reflect the misalignment (the
    walls across the error direction all sit at the offset) and GMMSC rejects
    whole walls as "outliers", stalling the pose in that direction.

    ``mixture``: a mixture from a previous registration (``ICPResult.mixture``);
    if given it is used instead of a first fit (saves one EM run per
    sweep) and refit only by the ``gmm_refit_ratio`` rule.

    ``prior_pose`` (3,) and ``prior_information`` (3, 3): optional Gaussian prior
    on the pose added to every GN step (see :func:`gauss_newton_step`); it holds
    directions the scan leaves unconstrained (e.g. along a corridor). The
    returned ``hessian`` then includes ``Λ``.

    ``inlier_distance`` (m): the caller will ask :func:`~.recovery.inlier_fraction` about it at the
    returned pose; the compiled kernel then counts those inliers in the same call (kept on the
    result's ``search``), the numpy path leaves them to it.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call, the same
    pairs, iterations and EM fits; ``target_tree`` a :class:`~fmcwlog.kernels.compiled.MapIndex`
    lends it its grid), else :func:`register_numpy`.
    """
    core = compiled.core()
    if core is None:
        return register_numpy(source_xy, target_tree, target_xy, initial_pose, params, mixture, prior_pose,
                              prior_information)
    return _register_compiled(core, source_xy, target_tree, target_xy, initial_pose, params, mixture, prior_pose,
                              prior_information, inlier_distance)


@lru_cache(maxsize=8)
def _core_params(core: ModuleType, p: ICPParams) -> object:
    """``p`` as the compiled module's ``RobustICPParams`` (made once per parameter set)."""
    out = core.RobustICPParams()
    for name in ("max_iterations", "translation_tol", "rotation_tol", "min_correspondences", "huber_delta",
                 "use_huber", "use_gmmsc", "gmm_start_translation", "gmm_start_rotation", "gmm_refit_ratio",
                 "extrapolate", "max_extrapolation", "extrapolation_min_cos", "extrapolation_lever"):
        setattr(out, name, getattr(p, name))
    for name in ("n_components", "w_th", "max_iter", "tol", "min_pairs", "min_spread", "merge_overlap",
                 "reg_covar", "max_fit_samples"):
        setattr(out, name, getattr(p.gmmsc, name))
    return out


def _register_compiled(
    core: ModuleType,
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams,
    mixture: DistanceMixture | None,
    prior_pose: np.ndarray | None,
    prior_information: np.ndarray | None,
    inlier_distance: float | None = None,
) -> ICPResult:
    """:func:`register` by the compiled module's ``robust_icp``: one call; the mixture goes in and
    comes out as plain numbers (the given object is returned where no fit replaced it); the inliers
    within ``inlier_distance`` (where given and within the gate) counted on the way."""
    source = np.ascontiguousarray(source_xy, dtype=float)
    gate = params.max_correspondence_distance
    grid = compiled.target_grid(core, target_tree, target_xy, gate)
    x, y, th = np.asarray(initial_pose, dtype=float).tolist()
    given = ((True, mixture.means.tolist(), mixture.sigmas.tolist(), mixture.mix.tolist(), mixture.merge_overlap,
              mixture.fit_median) if mixture is not None else (False, [], [], [], 0.0, float("nan")))
    has_prior = prior_pose is not None and prior_information is not None
    prior = (np.asarray(prior_pose, dtype=float).tolist(), np.asarray(prior_information, dtype=float).ravel().tolist()
             ) if has_prior else ([0.0] * 3, [0.0] * 9)
    count = inlier_distance is not None and 0.0 < inlier_distance <= gate
    lines = (compiled_lines(core, target_tree, target_xy, params.line_neighbours, 1.0 / params.line_eigen_ratio)
             if params.point_to_line else None)
    (pose, iterations, n_kept, converged, rmse, h, n_fits, replaced, (has, means, sigmas, mix, overlap, median_m),
     inliers) = core.robust_icp(grid, source, x, y, th, _core_params(core, params), given, has_prior, *prior,
                                inlier_distance if count else -1.0, lines)
    if replaced:
        mixture = DistanceMixture(np.array(means), np.array(sigmas), np.array(mix), overlap, median_m) if has else None
    search = compiled.CompiledNearest(core, source, target_tree, grid, gate)
    final = np.array(pose)
    if count and inlier_distance is not None:
        search.counted = (final, inlier_distance, inliers)
    return ICPResult(final, iterations, n_kept, converged, rmse, np.array(h).reshape(3, 3), n_fits, mixture, search)


def register_numpy(
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams = ICPParams(),
    mixture: DistanceMixture | None = None,
    prior_pose: np.ndarray | None = None,
    prior_information: np.ndarray | None = None,
) -> ICPResult:
    """:func:`register` in numpy: the reference the compiled kernel is tested against."""
    pose = np.asarray(initial_pose, dtype=float).copy()
    gmm_on = False
    n_fits = 0
    h = np.zeros((3, 3))
    n_kept, rmse, converged = 0, float("nan"), False
    last_distances = None  # of the last pairs used: the RMS is taken once, after the loop
    prev_delta: np.ndarray | None = None
    search = NearestPairs(source_xy, target_tree, target_xy, params.max_correspondence_distance, params.workers)
    lines = _target_lines(target_tree, target_xy, params)
    iterations = 0
    for iterations in range(1, params.max_iterations + 1):  # noqa: B007 (the count is returned)
        c = search.pairs(pose)
        if c.distances.size < params.min_correspondences:
            break
        keep = gmm_w = None  # all pairs (no copies of them) until GMMSC weighs them
        if gmm_on:
            med = median(c.distances)
            r = params.gmm_refit_ratio
            ref = mixture.fit_median if mixture is not None else np.nan
            # NaN reference (unknown): keep the given mixture
            refit = mixture is None or r >= 1.0 or med < r * ref or med * r > ref
            g = gmmsc_weights(c.distances, params.gmmsc, mixture, refit=refit)
            if refit:
                n_fits += g.mixture is not None
                mixture, prev_delta = g.mixture, None
            gmm_w, keep = g.weights, g.keep  # eq. 21, w_i < w_th rejected
        n_pairs = c.distances.size if keep is None else int(keep.sum())
        if n_pairs < params.min_correspondences:
            break
        d, moved, target, w, near = _kept(c, keep, gmm_w, params)
        if lines is None:
            delta, h = gauss_newton_step(moved, target, pose, w, prior_pose, prior_information)
        else:
            delta, h = gauss_newton_step_lines(moved, target, lines[0].take(near, axis=0), lines[1].take(near), pose,
                                               w, prior_pose, prior_information)
        step = delta
        if params.extrapolate and prev_delta is not None:
            step = delta * _extrapolation_factor(delta, prev_delta, params)
        prev_delta = delta
        pose = pose + step
        pose[2] = wrap_angle(pose[2])
        n_kept, last_distances = n_pairs, d
        if params.use_gmmsc and not gmm_on:
            gmm_on = bool(
                np.hypot(delta[0], delta[1]) < params.gmm_start_translation
                and abs(delta[2]) < params.gmm_start_rotation
            )
            if gmm_on:
                prev_delta = None  # new weights: a new fixed point
            continue  # never stop before GMMSC has been applied
        if step_is_small(delta, params):
            converged = True
            break
    if last_distances is not None:
        rmse = float(np.sqrt(np.mean(last_distances * last_distances)))
    return ICPResult(pose, iterations, n_kept, converged, rmse, h, n_fits, mixture, search)
