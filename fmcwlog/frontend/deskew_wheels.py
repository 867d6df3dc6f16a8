"""De-skewing by the motion within the sweep that the wheels measured (``frontend.deskew_motion``).

:mod:`.deskew` moves each point to the sweep's stamp under one constant twist ``(v, ω)``. A sweep in
which the robot enters or leaves a turn (the yaw rate steps by 2-3 rad/s at the end of an aisle)
has no constant twist: at a 75 ms sweep a step of 2 rad/s half-way turns the last points by up to
0.04 rad against the constant twist's placement, 0.4 m at 10 m range. The wheel ticks arrive at
~50 Hz, five a sweep, so the motion prior (:class:`~.motion_prior.PoseTrack`) resolves the step.

Frames and units: the sweep's *knots* are times ``τ_0 = 0 < τ_1 < … < τ_K`` (s after the sweep's
stamp: the stamp, the prior's own stamps inside the sweep, its end) and base_link's poses at them
(m, m, rad) in base_link at the stamp (the first is the identity). Between two knots the base
moves along the arc of the twist ``ξ_j = (v_j, ω_j)`` (m/s, rad/s) that joins them (the ticks'
own model, :func:`~.odometry.integrate_arc`), a piecewise-constant twist; before the first knot
and after the last the first and last twists go on. A point seen at ``t_i`` in the lidar frame
then lies at ``B(t_i) ⊕ L · p_i`` in base_link at the stamp (``L`` the mount): the same
reference as :func:`~.deskew.deskewed_source` (the lidar frame at the stamp, placed by the mount).

Which sweeps, and which scale (measured on the 3 m/s warehouse log, seed 0, 60 s: the points of
every sweep placed by each motion against the simulator's true motion, RMS over the points of a
sweep, then over the sweeps): the wheels' yaw rate is the one to follow within a sweep, and the
fused twist's is not: at a turn's entry the fused (Doppler and wheels) yaw rate was 1.49 rad/s where
the truth's mean over the sweep was 0.94, so shifting the wheels' profile to the fused mean put
the points 170 mm (RMS) off in the sweeps crossing a turn's end, the constant twist 148 mm, the
wheels' own profile 7 mm. Their speed is another matter: scaled by one factor to the fused mean
speed (the yaw rates left the wheels') the points came 4.07 mm off over all sweeps against 4.21 mm
with the wheels' own speed (their radii 0.3-0.5 % off), so the speed is scaled. In the 593 steady
sweeps, though, the constant twist placed the points to 0.6 mm (median) and the wheels' profile to
2.7 mm: a tick of yaw is 0.34 mrad (4096 ticks a turn, 0.45 m track), 7 mm at 20 m. So the profile is used
only where the wheels' yaw rates within the sweep spread by ``frontend.deskew_min_yaw_step``
(0.2 rad/s) or more. Where it is used the front end's heading error shows it: on the 120 s
warehouse logs (seeds 0-5) its largest heading error fell from 2.8-3.1 deg to 0.8-1.4 deg and its
RPE over 1 m from 0.047 to 0.031 deg/m; its ATE, set by the drift along the aisles, moved within
the spread between seeds.

Two kernels: :func:`deskewed_source_wheels_numpy` (the reference, through
:func:`~fmcwlog.geometry.compose` and :func:`~.deskew.se2_exp`) and the compiled
``deskew_source_wheels`` (``src/core/deskew.cpp``): the same points to rounding (~1e-15 m), the
same ``use`` mask; ``tests/unit/frontend/test_deskew_wheels.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry import compose, transform_points
from ..kernels import compiled
from .deskew import core_velocity, se2_exp, sweep_columns, thinned_source, used_points

MIN_SEGMENT_S = 1e-4  # s: knots closer than this are merged (a twist over a shorter time is noise)
MIN_SCALED_SPEED = 0.05  # m/s: below this wheel speed the profile's speed is shifted, not scaled


@dataclass(frozen=True)
class SweepKnots:
    """The motion prior's track over one sweep: ``times`` (K+1,) s after the stamp, increasing,
    the first 0; ``poses`` (K+1, 3) base_link's poses then (m, m, rad) in base_link at the stamp,
    the first the identity. K >= 1."""

    times: np.ndarray
    poses: np.ndarray


@dataclass(frozen=True)
class SweepProfile:
    """The piecewise-constant twist a sweep is de-skewed with: segment ``j`` starts at
    ``starts[j]`` (s after the stamp; ``starts[0]`` = 0) from base_link's pose ``poses[j]`` (m, m,
    rad; in base_link at the stamp) with the twist ``twists[j] = (v, ω)`` (m/s, rad/s). Arrays
    (K,), (K, 3), (K, 2), float64, C-contiguous."""

    starts: np.ndarray
    poses: np.ndarray
    twists: np.ndarray


def segment_twists(knots: SweepKnots) -> np.ndarray:
    """The twists (K, 2) ``(v, ω)`` (m/s, rad/s) of the arcs joining consecutive knots: for the
    relative motion ``(dx, dy, dθ)`` over ``dt``, ``ω = dθ / dt`` and ``v`` the arc's length over
    ``dt`` with the sign of ``dx`` (``|v| dt = chord · (dθ/2) / sin(dθ/2)``)."""
    p, dt = knots.poses, np.diff(knots.times)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    dx, dy = p[1:, 0] - p[:-1, 0], p[1:, 1] - p[:-1, 1]
    fx, fy = c * dx + s * dy, -s * dx + c * dy  # the motion in the frame of the segment's start
    dth = np.unwrap(p[:, 2])
    dth = dth[1:] - dth[:-1]
    chord = np.hypot(fx, fy) / np.sinc(dth / (2.0 * np.pi))  # sinc(x/π) = sin(x)/x
    return np.stack([np.copysign(chord, fx) / dt, dth / dt], -1)


def yaw_rate_spread(t: list[float], yaw: list[float]) -> float:
    """The spread (largest less smallest, rad/s) of the yaw rates between consecutive knots (times
    ``t`` s, yaws rad), the infinity where two share a time or fewer than two are given.
    :func:`wheel_profile`'s segments merge
    knots closer than :data:`MIN_SEGMENT_S`, and a merged segment's rate is the time-weighted mean
    of the rates it joins: their spread is at most this one, so a sweep steady here is steady there."""
    rates = []
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        if not dt > 0:
            return math.inf
        rates.append(math.remainder(yaw[i + 1] - yaw[i], 2 * math.pi) / dt)
    return max(rates) - min(rates) if rates else math.inf


def wheel_profile(knots: SweepKnots, speed: float | None = None, min_step: float | None = None) -> SweepProfile | None:
    """The profile (:class:`SweepProfile`) of the knots' arcs; with ``speed`` (m/s) their speeds scaled
    by one factor so that their time-weighted mean over ``[0, τ_K]`` is ``speed`` (the yaw rates stay
    the wheels'; where the wheels' mean speed is below :data:`MIN_SCALED_SPEED` in size the speeds are
    shifted by ``speed`` less that mean instead). None where the knots are unusable (not finite, fewer
    than two, times not increasing), ``speed`` is not finite, or the yaw rates' spread (largest less
    smallest, rad/s) is below ``min_step``: a steady sweep, which one twist de-skews better than the
    ticks' quantised yaw."""
    t, p = np.asarray(knots.times, dtype=float), np.asarray(knots.poses, dtype=float)
    if t.ndim != 1 or len(t) < 2 or p.shape != (len(t), 3) or not (np.isfinite(t).all() and np.isfinite(p).all()):
        return None
    if min_step is not None and yaw_rate_spread(t.tolist(), p[:, 2].tolist()) < min_step - 1e-9:
        return None  # steady: decided on floats, before any array is built
    keep = [0]
    for i in range(1, len(t)):  # knots closer than MIN_SEGMENT_S to the last kept one are merged into it
        if t[i] - t[keep[-1]] >= MIN_SEGMENT_S:
            keep.append(i)
    if keep[-1] != len(t) - 1:
        keep[-1] = len(t) - 1  # the last knot stays: it ends the sweep
    t, p = t[keep], p[keep]
    if len(t) < 2 or not (np.diff(t) > 0).all():
        return None
    twists = segment_twists(SweepKnots(t, p))
    if speed is not None:
        if not math.isfinite(speed):
            return None
        mean = float((twists[:, 0] * np.diff(t)).sum() / (t[-1] - t[0]))
        if abs(mean) >= MIN_SCALED_SPEED:
            twists[:, 0] *= float(speed) / mean
        else:
            twists[:, 0] += float(speed) - mean
    if not np.isfinite(twists).all():
        return None
    if min_step is not None and float(np.ptp(twists[:, 1])) < min_step:
        return None
    starts = t[:-1].copy()
    poses = np.zeros((len(starts), 3))
    for j in range(1, len(starts)):  # the chain of arcs from the identity
        poses[j] = compose(poses[j - 1], se2_exp(float(twists[j - 1, 0]), 0.0, float(twists[j - 1, 1]),
                                                 np.array(starts[j] - starts[j - 1])))
    return SweepProfile(np.ascontiguousarray(starts), poses, np.ascontiguousarray(twists))


