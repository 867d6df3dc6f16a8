"""What both ICP variants share: parameters, result, one Gauss-Newton step.

Frames and units: ``source_xy`` (N, 2) in the source frame (e.g. the de-skewed
frame of a sweep, m); ``target_xy`` (M, 2) in the target frame (e.g. ``map``);
poses ``(x, y, θ)`` map source into target (``q ≈ R(θ) p + t``,
:func:`fmcwlog.geometry.transform_points`). The caller builds the target's
``cKDTree`` once and passes it in; the pairs come from :mod:`fmcwlog.kernels.nearest`.

The variants: :mod:`fmcwlog.frontend.robust_icp` (the paper's, eq. 22-26) and
:mod:`fmcwlog.frontend.point_to_point_icp` (the classic baseline).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import Checked, param
from ..geometry import wrap_angle
from ..kernels.compiled import CompiledNearest
from ..kernels.nearest import NearestPairs
from .gmmsc import DistanceMixture, GMMSCParams


@dataclass(frozen=True)
class ICPParams(Checked):
    """Parameters shared by :func:`register` and :func:`register_point_to_point`.

    max_iterations: iteration cap.
    max_correspondence_distance: pairs farther apart are dropped (m).
    translation_tol, rotation_tol: stop when a step is below both (m, rad).
    min_correspondences: fewer usable pairs aborts (converged=False).
    huber_delta: Huber threshold δ on the residual norm (m); robust only.
    use_huber: weight residuals by the Huber kernel (robust only; False = plain least squares).
    use_gmmsc: apply GMMSC weights/rejection (robust only; False = Huber only).
    gmmsc: parameters of the distance mixture.
    gmm_start_translation, gmm_start_rotation: GMMSC starts once a (Huber-only)
        step is below both (m, rad); see :func:`register`.
    gmm_refit_ratio: after the first fit the mixture is refit only when the
        median pair distance leaves ``[r, 1/r] ×`` the median the mixture was
        fit to (``DistanceMixture.fit_median``; this also applies to a mixture
        reused from a previous sweep); otherwise eq. 21 is just evaluated with
        the last mixture (~0.05 ms instead of an EM run).
        ≥ 1 refits every iteration.
    extrapolate, max_extrapolation, extrapolation_min_cos, extrapolation_lever:
        step extrapolation of the robust variant (``_extrapolation_factor``);
        halves the iterations in our tests at unchanged accuracy.
    workers: threads for the KD-tree query (1: the per-sweep budget is tiny).
    """

    max_iterations: int = param(30, "", ge=1, le=1000)
    max_correspondence_distance: float = param(0.5, "m", gt=0.0, le=100.0)
    # tolerances: a zero tolerance never stops before max_iterations; 1 m / 1 rad steps are not convergence
    translation_tol: float = param(1e-4, "m", gt=0.0, le=1.0)
    rotation_tol: float = param(5e-5, "rad", gt=0.0, le=1.0)
    # fewer than 2 pairs leave the 3 unknowns of an SE(2) step undetermined
    min_correspondences: int = param(10, "pairs", ge=2, le=1_000_000)
    # δ beyond 1 m makes the kernel plain least squares for any pair the 0.5 m gate lets through
    huber_delta: float = param(0.05, "m", gt=0.0, le=1.0)
    use_huber: bool = True
    use_gmmsc: bool = True
    gmmsc: GMMSCParams = field(default_factory=GMMSCParams)
    gmm_start_translation: float = param(2e-3, "m", gt=0.0, le=1.0)
    gmm_start_rotation: float = param(2e-3, "rad", gt=0.0, le=1.0)
    gmm_refit_ratio: float = param(0.25, "", gt=0.0, le=1.0)  # 1 refits every iteration; above 1 means the same
    extrapolate: bool = True
    max_extrapolation: float = param(10.0, "", ge=0.0, le=100.0)  # extra steps; 0 never extrapolates
    extrapolation_min_cos: float = param(0.9, "", ge=-1.0, le=1.0)
    extrapolation_lever: float = param(3.0, "m", ge=0.0, le=100.0)  # turns rad into m to compare steps
    workers: int = param(1, "threads", ge=1, le=1024)  # scipy's -1 (all cores) is not offered: sweeps are tiny


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
    search: the registration's correspondence search: the nearest map distances at the final
        pose from it (:meth:`NearestPairs.nearest`) cost few or no new queries.
    """

    pose: np.ndarray
    iterations: int
    n_correspondences_kept: int
    converged: bool
    rmse: float
    hessian: np.ndarray
    n_gmm_fits: int = 0
    mixture: DistanceMixture | None = None
    search: NearestPairs | CompiledNearest | None = None


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
    (eq. 25). Returns ``Δ = -(JᵀWJ)⁻¹ JᵀWe`` (eq. 26 with the ``Jᵀ`` the paper drops; docs/physics.md)
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


def step_is_small(step: np.ndarray, p: ICPParams) -> bool:
    return bool(np.hypot(step[0], step[1]) < p.translation_tol and abs(step[2]) < p.rotation_tol)
