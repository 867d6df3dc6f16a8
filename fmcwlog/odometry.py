"""Wheel odometry of the rear axle from cumulative encoder ticks (paper §3.2).

Frames and units: poses are ``(x, y, yaw)`` of ``base_link`` (rear-axle
midpoint) in the odometry frame, metres and radians; stamps in seconds.

Eq. 9 turns encoder pulses into wheel arc length, ``Δs = 2π r n / k``.
Eq. 13 is the differential-drive model of the (unsteered) rear axle; NOTES.md
gives it as ``v = (r_L ω_L + r_R ω_R) / 2``, ``ω = (r_R ω_R - r_L ω_L) / b``,
which is what we implement (per interval, on arc lengths rather than rates).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmcwlog.geometry import wrap_angle


@dataclass(frozen=True)
class WheelCalibration:
    """Rear-axle calibration.

    wheel_radius_left, wheel_radius_right: rolling radii ``r_L``, ``r_R`` (m).
    track_width: distance ``b`` between the rear wheels' contact points (m), eq. 10.
    ticks_per_revolution: encoder pulses per wheel revolution ``k`` (eq. 9).
    """

    wheel_radius_left: float
    wheel_radius_right: float
    track_width: float
    ticks_per_revolution: int


def wheel_arc_lengths(
    left_ticks: np.ndarray, right_ticks: np.ndarray, calib: WheelCalibration
) -> tuple[np.ndarray, np.ndarray]:
    """Arc length (m) rolled by each rear wheel over each interval, eq. 9.

    ``left_ticks``/``right_ticks`` are cumulative int64 counts (N,), any
    starting value, possibly negative. Returns two (N-1,) arrays; negative when
    the wheel rolls backwards.
    """
    dl = np.diff(np.asarray(left_ticks, dtype=np.int64))  # integer diff: exact
    dr = np.diff(np.asarray(right_ticks, dtype=np.int64))
    k = float(calib.ticks_per_revolution)
    ds_l = 2.0 * np.pi * calib.wheel_radius_left * dl.astype(float) / k  # eq. 9
    ds_r = 2.0 * np.pi * calib.wheel_radius_right * dr.astype(float) / k
    return ds_l, ds_r


def body_increments(
    left_ticks: np.ndarray, right_ticks: np.ndarray, calib: WheelCalibration
) -> tuple[np.ndarray, np.ndarray]:
    """Per-interval travelled arc ``Δs`` (m) and heading change ``Δθ`` (rad) of base_link.

    Eq. 13 as corrected in NOTES.md, applied to arc lengths:
    ``Δs = (Δs_L + Δs_R) / 2``, ``Δθ = (Δs_R - Δs_L) / b``.
    """
    ds_l, ds_r = wheel_arc_lengths(left_ticks, right_ticks, calib)
    return 0.5 * (ds_l + ds_r), (ds_r - ds_l) / calib.track_width


def wheel_speeds_from_ticks(
    stamps_s: np.ndarray,
    left_ticks: np.ndarray,
    right_ticks: np.ndarray,
    calib: WheelCalibration,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean forward speed ``v`` (m/s) and yaw rate ``ω`` (rad/s) over each interval.

    Returns two (N-1,) arrays, interval ``i`` spanning ``stamps_s[i]..stamps_s[i+1]``.
    Raises ``ValueError`` if the stamps are not strictly increasing.
    """
    dt = np.diff(np.asarray(stamps_s, dtype=float))
    if np.any(dt <= 0.0):
        raise ValueError("stamps must be strictly increasing")
    ds, dth = body_increments(left_ticks, right_ticks, calib)
    return ds / dt, dth / dt


def integrate_arcs(
    ds: np.ndarray, dtheta: np.ndarray, initial_pose: np.ndarray | tuple = (0.0, 0.0, 0.0)
) -> np.ndarray:
    """Chain constant-curvature arcs into poses (N+1, 3), exactly and vectorised.

    Over an arc of length ``Δs`` turning by ``Δθ`` from heading ``θ_k`` the chord
    has length ``Δs · sin(Δθ/2)/(Δθ/2)`` and direction ``θ_k + Δθ/2``; ``np.sinc``
    makes ``Δθ → 0`` (straight line) exact with no special case.
    """
    x0, y0, th0 = (float(c) for c in initial_pose)
    ds = np.asarray(ds, dtype=float)
    dtheta = np.asarray(dtheta, dtype=float)
    heading = th0 + np.concatenate(([0.0], np.cumsum(dtheta)))  # heading at each sample
    mid = heading[:-1] + 0.5 * dtheta
    chord = ds * np.sinc(dtheta / (2.0 * np.pi))  # np.sinc(x) = sin(πx)/(πx)
    x = x0 + np.concatenate(([0.0], np.cumsum(chord * np.cos(mid))))
    y = y0 + np.concatenate(([0.0], np.cumsum(chord * np.sin(mid))))
    return np.stack([x, y, wrap_angle(heading)], -1)


def integrate_wheel_odometry(
    stamps_s: np.ndarray,
    left_ticks: np.ndarray,
    right_ticks: np.ndarray,
    calib: WheelCalibration,
    initial_pose: np.ndarray | tuple = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """Dead-reckoned base_link poses (N, 3) at each tick sample, odometry frame.

    Each interval is integrated exactly as an arc of constant curvature (the
    wheels' arc lengths fix both its length and its turn; time is not needed
    for the pose, only checked for monotonicity). ``poses[0] = initial_pose``.
    """
    stamps = np.asarray(stamps_s, dtype=float)
    n = stamps.shape[0]
    if np.asarray(left_ticks).shape != (n,) or np.asarray(right_ticks).shape != (n,):
        raise ValueError("stamps, left_ticks and right_ticks must have the same length")
    if n and np.any(np.diff(stamps) < 0.0):
        raise ValueError("stamps must be non-decreasing")
    if n == 0:
        return np.zeros((0, 3))
    ds, dth = body_increments(left_ticks, right_ticks, calib)
    return integrate_arcs(ds, dth, initial_pose)
