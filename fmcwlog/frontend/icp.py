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
    residual: the robust variant's residual (robust only: the baseline is point-to-point).
        ``point_to_line``: a pair whose map point lies on a line (its neighbourhood's covariance has
        ``line_eigen_ratio`` or more between its eigenvalues) gives one residual along that line's
        normal, ``n · (R p + t - q)``; the other pairs give the point-to-point residual
        ``R p + t - q``. ``point_to_point``: every pair gives the point-to-point residual (the
        paper's eq. 22). The weights are the same for both (from the point-to-point distance).
        Against a map thinned to one point per voxel, point-to-point pulls each scan point toward
        the voxel's sample, which sits anywhere along a wall: a bias along walls that accumulates
        (docs/methods.md has the measurements).
    line_neighbours: a map point's normal is fitted to its this many nearest map points (itself
        among them; ≥ 3).
    line_eigen_ratio: a map point is on a line where its neighbours' covariance has a larger
        eigenvalue at least this many times the smaller (≥ 1).
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
    residual: str = param("point_to_line", "", choices=("point_to_line", "point_to_point"))
    # 7 points at the map's 5 cm voxels span ~30 cm of wall: long enough to average the range noise,
    # short enough to stay on one side of a corner
    line_neighbours: int = param(7, "points", ge=3, le=100)
    line_eigen_ratio: float = param(9.0, "", ge=1.0, le=1e9)

    @property
    def point_to_line(self) -> bool:
        """Whether the robust variant uses point-to-line residuals on lines (``residual``)."""
        return self.residual == "point_to_line"


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
    h, g = _point_sums(moved, target, pose, weights)
    return _solve(h, g, pose, prior_pose, prior_information)


def _point_sums(moved: np.ndarray, target: np.ndarray, pose: np.ndarray, weights: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """``JᵀWJ`` and ``JᵀWe`` of the point-to-point residuals (:func:`gauss_newton_step`)."""
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
    return h, g


def _solve(h: np.ndarray, g: np.ndarray, pose: np.ndarray, prior_pose: np.ndarray | None,
           prior_information: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The step ``-(H + Λ)⁻¹ (g + Λ (x - x_p))`` and ``H + Λ`` (no prior: ``-H⁻¹ g`` and ``H``)."""
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


def gauss_newton_step_lines(
    moved: np.ndarray,
    target: np.ndarray,
    normals: np.ndarray,
    on_line: np.ndarray,
    pose: np.ndarray,
    weights: np.ndarray,
    prior_pose: np.ndarray | None = None,
    prior_information: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gauss_newton_step` where the pairs ``on_line`` (K,) give one residual along their
    target's unit normal (``normals`` (K, 2), target frame) instead of two: ``r = n · (moved -
    target)``, ``∂r/∂(x, y, θ) = (n_x, n_y, n · (-(Rp)_y, (Rp)_x))``, each weighted by its
    ``weights``. The other pairs are point-to-point, as there. Returns ``Δ`` and ``H = JᵀWJ``
    (+ ``Λ``), as :func:`gauss_newton_step`."""
    if not on_line.any():
        return gauss_newton_step(moved, target, pose, weights, prior_pose, prior_information)
    off = ~on_line
    h, g = _point_sums(moved[off], target[off], pose, weights[off])
    rp = moved[on_line] - pose[:2]
    e = moved[on_line] - target[on_line]
    n = normals[on_line]
    j = np.empty((len(n), 3))
    j[:, :2] = n
    j[:, 2] = n[:, 0] * -rp[:, 1] + n[:, 1] * rp[:, 0]
    r = n[:, 0] * e[:, 0] + n[:, 1] * e[:, 1]
    wj = j * weights[on_line][:, None]
    return _solve(h + wj.T @ j, g + wj.T @ r, pose, prior_pose, prior_information)


def step_is_small(step: np.ndarray, p: ICPParams) -> bool:
    return bool(np.hypot(step[0], step[1]) < p.translation_tol and abs(step[2]) < p.rotation_tol)
