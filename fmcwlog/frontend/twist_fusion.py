"""The robot's twist from Doppler and the wheels together, at any mount.

Not in the paper (Wang et al. use Doppler to segment, and odometry as the prior). With the
lidar at ``l = (l_x, l_y)`` and yaw ``l_yaw`` in base_link, the lidar origin moves at
``v_s = v_b + ω × l`` (base_link axes); with the rear axle not sliding sideways
(``v_by = 0``), the lidar origin's velocity in the lidar frame is (the physics notes,
docs/physics.md)

    z = A x,   A = R(-l_yaw) [[1, -l_y], [0, l_x]],   x = (v, ω)

``det A = l_x``: ahead of or behind the axle Doppler observes both ``v`` and ``ω``; over
the axle (``l_x = 0``) it observes only ``v - ω l_y`` (its second equation reads
``0 = 0``: it tests ``v_by = 0`` and nothing else). Inverting ``A`` blows up as
``l_x → 0`` (over the axle it hands the ICP's prior a NaN). Instead the twist is the
weighted least-squares solution of the two Doppler equations (covariance ``C_d``) together
with the wheels' own ``(v, ω)`` (covariance ``C_w``, :func:`wheel_covariance`):

    x̂ = (Aᵀ C_d⁻¹ A + C_w⁻¹)⁻¹ (Aᵀ C_d⁻¹ z + C_w⁻¹ x_w)

so every component comes from whichever source knows it better, continuously in the
mount: nothing to switch, nothing singular (the wheels' information is positive
definite). Without wheels (none in the log, or found faulty) a constant-velocity "hold"
(the method's own last scan-matched twist, with a wide covariance) takes their place.
The share of Doppler in each component is the diagonal of ``P Aᵀ C_d⁻¹ A`` (``P`` the
fused covariance); the wheels' (or hold's) share is the rest, ``diag(P C_w⁻¹)``: the
two sum to one per component (``P (I_d + I_w) = 1``). A per-sweep 2x2 solve.

Why not a filter over time: each sweep's twist stays independent of the last, so a bad
sweep cannot leak into the next; the pose's memory is the ICP's map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Checked, param
from ..kernels import compiled


@dataclass(frozen=True)
class WheelNoise(Checked):
    """How far the wheels' (or an Odometry topic's) twist over one sweep is trusted.

    speed_rel: standard deviation of ``v`` as a fraction of ``|v|``, in [0, 1]. The wheels'
        error is mostly a bias (radii off by a fraction of a percent), which a per-sweep
        variance cannot express and which does not average out. 0.05: on the 2-minute
        ``long-corridor`` log (seed 0; ``fmcwlog record --scenario long-corridor --duration 120``,
        then ``fmcwlog process --method improved --set wheel_noise.speed_rel=0.01``), at 1 %
        the wheels take 7 % of ``v`` and their -0.4 % bias doubles the improved method's ATE
        in the 100 m bare corridor (2.8 against 1.4 cm); at 5 % it is 1.36 cm.
        speed_min: its floor (m/s; tick quantisation), > 0.
    yaw_rate_per_speed: standard deviation of ``ω`` per m/s of speed (rad/m), >= 0; 0.05
        for the same reason (a 0.2 % difference of the radii over a 0.45 m track is a
        0.0044 rad/m bias). yaw_rate_min: its floor (rad/s), > 0.
    hold_speed, hold_yaw_rate: standard deviations of the constant-velocity hold used
        when there are no wheels (m/s, rad/s), > 0: wide, so Doppler and the scans decide.
    adapt_rate: weight of each sweep in the exponentially weighted mean squares of
        :class:`ObservedNoise` (0..1; about ``1 / adapt_rate`` sweeps remembered); 0 keeps the
        nominal weights above and the fit's own covariance. 0.02.
    adapt_gate: the weights move once Doppler's observed mean-square error exceeds this multiple
        of the variance its fits claim (the mean of the ``v`` and ``ω`` ratios), and return to the
        nominal ones below half of it (>= 1). There, Doppler's variance is the larger of the fit's
        claim and what the sweeps show, the wheels' the smaller of the above and what they show
        (floored at ``speed_min``, ``yaw_rate_min``). 6.5: on the 60 s ``crowd`` logs (seeds 0-2)
        the nominal Doppler errs up to 5.6 times (in variance) what it claims, and keeps the
        nominal weights; a coarse Doppler (bench/sensors/worse-doppler.toml: noise 0.1 m/s,
        0.25 m/s steps) claims a few mm/s, errs 2 cm/s, 12-20 times its claim (at least 4.9), and
        the nominal weights take it almost whole.
    adapt_min_sweeps: sweeps compared before the weights may move (>= 1). 10: the ratio of the
        nominal Doppler over its first 3 to 5 sweeps reaches 6.7.
    """

    speed_rel: float = param(0.05, "", ge=0, le=1)
    speed_min: float = param(0.005, "m/s", gt=0, le=10)
    yaw_rate_per_speed: float = param(0.05, "rad/m", ge=0, le=10)
    yaw_rate_min: float = param(0.01, "rad/s", gt=0, le=10)
    hold_speed: float = param(0.5, "m/s", gt=0, le=100)
    hold_yaw_rate: float = param(0.5, "rad/s", gt=0, le=100)
    adapt_rate: float = param(0.02, "", ge=0, le=1)
    adapt_gate: float = param(6.5, "", ge=1, le=1e6)
    adapt_min_sweeps: int = param(10, "sweeps", ge=1, le=1000000)


@dataclass(frozen=True)
class FusedTwist:
    """The fused ``(v, ω)`` of base_link (m/s, rad/s), its (2, 2) covariance, and where it came from.

    doppler_share: (2,) Doppler's share of the information in ``v`` and ``ω`` (0..1;
        the wheels or the hold have the rest).
    chi2: ``(z - A x̂)ᵀ C_d⁻¹ (z - A x̂) + (x_w - x̂)ᵀ C_w⁻¹ (x_w - x̂)``, the disagreement
        of the sources (2 degrees of freedom), NaN without Doppler.
    """

    twist: np.ndarray
    covariance: np.ndarray
    doppler_share: np.ndarray
    chi2: float


def doppler_design(mount: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """``A`` (2, 2): the lidar's velocity in its frame per unit ``(v, ω)`` of base_link (v_by = 0).

    ``mount``: ``(lidar_x, lidar_y, lidar_yaw)``, the lidar in base_link (m, m, rad).
    """
    lx, ly, yaw = (float(m) for m in mount)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, s], [-s, c]]) @ np.array([[1.0, -ly], [0.0, lx]])


def wheel_covariance(twist: tuple[float, float] | np.ndarray, noise: WheelNoise) -> np.ndarray:
    """Diagonal covariance (2, 2) of the wheels' ``(v, ω)`` over one sweep, from :class:`WheelNoise`."""
    speed = abs(float(twist[0]))
    s_v = max(noise.speed_rel * speed, noise.speed_min)
    s_w = max(noise.yaw_rate_per_speed * speed, noise.yaw_rate_min)
    return np.array([[s_v**2, 0.0], [0.0, s_w**2]])  # np.diag's values