def base_motion(profile: SweepProfile, t: np.ndarray) -> np.ndarray:
    """base_link's poses (N, 3) (m, m, rad) at times ``t`` (N,, s after the stamp) in base_link at
    the stamp: ``poses[j] ⊕ exp((t - starts[j]) ξ_j)`` for the segment ``j`` holding ``t`` (the first
    before it, the last after)."""
    j = np.clip(np.searchsorted(profile.starts, t, side="right") - 1, 0, len(profile.starts) - 1)
    tw = profile.twists[j]
    return compose(profile.poses[j], se2_exp(tw[:, 0], 0.0, tw[:, 1], t - profile.starts[j]))


def deskew_wheels_numpy(xy: np.ndarray, t: np.ndarray, profile: SweepProfile, mount: np.ndarray) -> np.ndarray:
    """Points (N, 2) seen in the lidar frame at ``t`` (N,, s), in base_link at the stamp: each by
    ``B(t_i) ⊕ L`` (``L`` the ``mount`` (3,), :func:`base_motion` ``B``); (N, 2) m."""
    xy = np.asarray(xy, dtype=float)
    if len(xy) == 0:
        return np.empty((0, 2))
    return transform_points(compose(base_motion(profile, np.asarray(t, dtype=float)), np.asarray(mount, float)), xy)


