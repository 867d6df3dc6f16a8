"""The sensor's own velocity from one sweep's Doppler field (the physics notes, docs/physics.md).

Frames and units: ``xy`` (N, 2) in the ``lidar`` frame (m); ``v_r`` (N,) radial
Doppler velocity (m/s), positive when the range grows; ``v_sensor`` (2,) the
velocity of the lidar's origin expressed in the lidar frame (m/s).

A static point along the unit bearing ``u`` has ``v_r = -uᵀ v_s`` (the sensor's
rotation about its own origin does not change a range, so only its translation appears).
Moving points are outliers to that two-parameter linear model, so it is fit by
RANSAC on pairs followed by least squares on the inliers. The compensated
velocity ``ε = v_r + uᵀ v_s`` is then ~0 for static points and is what the
segmentation thresholds.

Departure from the paper: Wang et al. threshold the raw ``v_r`` (eq. 18-19), which holds
only while the robot stands still; a moving sensor sees every static point with
``v_r ≠ 0``. The paper estimates no sensor velocity at all; this module is what makes the
threshold on ``ε`` possible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..kernels import compiled


@dataclass
class EgoMotion:
    """Result of :func:`fit_sensor_velocity`.

    v_sensor: (2,) lidar-origin velocity in the lidar frame, m/s (NaN if unfit).
    covariance: (2, 2) covariance of ``v_sensor``, (m/s)².
    inliers: (N,) bool, points consistent with a static world.
    sigma: robust residual standard deviation of the inliers, m/s.
    unconstrained: with a ``prior``, the fit the largest consensus gives when it lies
        outside the prior's gate (the gate changed the answer: a crowd moving together,
        or a prior that is wrong), else None; never itself has an ``unconstrained``.
    """

    v_sensor: np.ndarray
    covariance: np.ndarray
    inliers: np.ndarray
    sigma: float
    unconstrained: EgoMotion | None = None

    @property
    def n_inliers(self) -> int:
        """Points consistent with a static world."""
        return int(self.inliers.sum())


@dataclass
class BaseTwist:
    """Robot twist from the sensor velocity (:func:`base_twist_from_sensor_velocity`).

    v: forward speed of base_link (rear-axle midpoint), m/s.
    omega: yaw rate, rad/s; NaN when the lever arm ``lidar_x`` is too small.
    covariance: (2, 2) covariance of ``(v, omega)``; NaN entries when unobservable.
    well_conditioned: False when ``|lidar_x| < min_lever`` (ω unobservable).
    """

    v: float
    omega: float
    covariance: np.ndarray
    well_conditioned: bool


def _points(a: object) -> bool:
    """Whether ``a`` is what the compiled kernels take as points: a C-contiguous float64 (N, 2) array."""
    return (type(a) is np.ndarray and a.dtype == np.float64 and a.ndim == 2 and a.shape[1] == 2
            and a.flags.c_contiguous)


def unit_bearings(xy: np.ndarray) -> np.ndarray:
    """Unit bearing vectors (N, 2) of points (N, 2); zero-range points give (0, 0).

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (the same
    ``hypot`` and division: the same bits), else :func:`unit_bearings_numpy`."""
    core = compiled.core()
    if core is not None and _points(xy):
        return core.unit_bearings(xy)
    return unit_bearings_numpy(xy)


def unit_bearings_numpy(xy: np.ndarray) -> np.ndarray:
    """:func:`unit_bearings` in numpy: the reference."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        u = xy / r[:, None]
    u[~(r > 0)] = 0.0
    return u


def compensated_velocity(xy: np.ndarray, v_r: np.ndarray, v_sensor: np.ndarray,
                          bearings: np.ndarray | None = None) -> np.ndarray:
    """Ego-motion-compensated radial velocity ``ε = v_r + uᵀ v_s`` (N,), m/s: ~0 for a static point.

    ``xy`` (N, 2) lidar frame (m), ``v_r`` (N,) m/s, ``v_sensor`` (2,) the lidar origin's velocity
    in the lidar frame (m/s). ``bearings``: ``unit_bearings(xy)`` if the caller has them already.
    Numpy either way: two calls (2 µs for 1,000 points), which a compiled call does not beat."""
    u = unit_bearings(xy) if bearings is None else bearings
    return v_r + u @ np.asarray(v_sensor, dtype=float)


