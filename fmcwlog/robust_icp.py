"""Robust point-to-point ICP in SE(2) (paper §4.3, eq. 22-26) and its classic baseline.

Frames and units: ``source_xy`` (N, 2) in the source frame (e.g. the de-skewed
lidar frame of a sweep, m); ``target_xy`` (M, 2) in the target frame (e.g.
``map``); poses ``(x, y, θ)`` map source into target
(``q ≈ R(θ) p + t``, :func:`fmcwlog.geometry.transform_points`). The caller
builds the target's ``cKDTree`` once and passes it in.

Robust variant (:func:`register`): Gauss-Newton on ``(x, y, θ)`` minimising
eq. 22 ``Σ w_ij ρ(‖R p_i + t - q_j‖)`` with ``w_ij`` the GMMSC weights
(eq. 20-21, :mod:`fmcwlog.gmmsc`) and ρ the Huber kernel applied as
iteratively reweighted least squares (weight 1 for ``|r| ≤ δ``, ``δ/|r|``
beyond). The step is ``Δ = -(JᵀWJ)⁻¹ JᵀWe`` — NOTES.md: eq. 26 drops the
``Jᵀ``. The paper's steps 1-2 (centroid pre-alignment) are not done (NOTES:
harmful when movers pull the centroid; the odometry prior is the start).
Two additions, both measured on the tests' room scans: GMMSC starts only once
Huber-only steps are small (fitting the mixture to misaligned distances
rejects whole walls and stalls the pose), and successive collinear GN steps
are extrapolated (point-to-point ICP converges linearly; this about halves
the iterations at unchanged accuracy; ``ICPParams.extrapolate=False`` turns it off).

Baseline (:func:`register_point_to_point`): classic point-to-point ICP with
the same correspondence search and distance gate, unit weights, no rejection,
no kernel, solved in closed form each iteration (2-D Kabsch / Arun SVD: the
optimal rotation from the cross-covariance of the centred pairs). The
centring there is part of the least-squares solution, not a pre-alignment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from fmcwlog.geometry import transform_points, wrap_angle
from fmcwlog.gmmsc import DistanceMixture, GMMSCParams, gmmsc_weights


@dataclass(frozen=True)
class ICPParams:
    """Parameters shared by :func:`register` and :func:`register_point_to_point`.

    max_iterations: iteration cap.
    max_correspondence_distance: pairs farther apart are dropped (m).
    translation_tol, rotation_tol: stop when a step is below both (m, rad).
    min_correspondences: fewer usable pairs aborts (converged=False).
    huber_delta: Huber threshold δ on the residual norm (m); robust only.
    use_gmmsc: apply GMMSC weights/rejection (robust only; False = Huber only).
    gmmsc: parameters of the distance mixture.
    gmm_start_translation, gmm_start_rotation: GMMSC starts once a (Huber-only)
        step is below both (m, rad); see :func:`register`.
    gmm_refit_ratio: after the first fit the mixture is refit only when the
        median pair distance leaves ``[r, 1/r] ×`` the median the mixture was
        fit to (``DistanceMixture.fit_median``; this also applies to a mixture
        reused from a previous sweep); otherwise eq. 21 is just evaluated with
        the last mixture (~0.05 ms instead of a ~1-3 ms sklearn EM run).
        ≥ 1 refits every iteration.
    extrapolate, max_extrapolation, extrapolation_min_cos, extrapolation_lever:
        step extrapolation of the robust variant (``_extrapolation_factor``);
        halves the iterations in our tests at unchanged accuracy.
    workers: threads for the KD-tree query (1: the per-sweep budget is tiny).
    """

    max_iterations: int = 30
    max_correspondence_distance: float = 0.5
    translation_tol: float = 1e-4
    rotation_tol: float = 5e-5
    min_correspondences: int = 10
    huber_delta: float = 0.05
    use_gmmsc: bool = True
    gmmsc: GMMSCParams = field(default_factory=GMMSCParams)
    gmm_start_translation: float = 2e-3
    gmm_start_rotation: float = 2e-3
    gmm_refit_ratio: float = 0.25
    extrapolate: bool = True
    max_extrapolation: float = 10.0
    extrapolation_min_cos: float = 0.9
    extrapolation_lever: float = 3.0
    workers: int = 1


@dataclass
class ICPResult:
    """Registration result.

    pose: (3,) source-to-target pose (m, m, rad).
    iterations: iterations run.
    n_correspondences_kept: pairs used in the last step (within the gate and,
        for the robust variant, kept by GMMSC).
    converged: the last step was below tolerance.
    rmse: RMS distance of the kept pairs at the last iteration (m).
    hessian: (3, 3) ``JᵀWJ`` of the last step (information up to the noise scale).
    n_gmm_fits: EM fits run (robust variant; 0 for the baseline).
    mixture: the distance mixture last used (robust variant), reusable as the
        next sweep's ``mixture`` to skip the EM fit.
    """

    pose: np.ndarray
    iterations: int
    n_correspondences_kept: int
    converged: bool
    rmse: float
    hessian: np.ndarray
    n_gmm_fits: int = 0
    mixture: DistanceMixture | None = None


@dataclass
class Correspondences:
    """Nearest-neighbour pairs within the distance gate.

    source_idx (K,): indices into ``source_xy``; moved (K, 2): those points in
    the target frame under the current pose; target (K, 2): their nearest target
    points; distances (K,): ``‖moved - target‖`` (m).
    """

    source_idx: np.ndarray
    moved: np.ndarray
    target: np.ndarray
    distances: np.ndarray


def find_correspondences(
    source_xy: np.ndarray,
    pose: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    max_distance: float,
    workers: int = 1,
) -> Correspondences:
    """Transform the source by ``pose`` and pair each point with its nearest target point.

    Pairs farther than ``max_distance`` (m) are dropped (the tree's
    ``distance_upper_bound`` prunes the search itself).
    """
    moved = transform_points(pose, source_xy)
    dist, idx = target_tree.query(
        moved, k=1, distance_upper_bound=max_distance, workers=workers
    )
    ok = np.isfinite(dist)
    src = np.flatnonzero(ok)
    return Correspondences(src, moved[ok], target_xy[idx[ok]], dist[ok])


def gauss_newton_step(
    moved: np.ndarray,
    target: np.ndarray,
    pose: np.ndarray,
    weights: np.ndarray,
    prior_pose: np.ndarray | None = None,
    prior_information: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One weighted Gauss-Newton step on ``(x, y, θ)`` for point-to-point residuals.

    ``moved`` = ``R p + t`` (K, 2) under ``pose``; residual ``e = moved - target``
    (eq. 24 with the opposite sign); ``∂e/∂(x, y, θ) = [I | (-(Rp)_y, (Rp)_x)]``
    (eq. 25). Returns ``Δ = -(JᵀWJ)⁻¹ JᵀWe`` (eq. 26 as corrected in NOTES.md)
    and ``H = JᵀWJ``. Sums are formed in closed form, no (K, 3) Jacobian.

    Optional Gaussian prior (not in the paper): adds ``(x - x_p)ᵀ Λ (x - x_p)``
    to the cost, i.e. ``H += Λ``, ``g += Λ (x - x_p)`` (yaw difference wrapped).
    ``Λ`` must be in the units of the weighted squared residuals (an inverse
    prior covariance times the residual variance).
    """
    rp = moved - pose[:2]  # R p
    ax, ay = -rp[:, 1], rp[:, 0]  # ∂(Rp)/∂θ
    e = moved - target
    w = weights
    sw = w.sum()
    swax, sway = w @ ax, w @ ay
    h = np.array(
        [
            [sw, 0.0, swax],
            [0.0, sw, sway],
            [swax, sway, w @ (ax * ax + ay * ay)],
        ]
    )
    g = np.array([w @ e[:, 0], w @ e[:, 1], w @ (ax * e[:, 0] + ay * e[:, 1])])
    if prior_pose is not None and prior_information is not None:
        dp = np.asarray(pose, float) - np.asarray(prior_pose, float)
        dp[2] = wrap_angle(dp[2])
        lam = np.asarray(prior_information, float)
        h = h + lam
        g = g + lam @ dp
    try:
        delta = -np.linalg.solve(h, g)
    except np.linalg.LinAlgError:
        delta = -np.linalg.lstsq(h, g, rcond=None)[0]
    return delta, h