def deskewed_source_wheels(
    xy: np.ndarray,
    t: np.ndarray,
    profile: SweepProfile,
    mount: np.ndarray,
    near: np.ndarray,
    moving: np.ndarray | None,
    velocity: np.ndarray | None,
    voxel_size: float,
    centroid: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`~.deskew.deskewed_source` with the sweep de-skewed by ``profile`` (:func:`wheel_profile`)
    instead of one twist: ``(use, points, source, velocity)`` as it gives them, ``points`` in base_link at
    the stamp. The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it, else
    :func:`deskewed_source_wheels_numpy`."""
    core = compiled.core()
    mount = np.asarray(mount, dtype=float)
    if (core is not None and near is not None and mount.shape == (3,) and np.isfinite(mount).all()
            and sweep_columns(xy, t, near, moving)):
        fast_velocity = core_velocity(velocity, t)
        use = np.empty(len(xy), bool)
        mx, my, myaw = mount.tolist()
        points, source, kept = core.deskew_source_wheels(
            xy, t, near, moving, velocity if fast_velocity else None, profile.starts, profile.poses,
            profile.twists, mx, my, myaw, float(voxel_size), bool(centroid), use)
        if velocity is not None and not fast_velocity:
            kept = velocity[use]
        return use, points, source, kept
    return deskewed_source_wheels_numpy(xy, t, profile, mount, near, moving, velocity, voxel_size, centroid)


def deskewed_source_wheels_numpy(
    xy: np.ndarray,
    t: np.ndarray,
    profile: SweepProfile,
    mount: np.ndarray,
    near: np.ndarray,
    moving: np.ndarray | None,
    velocity: np.ndarray | None,
    voxel_size: float,
    centroid: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`deskewed_source_wheels` as its steps: the reference the compiled kernel is tested against."""
    use = used_points(near, moving)
    return thinned_source(use, deskew_wheels_numpy(xy[use], t[use], profile, mount), velocity, voxel_size, centroid)
