"""GMMSC false-match rejection on correspondence distances (paper §4.2, eq. 20-21).

Units: distances in metres (any non-negative scale works). A K-component 1-D
Gaussian mixture (eq. 20) is fit by EM (:func:`_em_1d`: sklearn's
``GaussianMixture`` algorithm, diagonal covariances, written out for one
dimension: a few (K, N) array operations per iteration, 0.03-0.1 ms a fit where
sklearn's takes 1-3 ms and 1.5 s of imports; ``tests/unit/frontend/test_gmmsc.py`` checks it
against sklearn); each pair is weighted by its posterior of the inlier component (eq. 21). The
paper leaves ``k`` in eq. 21 open; here it is the inlier component, the one with the
smallest mean distance (the physics notes, docs/physics.md). Pairs with weight below
``w_th`` are rejected.

Two additions to eq. 21, stated here because they change results.

1. Unimodal data. Fit to a single population (no outliers; residual norms are
   half-normal/Rayleigh-like, skewed), a 2-component mixture splits it into a
   "near" and a "far" part and eq. 21 would reject a third to a half of the
   good pairs. A component is only treated as outliers if most of its mass
   lies beyond the inlier component's band ``μ₁ + 3σ₁``; components with more
   than ``merge_overlap`` (default 0.2) of their mass inside that band are
   counted with the inlier component, and ``w_i`` is the summed posterior of
   that group. (Measured: split single populations put 0.35-0.7 of the far
   component inside the band, true outlier components < 0.05.)
   ``merge_overlap ≥ 1`` gives plain eq. 21.
2. Monotonicity. The weight is made non-increasing in the distance. A raw
   Gaussian posterior can *drop* for distances below the inlier mean (a
   narrow inlier Gaussian centred at μ₁ > 0 is less dense at d = 0 than a
   broad outlier one) and can rise again far out when the outlier component
   is the narrower one. We evaluate the posterior at ``max(d, μ₁)`` and take
   the running minimum over increasing distance, so a closer pair is never
   less credible than a farther one.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..config import Checked, param


@dataclass(frozen=True)
class GMMSCParams(Checked):
    """Parameters of the distance mixture.

    n_components: K in eq. 20 (1 disables rejection: every weight is 1).
    w_th: rejection threshold on the inlier posterior w_i.
    max_iter, tol: EM budget: stop when the mean log-likelihood per sample changes by less than ``tol``.
    min_pairs: below this many pairs no mixture is fit and all weights are 1.
    min_spread: distances spanning less than this (m) are "all equal": weights 1.
    merge_overlap: a component with more than this fraction of its mass below
        ``μ₁ + 3σ₁`` joins the inlier group (module docstring); ≥ 1 disables.
    reg_covar: variance floor added to each component's variance, m².
    max_fit_samples: distances used for the EM fit (strided subsample; weights
        are still computed for all pairs). Keeps the fit cost bounded.
    random_state: accepted so that config files that set it still load; the fit
        draws nothing (its initial guess is deterministic).
    """

    n_components: int = param(2, "", ge=1, le=10)
    w_th: float = param(0.5, "", ge=0.0, le=1.0)  # a posterior
    max_iter: int = param(10, "", ge=1, le=10_000)
    tol: float = param(1e-3, "", gt=0.0, le=1.0)
    min_pairs: int = param(10, "pairs", ge=1, le=1_000_000)
    min_spread: float = param(1e-9, "m", ge=0.0, le=1.0)
    merge_overlap: float = param(0.2, "", ge=0.0, le=1.0)  # a fraction of mass; 1 disables merging
    # a negative floor is no variance, and 0 lets a component collapse onto one distance
    reg_covar: float = param(1e-10, "m^2", gt=0.0, le=1.0)
    max_fit_samples: int = param(500, "pairs", ge=2, le=10_000_000)
    random_state: int = param(0, "", ge=0, le=2**32 - 1)  # unused: EM draws nothing


@dataclass(frozen=True)
class DistanceMixture:
    """A fitted 1-D mixture (eq. 20): means, standard deviations, mixing weights (K,).

    merge_overlap: threshold defining the inlier group (module docstring).
    fit_median: median of the distances it was fit to (m); lets a user of a
        stored mixture decide when the distance scale has moved away from it.
    """

    means: np.ndarray
    sigmas: np.ndarray
    mix: np.ndarray
    merge_overlap: float = 0.2
    fit_median: float = float("nan")

    # the mixture is fixed once made: what eq. 21 needs of it alone is worked out once (cached_property
    # writes the instance's __dict__, which a frozen dataclass allows), not at every ICP iteration
    @cached_property
    def inlier(self) -> int:
        """Index of the inlier component: the smallest mean (eq. 21's ``k``, which the paper leaves open)."""
        return int(np.argmin(self.means))

    @cached_property
    def _log_scale(self) -> np.ndarray:
        """(K, 1) ``log π_k - log σ_k``, eq. 20's constant part per component."""
        return (np.log(self.mix) - np.log(self.sigmas))[:, None]

    @cached_property
    def inlier_group(self) -> np.ndarray:
        """Bool (K,): the inlier component and those overlapping its 3σ band."""
        i = self.inlier
        band = self.means[i] + 3.0 * self.sigmas[i]
        from scipy.special import ndtr  # here, not at import: scipy.special is 0.07 s of imports

        inside = ndtr((band - self.means) / self.sigmas)  # mass of each below the band
        group = inside > self.merge_overlap
        group[i] = True
        return group

    def posterior(self, distances: np.ndarray) -> np.ndarray:
        """Eq. 21: summed posterior of the inlier group at each distance (N,).

        With ``merge_overlap ≥ 1`` the group is the inlier component alone.
        """
        d = np.asarray(distances, dtype=float)[None, :]
        # (K, N) layout: reductions run over the short K axis row by row (fast in numpy)
        z = (d - self.means[:, None]) / self.sigmas[:, None]
        logp = self._log_scale - 0.5 * z * z
        logp -= np.maximum.reduce(logp, axis=0)
        p = np.exp(logp)
        group = self.inlier_group
        return np.add.reduce(p[group], axis=0) / np.add.reduce(p, axis=0)

    def weights(self, distances: np.ndarray) -> np.ndarray:
        """Eq. 21 made non-increasing in the distance (see module docstring), (N,)."""
        d = np.asarray(distances, dtype=float)
        if d.size == 0:
            return np.zeros(0)
        w = self.posterior(np.maximum(d, self.means[self.inlier]))
        order = np.argsort(d, kind="stable")
        out = np.empty_like(w)
        out[order] = np.minimum.accumulate(w[order])
        return out


@dataclass
class GMMSCResult:
    """Weights (N,) in [0, 1], keep mask (N,) = weights ≥ w_th, the mixture (None if not fit)."""

    weights: np.ndarray
    keep: np.ndarray
    mixture: DistanceMixture | None


def _initial_guess(d: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Deterministic init: means at spread quantiles, variances of the nearest-mean groups."""
    q = np.linspace(0.2, 0.9, k) if k > 1 else np.array([0.5])
    means = np.quantile(d, q)
    means = means + np.arange(k) * 1e-9 * max(float(np.ptp(d)), 1.0)  # keep them distinct
    group = np.argmin(np.abs(d[:, None] - means[None, :]), axis=1)
    floor = (1e-3 * max(float(np.ptp(d)), 1e-9)) ** 2
    var = np.array(
        [max(float(np.var(d[group == j])) if np.any(group == j) else 0.0, floor) for j in range(k)]
    )
    mix = np.full(k, 1.0 / k)
    return means, var, mix


_EPS10 = 10 * np.finfo(float).eps  # sklearn's guard against an empty component


def _em_1d(d: np.ndarray, means: np.ndarray, var: np.ndarray, mix: np.ndarray, max_iter: int, tol: float,
           reg_covar: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EM for a K-component 1-D Gaussian mixture from (means, variances, weights) (K,) on samples ``d`` (N,).

    The steps of ``sklearn.mixture.GaussianMixture(covariance_type="diag")`` for one
    feature: E-step log-responsibilities by log-sum-exp, M-step weighted moments with
    ``reg_covar`` added to the variances; stop when the mean log-likelihood per sample
    moves by less than ``tol`` or after ``max_iter`` iterations. Returns the final
    (means, variances, weights) (K,).
    """
    log_2pi = np.log(2.0 * np.pi)
    lower = -np.inf
    dd = d * d
    for _ in range(max_iter):
        # E-step, (K, N): log(π_k N(d | μ_k, σ_k²))
        z = d[None, :] - means[:, None]
        logp = (np.log(mix) - 0.5 * (log_2pi + np.log(var)))[:, None] - 0.5 * z * z / var[:, None]
        top = np.maximum.reduce(logp, axis=0)
        norm = top + np.log(np.add.reduce(np.exp(logp - top), axis=0))
        resp = np.exp(logp - norm)
        # M-step
        nk = resp.sum(axis=1) + _EPS10
        means = (resp @ d) / nk
        var = (resp @ dd) / nk - means * means + reg_covar
        mix = nk / nk.sum()
        prev, lower = lower, float(norm.mean())
        if abs(lower - prev) < tol:
            break
    return means, var, mix


def fit_distance_mixture(
    distances: np.ndarray,
    params: GMMSCParams = GMMSCParams(),
    init: DistanceMixture | None = None,
) -> DistanceMixture | None:
    """EM fit of eq. 20 to distances (N,), m; None when degenerate (fewer than
    ``max(min_pairs, n_components)`` finite distances, or all within ``min_spread``).

    Non-finite distances are left out. ``init`` warm-starts EM from a previous fit (e.g. the
    previous ICP iteration) when it has ``n_components`` components. Raises nothing of its own.
    """
    d = np.asarray(distances, dtype=float)
    d = d[np.isfinite(d)]
    k = params.n_components
    if d.size < max(params.min_pairs, k) or np.ptp(d) < params.min_spread:
        return None
    if d.size > params.max_fit_samples:
        d = d[:: int(np.ceil(d.size / params.max_fit_samples))]
    if init is not None and init.means.shape == (k,):
        means, var, mix = init.means, np.maximum(init.sigmas**2, params.reg_covar), init.mix
    else:
        means, var, mix = _initial_guess(d, k)
    means, var, mix = _em_1d(d, means, var, mix / mix.sum(), params.max_iter, params.tol, params.reg_covar)
    return DistanceMixture(
        means=means,
        sigmas=np.sqrt(var),
        mix=mix,
        merge_overlap=params.merge_overlap,
        fit_median=float(np.median(d)),
    )


def gmmsc_weights(
    distances: np.ndarray,
    params: GMMSCParams = GMMSCParams(),
    mixture: DistanceMixture | None = None,
    refit: bool = True,
) -> GMMSCResult:
    """Weights and keep mask of correspondence pairs from their distances (N,), m (eq. 20-21).

    With ``refit`` a mixture is fit (warm-started from ``mixture`` if given);
    without it the given ``mixture`` is only evaluated (eq. 21), which costs
    microseconds instead of an EM run. Degenerate inputs (fewer than
    ``min_pairs``, all distances equal, K = 1) give weights 1 and keep all.
    """
    d = np.asarray(distances, dtype=float)
    if refit:
        mixture = fit_distance_mixture(d, params, init=mixture)
    if mixture is None or params.n_components == 1:
        ones = np.ones(d.shape[0])
        return GMMSCResult(ones, np.ones(d.shape[0], bool), mixture)
    w = mixture.weights(d)
    return GMMSCResult(w, w >= params.w_th, mixture)