def wheel_variances(twist: tuple[float, float], noise: WheelNoise) -> tuple[float, float]:
    """The diagonal of :func:`wheel_covariance` as two floats ((m/s)², (rad/s)²)."""
    speed = abs(float(twist[0]))
    return max(noise.speed_rel * speed, noise.speed_min) ** 2, max(noise.yaw_rate_per_speed * speed,
                                                                   noise.yaw_rate_min) ** 2


def hold_covariance(noise: WheelNoise) -> np.ndarray:
    """Diagonal covariance (2, 2) of the constant-velocity hold's ``(v, ω)`` ((m/s)², (rad/s)²)."""
    return np.diag([noise.hold_speed**2, noise.hold_yaw_rate**2])


class ObservedNoise:
    """What the recent sweeps show of Doppler's and the wheels' error, per component of ``(v, ω)``.

    Three estimates of each sweep's motion, with independent errors, are compared pairwise
    (the "three-cornered hat"): Doppler's ``x_d = A⁻¹ z``, the wheels' ``x_w`` and the
    scan-matched ``x_s`` (pose difference over the interval, known one sweep later). With
    ``D = E(x_d - x_w)²``, ``S_d = E(x_d - x_s)²`` and ``S_w = E(x_w - x_s)²`` (exponentially
    weighted, weight ``rate`` per sweep), Doppler's mean-square error is ``(D + S_d - S_w) / 2``
    and the wheels' ``(D + S_w - S_d) / 2``: the scans' own error (cm/s per sweep, far more
    than either) cancels. Mean squares, not variances: a bias counts. The ICP is held to the
    fused motion, so the scans' error leans toward the source fused most; the hat then
    underrates that source, and the weights move only as far as the evidence pushes them.

    The weights move only on significant evidence (:meth:`adapting`): once ``1 / rate`` sweeps
    are in, and only in a component where Doppler's observed mean square exceeds ``gate`` times
    the variance its fits claimed over the same sweeps (``C``, the same weighting). A Doppler
    that errs as it claims (or a little more) keeps the nominal weights, and so do the wheels.
    A faulty source is not followed: a wheel fault raises the wheels' share of the hat, not
    Doppler's, and wheel variances only ever shrink from the nominal ones.
    """

    STEP = 0.05  # rad/s: a step in the wheels' ω between intervals beyond which one is left out

    def __init__(self, rate: float, gate: float = 1.0, min_sweeps: int = 1) -> None:
        self.last_yaw_rate = math.nan  # the wheels' ω of the last interval given (rad/s)
        self.rate = float(rate)
        self.gate = float(gate)
        self.min_sweeps = int(min_sweeps)
        self.on = False  # whether the weights move (:meth:`_update`)
        # D_v, D_w, S_d v, S_d w, S_w v, S_w w, C_v, C_w (m²/s², rad²/s²)
        self.sq: list[float] | None = None
        self.count = 0  # sweeps added

    def add(self, x_d: tuple[float, float], x_w: tuple[float, float], x_s: tuple[float, float],
            claim: tuple[float, float] = (math.nan, math.nan)) -> None:
        """One interval's three ``(v, ω)`` (m/s, rad/s) and the variances of ``(v, ω)`` Doppler's fit
        claimed for it (base_link, :func:`base_variances`; NaN: none, then :meth:`adapting` stays
        False); ignored unless the three are finite, and where the wheels' ``ω`` stepped by more than
        :attr:`STEP` since the last interval given (a sweep across a step in curvature has no one
        twist: the sources disagree there whatever their noise)."""
        vals = (x_d[0], x_d[1], x_w[0], x_w[1], x_s[0], x_s[1])
        last, self.last_yaw_rate = self.last_yaw_rate, x_w[1]
        if not all(math.isfinite(x) for x in vals) or not abs(x_w[1] - last) <= self.STEP:
            return
        new = [(x_d[0] - x_w[0]) ** 2, (x_d[1] - x_w[1]) ** 2, (x_d[0] - x_s[0]) ** 2, (x_d[1] - x_s[1]) ** 2,
               (x_w[0] - x_s[0]) ** 2, (x_w[1] - x_s[1]) ** 2, float(claim[0]), float(claim[1])]
        self.count += 1
        if self.sq is None:
            self.sq = new
        else:  # the plain mean until 1 / rate sweeps are in: a first sweep does not dominate the start
            r = max(self.rate, 1.0 / self.count)
            self.sq = [a + r * (b - a) for a, b in zip(self.sq, new)]
        self._update()

    def mean_squares(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """Doppler's and the wheels' mean-square error of ``(v, ω)`` (each >= 0), None before any sweep."""
        if self.sq is None:
            return None
        dv, dw, sdv, sdw, swv, sww = self.sq[:6]
        return ((max(0.5 * (dv + sdv - swv), 0.0), max(0.5 * (dw + sdw - sww), 0.0)),
                (max(0.5 * (dv + swv - sdv), 0.0), max(0.5 * (dw + sww - sdw), 0.0)))

    def ratio(self) -> float:
        """Doppler's observed mean square over the variance its fits claimed, the mean of the ``v``
        and ``ω`` ratios (NaN before any sweep, or without claims)."""
        ms = self.mean_squares()
        if ms is None or self.sq is None:
            return math.nan
        (md_v, md_w), (c_v, c_w) = ms[0], self.sq[6:8]
        return 0.5 * (md_v / c_v + md_w / c_w) if c_v > 0 and c_w > 0 else math.nan

    def _update(self) -> None:
        """Whether the weights move from here: on once ``min_sweeps`` are in and :meth:`ratio` is above
        ``gate``, off again once it is below half of it (hysteresis: a Doppler that errs several times
        its claim does not flicker back to the nominal weights where its ratio dips)."""
        r = self.ratio()
        if self.count < self.min_sweeps or not math.isfinite(r):
            self.on = False
        elif self.on:
            self.on = r >= 0.5 * self.gate
        else:
            self.on = r > self.gate

    def adapting(self) -> tuple[bool, bool]:
        """Per component ``(v, ω)``: whether the evidence moves the weights (:meth:`_update`)."""
        return (self.on, self.on)

    def weights(self, c_d: list[list[float]], a: list[list[float]], wheel_var: tuple[float, float],
                noise: WheelNoise) -> tuple[list[list[float]], tuple[float, float]]:
        """Doppler's covariance ``c_d`` (lidar frame, nested 2x2) and the wheels' variances, as fused.

        In each component that is :meth:`adapting`, Doppler's standard deviation in base_link
        (``A⁻¹ c_d A⁻ᵀ``) grows to what the sweeps show where that is more (the correlation kept,
        then back through ``A``), and the wheels' variance shrinks to what they show where that
        is less, floored at ``speed_min²``, ``yaw_rate_min²``. Elsewhere both are as given; all
        of it when ``A`` is singular.
        """
        on = self.adapting()
        ms = self.mean_squares()
        b = base_variances(c_d, a)
        if ms is None or b is None or not (on[0] or on[1]):
            return c_d, wheel_var
        (md_v, md_w), (mw_v, mw_w) = ms
        floors = (noise.speed_min**2, noise.yaw_rate_min**2)
        wv = tuple(min(w, max(m, f)) if o else w for w, m, f, o in zip(wheel_var, (mw_v, mw_w), floors, on))
        b00, b01, b11 = b
        s0 = math.sqrt(max(md_v / b00, 1.0)) if on[0] and b00 > 0 else 1.0
        s1 = math.sqrt(max(md_w / b11, 1.0)) if on[1] and b11 > 0 else 1.0
        if s0 == 1.0 and s1 == 1.0:
            return c_d, (wv[0], wv[1])
        b00, b01, b11 = b00 * s0 * s0, b01 * s0 * s1, b11 * s1 * s1
        (a00, a01), (a10, a11) = a
        # A B Aᵀ
        u00, u01 = a00 * b00 + a01 * b01, a00 * b01 + a01 * b11
        u10, u11 = a10 * b00 + a11 * b01, a10 * b01 + a11 * b11
        return ([[u00 * a00 + u01 * a01, u00 * a10 + u01 * a11], [u10 * a00 + u11 * a01, u10 * a10 + u11 * a11]],
                (wv[0], wv[1]))


def base_variances(c_d: list[list[float]], a: list[list[float]]) -> tuple[float, float, float] | None:
    """Doppler's covariance ``c_d`` (lidar frame, nested 2x2) in base_link, ``B = A⁻¹ c_d A⁻ᵀ``, as
    ``(B_vv, B_vω, B_ωω)`` ((m/s)², m·rad/s², (rad/s)²); None where ``A`` is singular (``|det| <= 1e-9``)."""
    (a00, a01), (a10, a11) = a
    det = a00 * a11 - a01 * a10
    if not abs(det) > 1e-9:
        return None
    i00, i01, i10, i11 = a11 / det, -a01 / det, -a10 / det, a00 / det  # A⁻¹
    (c00, c01), (c10, c11) = c_d
    t00, t01 = i00 * c00 + i01 * c10, i00 * c01 + i01 * c11
    t10, t11 = i10 * c00 + i11 * c10, i10 * c01 + i11 * c11
    return t00 * i00 + t01 * i01, t00 * i10 + t01 * i11, t10 * i10 + t11 * i11


def _inv2(m: np.ndarray) -> np.ndarray | None:
    """Inverse of a 2x2 matrix in closed form (a per-sweep solve: ``np.linalg.inv`` costs more
    than the arithmetic); None when it is singular or not finite."""
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    if not (np.isfinite(det) and abs(det) > 1e-300):
        return None
    return np.array([[m[1, 1], -m[0, 1]], [-m[1, 0], m[0, 0]]]) / det


def fuse_twist(z: np.ndarray | None, c_d: np.ndarray | None, a: np.ndarray,
               x_w: np.ndarray, c_w: np.ndarray) -> FusedTwist:
    """Weighted least squares of the Doppler equations ``z = A x`` (``z`` None: no Doppler) and ``x = x_w``.

    ``z`` (2,): the lidar origin's velocity in the lidar frame (m/s); ``a``: :func:`doppler_design`;
    ``x_w`` (2,): the wheels' (or the hold's) ``(v, ω)`` of base_link (m/s, rad/s).
    ``c_d`` (2, 2) is ``z``'s covariance ((m/s)²), positive definite; ``c_w`` that of ``x_w``
    (positive definite). A singular ``c_d`` (a degenerate fit) counts as no Doppler.
    Raises ``ValueError`` when ``c_w`` is singular or not finite.

    Where :func:`fmcwlog.kernels.compiled.core` selects the compiled kernels, the same formulas on
    Python floats (a 2x2 solve: numpy's calls cost more than its arithmetic), equal to
    :func:`fuse_twist_numpy` to rounding (numpy's 2x2 products may fuse a multiply-add).
    """
    if compiled.core() is not None:
        return _fuse_twist_floats(z, c_d, a, x_w, c_w)
    return fuse_twist_numpy(z, c_d, a, x_w, c_w)


def fuse_twist_numpy(z: np.ndarray | None, c_d: np.ndarray | None, a: np.ndarray,
                     x_w: np.ndarray, c_w: np.ndarray) -> FusedTwist:
    """:func:`fuse_twist` on numpy arrays: the reference."""
    x_w = np.asarray(x_w, dtype=float)
    info_w = _inv2(c_w)
    if info_w is None:
        raise ValueError("the wheels' covariance must be positive definite")
    w_d = None if z is None or c_d is None else _inv2(c_d)
    if z is None or w_d is None:
        return FusedTwist(x_w.copy(), np.asarray(c_w, dtype=float).copy(), np.zeros(2), float("nan"))
    at_w = a.T @ w_d
    info_d = at_w @ a
    cov = _inv2(info_d + info_w)
    assert cov is not None  # info_w is positive definite, info_d positive semi-definite
    x = cov @ (at_w @ z + info_w @ x_w)
    r_d, r_w = z - a @ x, x_w - x
    chi2 = float(r_d @ w_d @ r_d + r_w @ info_w @ r_w)
    share = np.clip(np.diag(cov @ info_d), 0.0, 1.0)
    return FusedTwist(x, cov, share, chi2)


def _inv2_floats(m: list[list[float]]) -> list[list[float]] | None:
    """:func:`_inv2` of a 2x2 nested list of floats."""
    (m00, m01), (m10, m11) = m
    det = m00 * m11 - m01 * m10
    if not (math.isfinite(det) and abs(det) > 1e-300):
        return None
    return [[m11 / det, -m01 / det], [-m10 / det, m00 / det]]


def _fuse_twist_floats(z: np.ndarray | None, c_d: np.ndarray | None, a: np.ndarray,
                       x_w: np.ndarray, c_w: np.ndarray) -> FusedTwist:
    """:func:`fuse_twist_numpy`'s operations on Python floats (same contract and errors)."""
    xw = np.asarray(x_w, dtype=float)
    cw = np.asarray(c_w, dtype=float).tolist()
    if z is None or c_d is None:
        if _inv2_floats(cw) is None:
            raise ValueError("the wheels' covariance must be positive definite")
        return FusedTwist(xw.copy(), np.array(cw), np.zeros(2), float("nan"))
    return fuse_twist_lists(np.asarray(z, dtype=float).tolist(), np.asarray(c_d, dtype=float).tolist(),
                            np.asarray(a, dtype=float).tolist(), xw.tolist(), cw)


def fuse_twist_lists(z: list[float], c_d: list[list[float]], a: list[list[float]], x_w: list[float],
                     c_w: list[list[float]]) -> FusedTwist:
    """:func:`fuse_twist`'s compiled-switch path on Python numbers: ``z`` and ``x_w`` as 2-lists,
    ``c_d``, ``a`` and ``c_w`` as nested 2x2 lists (a caller holding floats skips the arrays). Each
    product and sum is :func:`fuse_twist_numpy`'s, in its order, written out (no helper calls)."""
    info_w = _inv2_floats(c_w)
    if info_w is None:
        raise ValueError("the wheels' covariance must be positive definite")
    w_d = _inv2_floats(c_d)
    if w_d is None:
        return FusedTwist(np.array(x_w), np.array(c_w), np.zeros(2), float("nan"))
    (a00, a01), (a10, a11) = a
    (d00, d01), (d10, d11) = w_d
    (i00, i01), (i10, i11) = info_w
    # at_w = Aᵀ W_d
    t00, t01 = a00 * d00 + a10 * d10, a00 * d01 + a10 * d11
    t10, t11 = a01 * d00 + a11 * d10, a01 * d01 + a11 * d11
    # info_d = at_w A
    n00, n01 = t00 * a00 + t01 * a10, t00 * a01 + t01 * a11
    n10, n11 = t10 * a00 + t11 * a10, t10 * a01 + t11 * a11
    cov = _inv2_floats([[n00 + i00, n01 + i01], [n10 + i10, n11 + i11]])
    assert cov is not None  # info_w is positive definite, info_d positive semi-definite
    (c00, c01), (c10, c11) = cov
    z0, z1 = z
    w0, w1 = x_w
    bd0, bd1 = t00 * z0 + t01 * z1, t10 * z0 + t11 * z1  # at_w z
    bw0, bw1 = i00 * w0 + i01 * w1, i10 * w0 + i11 * w1  # info_w x_w
    s0, s1 = bd0 + bw0, bd1 + bw1
    x0, x1 = c00 * s0 + c01 * s1, c10 * s0 + c11 * s1
    rd0, rd1 = z0 - (a00 * x0 + a01 * x1), z1 - (a10 * x0 + a11 * x1)
    rw0, rw1 = w0 - x0, w1 - x1
    chi2 = ((rd0 * (d00 * rd0 + d01 * rd1) + rd1 * (d10 * rd0 + d11 * rd1))
            + (rw0 * (i00 * rw0 + i01 * rw1) + rw1 * (i10 * rw0 + i11 * rw1)))
    share = [min(max(c00 * n00 + c01 * n10, 0.0), 1.0), min(max(c10 * n01 + c11 * n11, 0.0), 1.0)]  # np.clip
    return FusedTwist(np.array([x0, x1]), np.array(cov), np.array(share), chi2)


def observability(mount: tuple[float, float, float], min_lever: float) -> str:
    """In words, what Doppler can observe of ``(v, ω)`` at ``mount`` (``min_lever`` in m)."""
    lx, ly, _ = mount
    if abs(lx) >= min_lever:
        return f"v and omega (lever arm lidar_x = {lx:.3f} m)"
    if abs(ly) < min_lever:
        return f"v only (lidar_x = {lx:.3f} m: no lever arm for omega)"
    return f"only v - omega*lidar_y (lidar_x = {lx:.3f} m, lidar_y = {ly:.3f} m)"


@dataclass
class TwistSources:
    """Per log: how many sweeps took their twist from which source, and Doppler's share of it."""

    sweeps: int = 0
    with_doppler: int = 0  # Doppler usable and fused
    with_wheels: int = 0  # the wheels' twist was there to fuse (else the hold)
    fit_failed: int = 0  # Doppler present but no fit (too few static points, or the scans ruled it out)
    prior_sweeps: int = 0  # the ICP was held to the fused motion
    share_v: float = 0.0  # sums of Doppler's share over the sweeps with Doppler
    share_omega: float = 0.0

    def count(self, doppler: bool, fused: FusedTwist | None, wheels: bool, twist_from_fusion: bool) -> None:
        """One sweep: Doppler present, its fusion (None if the fit failed), wheels present, and
        whether the fused twist is the one used (``doppler_twist``)."""
        self.sweeps += 1
        self.with_wheels += wheels
        if doppler and fused is None:
            self.fit_failed += 1
        if fused is not None and twist_from_fusion:
            self.with_doppler += 1
            self.share_v += float(fused.doppler_share[0])
            self.share_omega += float(fused.doppler_share[1])

    def summary(self) -> dict:
        """For ``run.json``: the counts, and Doppler's mean share of ``v`` and ``ω`` over the sweeps it was in."""
        n = max(self.with_doppler, 1)
        return {
            "sweeps": self.sweeps,
            "twist_with_doppler_sweeps": self.with_doppler,
            "twist_with_wheels_sweeps": self.with_wheels,
            "doppler_fit_failed_sweeps": self.fit_failed,
            "doppler_prior_sweeps": self.prior_sweeps,
            "doppler_share_v": round(self.share_v / n, 4) if self.with_doppler else 0.0,
            "doppler_share_omega": round(self.share_omega / n, 4) if self.with_doppler else 0.0,
        }

    def warnings(self, seen: str, prior_name: str) -> list[str]:
        """When Doppler gave less than half of ``v`` or ``ω`` (``seen``: :func:`observability`), or failed."""
        out = []
        if self.with_doppler:
            sv, sw = self.share_v / self.with_doppler, self.share_omega / self.with_doppler
            if min(sv, sw) < 0.5:
                other = prior_name if self.with_wheels else "constant-velocity hold"
                out.append(f"at this mount Doppler observes {seen}: the twist took {sv:.0%} of v and "
                           f"{sw:.0%} of omega from Doppler, the rest from the {other}")
        if self.fit_failed:
            out.append(f"{self.fit_failed} of {self.sweeps} sweeps had no usable Doppler fit: their twist came "
                       f"from the {prior_name if self.with_wheels else 'constant-velocity hold'}")
        return out