def _lstsq_2(u: np.ndarray, v_r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of ``v_r = -u v`` via 2x2 normal equations; returns (v, (AᵀA)⁻¹)."""
    ata = u.T @ u  # A = -u, AᵀA = uᵀu
    atb = -(u.T @ v_r)
    ata_inv = np.linalg.inv(ata)
    return ata_inv @ atb, ata_inv


def usable(u: np.ndarray, v_r: np.ndarray) -> np.ndarray:
    """(N,) points with a finite Doppler and a bearing (not at zero range): ``np.isfinite(v_r) &
    np.any(u != 0, axis=1)``, the two columns compared apart (5 µs for 1,080 points, against 25 µs)."""
    return np.isfinite(v_r) & ((u[:, 0] != 0.0) | (u[:, 1] != 0.0))


def fit_sensor_velocity(
    xy: np.ndarray,
    v_r: np.ndarray,
    *,
    inlier_threshold: float = 0.15,
    n_hypotheses: int = 64,
    min_pair_sine: float = 0.25,
    refinements: int = 2,
    score_points: int = 256,
    random_state: int | np.random.Generator | None = 0,
    prior: np.ndarray | None = None,
    prior_gate: float = 0.3,
    bearings: np.ndarray | None = None,
) -> EgoMotion:
    """Robust fit of the lidar's velocity from static points' Doppler (``v_r = -uᵀ v_s``).

    ``xy`` (N, 2): the sweep's points in the lidar frame (m); ``v_r`` (N,): their radial
    Doppler velocity (m/s, positive when the range grows); non-finite ``v_r`` and zero-range
    points are left out. Returns an :class:`EgoMotion` whose ``v_sensor`` is NaN (and no
    inliers) when fewer than 3 points fit or no pair of bearings is far enough from
    parallel; raises nothing of its own.

    1. RANSAC on pairs: ``n_hypotheses`` random pairs drawn at once; each pair's
       2x2 system ``[-u_i; -u_j] v = [v_ri; v_rj]`` is solved in closed form
       (Cramer), pairs whose bearings are within ``asin(min_pair_sine)`` of
       (anti)parallel are dropped; every hypothesis is scored against all
       points in one (H, N) array and the one with the most inliers
       (``|residual| < inlier_threshold``, m/s) wins; hypotheses are scored
       on a strided subset of ``score_points`` points (enough to rank them).
    2. Least-squares refit on its inliers, re-selection of inliers with the
       same threshold, repeated ``refinements`` times.

    ``prior`` (2,), the sensor velocity predicted by odometry, guards against a
    crowd moving together outvoting the static world: it is one more
    hypothesis, and hypotheses farther than ``prior_gate`` (m/s) from it are
    discarded. Without a prior the largest consensus wins, whatever it is.
    When the gate discards a larger consensus than the one it keeps, that one is
    refit too and returned as ``unconstrained``: it is how a wrong prior (wheels
    counting the wrong way) or a wrong Doppler sign shows (:mod:`.sensor_checks`).
    Every hypothesis is scored either way, so the check costs a second refit only
    on sweeps where the gate changed the answer.

    ``inlier_threshold`` should be several σ of the Doppler noise: with 0.1 m/s
    quantisation σ ≈ 0.03 m/s, so 0.15 m/s. The covariance is ``σ² (AᵀA)⁻¹``
    on the inliers. Deterministic for a fixed ``random_state``. ``bearings``: ``unit_bearings(xy)``
    if the caller has them already (the front end uses them again for ``ε``).

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call; the pairs
    drawn here by numpy's generator, so the same hypotheses, inliers and scores; the velocity and
    covariance to rounding), else :func:`fit_sensor_velocity_numpy`.
    """
    args: dict[str, Any] = dict(inlier_threshold=inlier_threshold, n_hypotheses=n_hypotheses, min_pair_sine=min_pair_sine,
                refinements=refinements, score_points=score_points, random_state=random_state, prior=prior,
                prior_gate=prior_gate, bearings=bearings)
    core = compiled.core()
    if core is None:
        return fit_sensor_velocity_numpy(xy, v_r, **args)
    xy = np.ascontiguousarray(xy, dtype=float)
    v_r = np.ascontiguousarray(v_r, dtype=float)
    given = None if prior is None else np.asarray(prior, dtype=float).tolist()
    if (score_points == 0 or xy.ndim != 2 or xy.shape[1] != 2 or v_r.shape != xy.shape[:1]
            or not (bearings is None or (_points(bearings) and bearings.shape == xy.shape))
            or not (given is None or (isinstance(given, list) and len(given) == 2))):
        return fit_sensor_velocity_numpy(xy, v_r, **args)
    fixed = tuple(given) if given is not None and all(map(math.isfinite, given)) else None  # has_prior

    def draws(n_usable: int) -> np.ndarray:
        return _draws(random_state, n_usable, n_hypotheses)

    fit, gate_changed, free = core.fit_sensor_velocity(
        xy, v_r, bearings, draws, inlier_threshold, min_pair_sine, refinements, score_points, fixed, prior_gate)
    ego = _failed(len(v_r)) if fit is None else EgoMotion(*fit)
    if gate_changed:
        ego.unconstrained = _failed(len(v_r)) if free is None else EgoMotion(*free)
    return ego


def fit_sensor_velocity_numpy(
    xy: np.ndarray,
    v_r: np.ndarray,
    *,
    inlier_threshold: float = 0.15,
    n_hypotheses: int = 64,
    min_pair_sine: float = 0.25,
    refinements: int = 2,
    score_points: int = 256,
    random_state: int | np.random.Generator | None = 0,
    prior: np.ndarray | None = None,
    prior_gate: float = 0.3,
    bearings: np.ndarray | None = None,
) -> EgoMotion:
    """:func:`fit_sensor_velocity` in numpy: the reference the compiled kernel is tested against."""
    xy = np.asarray(xy, dtype=float)
    v_r = np.asarray(v_r, dtype=float)
    n = xy.shape[0]
    failed = _failed(n)
    u = unit_bearings_numpy(xy) if bearings is None else bearings
    valid = usable(u, v_r)
    if valid.sum() < 3:
        return failed
    rng = _generator(random_state)
    idx = np.flatnonzero(valid)
    ij = idx[rng.integers(0, idx.size, size=(n_hypotheses, 2))]
    ui, uj = u[ij[:, 0]], u[ij[:, 1]]
    det = ui[:, 0] * uj[:, 1] - ui[:, 1] * uj[:, 0]  # = sin of the angle between bearings
    ok = np.abs(det) > min_pair_sine
    if not ok.any():
        return failed
    ui, uj, det = ui[ok], uj[ok], det[ok]
    bi, bj = -v_r[ij[ok, 0]], -v_r[ij[ok, 1]]  # u·v = -v_r
    # Cramer's rule on [[ui_x, ui_y], [uj_x, uj_y]] v = [bi, bj]
    hyp = np.stack(
        [(bi * uj[:, 1] - bj * ui[:, 1]) / det, (ui[:, 0] * bj - uj[:, 0] * bi) / det], -1
    )
    has_prior = prior is not None and bool(np.all(np.isfinite(prior)))
    if has_prior:
        hyp = np.vstack([hyp, np.asarray(prior, dtype=float)[None, :]])
    sc = idx[:: max(1, idx.size // score_points)]  # strided subset for scoring
    res = v_r[sc][None, :] + hyp @ u[sc].T  # (H, n_score) residuals ε
    score = (np.abs(res) < inlier_threshold).sum(axis=1)
    if not has_prior:
        return _refine(u, v_r, valid, hyp[int(np.argmax(score))], inlier_threshold, refinements)
    in_gate = np.hypot(*(hyp - prior).T) <= prior_gate  # the prior itself always passes
    best = int(np.argmax(np.where(in_gate, score, -1)))
    fit = _refine(u, v_r, valid, hyp[best], inlier_threshold, refinements)
    free = int(np.argmax(score[:-1])) if len(score) > 1 else best
    if not in_gate[free] and score[free] > score[best]:  # the gate changed the answer: say what it hid
        fit.unconstrained = _refine(u, v_r, valid, hyp[free], inlier_threshold, refinements)
    return fit


_SEEDED: dict[int, tuple[np.random.Generator, Any]] = {}  # seed: (generator, its seeded state)


def _generator(random_state: int | np.random.Generator | None) -> np.random.Generator:
    """``np.random.default_rng(random_state)``; for an integer seed, one generator per seed put back
    to its seeded state: the same draws, for 20 instead of 67 µs a sweep (seeding hashes the seed)."""
    if not isinstance(random_state, (int, np.integer)) or isinstance(random_state, bool):
        return np.random.default_rng(random_state)
    seed = int(random_state)
    if seed not in _SEEDED:
        rng = np.random.default_rng(seed)
        _SEEDED[seed] = (rng, rng.bit_generator.state)
    rng, state = _SEEDED[seed]
    rng.bit_generator.state = state
    return rng


_DRAWS: dict[tuple[int, int, int], np.ndarray] = {}  # (seed, usable points, hypotheses): the pairs
_DRAWS_KEPT = 4096


def _draws(random_state: int | np.random.Generator | None, n_usable: int, n_hypotheses: int) -> np.ndarray:
    """The pairs' positions (H, 2) among the ``n_usable`` usable points: ``rng.integers(0, n_usable,
    size=(n_hypotheses, 2))`` of :func:`_generator`, as :func:`fit_sensor_velocity_numpy` draws them.
    An integer seed puts the generator back to its seeded state every fit, so its draws depend on
    ``(seed, n_usable, n_hypotheses)`` alone and are kept (read-only) for the next sweep of that size."""
    if not isinstance(random_state, (int, np.integer)) or isinstance(random_state, bool):
        return _generator(random_state).integers(0, n_usable, size=(n_hypotheses, 2))
    key = (int(random_state), n_usable, n_hypotheses)
    pairs = _DRAWS.get(key)
    if pairs is None:
        if len(_DRAWS) >= _DRAWS_KEPT:
            _DRAWS.clear()
        pairs = _generator(random_state).integers(0, n_usable, size=(n_hypotheses, 2))
        pairs.setflags(write=False)
        _DRAWS[key] = pairs
    return pairs


def _failed(n: int) -> EgoMotion:
    return EgoMotion(np.full(2, np.nan), np.full((2, 2), np.nan), np.zeros(n, bool), float("nan"))


def _refine(u: np.ndarray, v_r: np.ndarray, valid: np.ndarray, v: np.ndarray, inlier_threshold: float,
            refinements: int) -> EgoMotion:
    """Least squares on the inliers of ``v``, re-selected ``refinements`` times (step 2 above)."""
    failed = _failed(len(v_r))
    try:
        for _ in range(max(1, refinements)):
            eps = v_r + u @ v
            inliers = valid & (np.abs(eps) < inlier_threshold)
            if inliers.sum() < 3:
                return failed
            v, ata_inv = _lstsq_2(u[inliers], v_r[inliers])
            fitted = inliers
        eps = v_r + u @ v
        inliers = valid & (np.abs(eps) < inlier_threshold)
        if inliers.sum() < 3:
            return failed
        if not np.array_equal(inliers, fitted):  # else (AᵀA)⁻¹ of these inliers is the one in hand
            _, ata_inv = _lstsq_2(u[inliers], v_r[inliers])
    except np.linalg.LinAlgError:  # inliers along a single bearing: v_s unobservable
        return failed
    dof = max(int(inliers.sum()) - 2, 1)
    sigma = float(np.sqrt(np.sum(eps[inliers] ** 2) / dof))
    return EgoMotion(v, sigma**2 * ata_inv, inliers, sigma)


MAD_SIGMA = 1.4826  # a normal distribution's standard deviation per median absolute deviation


def refit_static(u: np.ndarray, v_r: np.ndarray, fit: EgoMotion, moving: np.ndarray, *,
                 min_threshold: float = 0.15, scale_gate: float = 3.0, refinements: int = 2) -> EgoMotion:
    """The fit again, without the points judged moving, its inlier gate from the sweep's own spread.

    ``u`` (N, 2): unit bearings (lidar frame); ``v_r`` (N,): radial Doppler velocity (m/s; NaN
    left out); ``fit``: :func:`fit_sensor_velocity`'s result; ``moving`` (N,) bool: the points the
    segmentation judged moving, whatever their Doppler. Returns ``fit`` unchanged where it failed,
    where fewer than 3 points remain, or where the first fit's gate holds two standard deviations
    of the sweep's spread (``s <= min_threshold / 2``, ``s`` below). That is a Doppler as fine as
    the paper's Table 1, whose first fit the segmentation and the ICP were tuned on: on the 60 s
    ``crowd`` log (seed 0) ``s`` is at most 0.062 m/s, against 0.092 to 0.149 m/s on 99 % of the
    sweeps with bench/sensors/worse-doppler.toml.

    Two things bias the first fit where the Doppler is coarse. Movers walking near the static
    world's velocity pass its fixed gate (``inlier_threshold``) and pull it their way, while
    the segmentation, which sees them move from sweep to sweep (tracks, free space), knows them.
    And a gate narrower than the sweep's residual spread truncates it: the residuals of a
    quantised Doppler fall in clumps a step apart, so a narrow window holds more of one clump
    than of the next and the fit leans toward it. Here each of ``refinements`` rounds keeps the
    static points within ``max(min_threshold, scale_gate * s)`` of the fit (``s``:
    ``MAD_SIGMA`` times the median absolute deviation of the static points' residuals about
    their median, m/s) and solves least squares on them. The covariance is ``σ² (AᵀA)⁻¹`` as in
    :func:`fit_sensor_velocity`; ``inliers`` are the points of the last solve.
    """
    if not (np.all(np.isfinite(fit.v_sensor)) and fit.inliers.any()):
        return fit
    if fit.sigma < 0.35 * min_threshold:
        # A spread of min_threshold / 2 seen through the first fit's gate of min_threshold (2 sigmas)
        # reads 0.88 of itself (a truncated normal): a first fit whose inliers spread less than
        # 0.7 of that (0.053 m/s) needs no look at the whole sweep. It saves the medians on every
        # sweep of a fine Doppler (0.035 m/s median on the crowd; 0.065-0.084 with worse-doppler.toml).
        return fit
    static = usable(u, v_r) & ~moving
    v = fit.v_sensor
    inliers = fit.inliers & static
    try:
        for k in range(max(1, refinements)):
            eps = v_r + u @ v
            res = eps[static]
            spread = MAD_SIGMA * float(np.median(np.abs(res - np.median(res)))) if res.size else 0.0
            if k == 0 and not spread > 0.5 * min_threshold:
                return fit  # the first fit's gate holds 2 sigmas of this sweep's spread: that fit stands
            inliers = static & (np.abs(eps) < max(min_threshold, scale_gate * spread))
            if inliers.sum() < 3:
                return fit
            v, ata_inv = _lstsq_2(u[inliers], v_r[inliers])
    except np.linalg.LinAlgError:  # inliers along a single bearing
        return fit
    eps = v_r[inliers] + u[inliers] @ v
    sigma = float(np.sqrt(np.sum(eps**2) / max(int(inliers.sum()) - 2, 1)))
    return EgoMotion(v, sigma**2 * ata_inv, inliers, sigma)


def sensor_velocity_from_base_twist(
    v: float, omega: float, lidar_x: float, lidar_y: float, lidar_yaw: float
) -> np.ndarray:
    """Velocity (2,) (m/s) of the lidar origin in the lidar frame for base twist (v, ω), v_by = 0.

    ``v`` m/s, ``omega`` rad/s, mount in base_link (m, m, rad). In base_link axes
    ``v_s = v_b + ω × l = (v - ω l_y, ω l_x)``, then rotated by ``-l_yaw``.
    """
    vb = np.array([v - omega * lidar_y, omega * lidar_x])
    c, s = np.cos(lidar_yaw), np.sin(lidar_yaw)
    return np.array([c * vb[0] + s * vb[1], -s * vb[0] + c * vb[1]])


def base_twist_from_sensor_velocity(
    v_sensor: np.ndarray,
    lidar_x: float,
    lidar_y: float,
    lidar_yaw: float,
    covariance: np.ndarray | None = None,
    min_lever: float = 0.05,
) -> BaseTwist:
    """Invert :func:`sensor_velocity_from_base_twist` using ``v_by = 0``.

    ``v_sensor`` (2,) in the lidar frame (m/s); mounting in base_link (m, rad).
    With ``w = R(l_yaw) v_s`` (base_link axes): ``ω = w_y / l_x``,
    ``v = w_x + ω l_y``. Ill-conditioned as ``l_x → 0`` (ω ∝ 1/l_x): when
    ``|l_x| < min_lever`` ω is NaN; ``v`` is then ``w_x`` if ``|l_y| < min_lever``
    (error ``ω l_y``), else NaN. The covariance is propagated linearly from
    ``covariance`` (2x2 of ``v_sensor``) if given, else NaN.
    The constraint fails when the rear wheels slide sideways: treat
    the result as a measurement, not truth. The front end does not invert the
    mount this way (it has no answer over the axle); it fuses Doppler with the
    wheels instead (:mod:`.twist_fusion`).
    """
    c, s = np.cos(lidar_yaw), np.sin(lidar_yaw)
    rot = np.array([[c, -s], [s, c]])
    w = rot @ np.asarray(v_sensor, dtype=float)
    if abs(lidar_x) < min_lever:
        v = float(w[0]) if abs(lidar_y) < min_lever else float("nan")
        cov = np.full((2, 2), np.nan)
        if covariance is not None and np.isfinite(v):
            cov[0, 0] = (rot @ covariance @ rot.T)[0, 0]
        return BaseTwist(v, float("nan"), cov, False)
    omega = w[1] / lidar_x
    v = w[0] + omega * lidar_y
    if covariance is None:
        cov = np.full((2, 2), np.nan)
    else:
        jac = np.array([[1.0, lidar_y / lidar_x], [0.0, 1.0 / lidar_x]]) @ rot
        cov = jac @ np.asarray(covariance, dtype=float) @ jac.T
    return BaseTwist(float(v), float(omega), cov, True)