def closed_form_pose(source_pts: np.ndarray, target_pts: np.ndarray) -> np.ndarray:
    """Least-squares pose (3,) with ``target ≈ R source + t`` for given pairs (2-D Kabsch).

    ``θ = atan2(Σ p'×q', Σ p'·q')`` on centred pairs, ``t = q̄ - R p̄``.
    """
    pc, qc = source_pts.mean(axis=0), target_pts.mean(axis=0)
    p, q = source_pts - pc, target_pts - qc
    th = np.arctan2(np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]), np.sum(p * q))
    c, s = np.cos(th), np.sin(th)
    t = qc - np.array([c * pc[0] - s * pc[1], s * pc[0] + c * pc[1]])
    return np.array([t[0], t[1], th])


def huber_weights(r: np.ndarray, delta: float) -> np.ndarray:
    """IRLS weights of the Huber kernel: 1 for ``|r| ≤ δ``, ``δ/|r|`` otherwise."""
    a = np.abs(r)
    return np.where(a <= delta, 1.0, delta / np.maximum(a, 1e-300))


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


def _small(step: np.ndarray, p: ICPParams) -> bool:
    return bool(np.hypot(step[0], step[1]) < p.translation_tol and abs(step[2]) < p.rotation_tol)


def register(
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams = ICPParams(),
    mixture: DistanceMixture | None = None,
    prior_pose: np.ndarray | None = None,
    prior_information: np.ndarray | None = None,
) -> ICPResult:
    """Robust ICP: GMMSC weights × Huber weights, Gauss-Newton on SE(2) (eq. 22-26).

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
    if given it is used instead of a first fit (saves one sklearn EM run per
    sweep) and refit only by the ``gmm_refit_ratio`` rule.

    ``prior_pose`` (3,) and ``prior_information`` (3, 3): optional Gaussian prior
    on the pose added to every GN step (see :func:`gauss_newton_step`); it holds
    directions the scan leaves unconstrained (e.g. along a corridor). The
    returned ``hessian`` then includes ``Λ``.
    """
    pose = np.asarray(initial_pose, dtype=float).copy()
    gmm_on = False
    n_fits = 0
    h = np.zeros((3, 3))
    n_kept, rmse, converged = 0, float("nan"), False
    prev_delta: np.ndarray | None = None
    it = 0
    for it in range(1, params.max_iterations + 1):
        c = find_correspondences(
            source_xy, pose, target_tree, target_xy,
            params.max_correspondence_distance, params.workers,
        )
        if c.distances.size < params.min_correspondences:
            break
        w = np.ones(c.distances.size)
        keep = np.ones(c.distances.size, bool)
        if gmm_on:
            med = float(np.median(c.distances))
            r = params.gmm_refit_ratio
            ref = mixture.fit_median if mixture is not None else np.nan
            # NaN reference (unknown): keep the given mixture
            refit = mixture is None or r >= 1.0 or med < r * ref or med * r > ref
            g = gmmsc_weights(c.distances, params.gmmsc, mixture, refit=refit)
            if refit:
                n_fits += g.mixture is not None
                mixture, prev_delta = g.mixture, None
            w, keep = g.weights, g.keep  # eq. 21, w_i < w_th rejected
        if keep.sum() < params.min_correspondences:
            break
        d = c.distances[keep]
        w = w[keep] * huber_weights(d, params.huber_delta)  # W = GMM × Huber (NOTES)
        delta, h = gauss_newton_step(
            c.moved[keep], c.target[keep], pose, w, prior_pose, prior_information
        )
        step = delta
        if params.extrapolate and prev_delta is not None:
            step = delta * _extrapolation_factor(delta, prev_delta, params)
        prev_delta = delta
        pose = pose + step
        pose[2] = wrap_angle(pose[2])
        n_kept, rmse = int(keep.sum()), float(np.sqrt(np.mean(d * d)))
        if params.use_gmmsc and not gmm_on:
            gmm_on = bool(
                np.hypot(delta[0], delta[1]) < params.gmm_start_translation
                and abs(delta[2]) < params.gmm_start_rotation
            )
            if gmm_on:
                prev_delta = None  # new weights: a new fixed point
            continue  # never stop before GMMSC has been applied
        if _small(delta, params):
            converged = True
            break
    return ICPResult(pose, it, n_kept, converged, rmse, h, n_fits, mixture)


def register_point_to_point(
    source_xy: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    initial_pose: np.ndarray,
    params: ICPParams = ICPParams(),
) -> ICPResult:
    """Baseline: classic point-to-point ICP, all gated pairs, unit weights, closed form.

    Same correspondence search and gate as :func:`register`; no GMMSC, no Huber.
    Each iteration solves the pose exactly for the current pairs (2-D Kabsch).
    """
    pose = np.asarray(initial_pose, dtype=float).copy()
    h = np.zeros((3, 3))
    n_kept, rmse, converged = 0, float("nan"), False
    it = 0
    for it in range(1, params.max_iterations + 1):
        c = find_correspondences(
            source_xy, pose, target_tree, target_xy,
            params.max_correspondence_distance, params.workers,
        )
        if c.distances.size < params.min_correspondences:
            break
        src = source_xy[c.source_idx]
        new = closed_form_pose(src, c.target)
        step = new - pose
        step[2] = wrap_angle(step[2])
        pose = new
        n_kept = int(c.distances.size)
        rmse = float(np.sqrt(np.mean(c.distances**2)))
        if _small(step, params):
            converged = True
            break
    if n_kept:  # information matrix of the last pairs at the final pose (unit weights)
        _, h = gauss_newton_step(transform_points(pose, src), c.target, pose, np.ones(n_kept))
    return ICPResult(pose, it, n_kept, converged, rmse, h, 0)
