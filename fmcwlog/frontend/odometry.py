"""Wheel odometry of the rear axle from cumulative encoder ticks (paper §3.2).

Frames and units: poses are ``(x, y, yaw)`` of ``base_link`` (rear-axle
midpoint) in the odometry frame, metres and radians; stamps in seconds.

Eq. 9 turns encoder pulses into wheel arc length, ``Δs = 2π r n / k``.
Eq. 13 is the differential-drive model ``v = (r_L ω_L + r_R ω_R) / 2``,
``ω = (r_R ω_R - r_L ω_L) / b``; it holds for the Ackermann chassis because its rear
wheels are not steered (the physics notes, docs/physics.md). It is applied per interval,
on arc lengths rather than rates.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import _wrap, wrap_angle
from ..types import WheelCalibration
from .deskew import sinc_of_float


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
    return _arc(dl.astype(float), calib.wheel_radius_left, calib), _arc(dr.astype(float), calib.wheel_radius_right, calib)


def _arc(ticks, radius: float, calib: WheelCalibration):
    """Eq. 9: the arc (m) of ``ticks`` counts (a float or a float array) on a wheel of ``radius`` (m)."""
    return 2.0 * np.pi * radius * ticks / float(calib.ticks_per_revolution)


def body_increments(
    left_ticks: np.ndarray, right_ticks: np.ndarray, calib: WheelCalibration
) -> tuple[np.ndarray, np.ndarray]:
    """Per-interval travelled arc ``Δs`` (m) and heading change ``Δθ`` (rad) of base_link.

    Eq. 13 applied to arc lengths: ``Δs = (Δs_L + Δs_R) / 2``, ``Δθ = (Δs_R - Δs_L) / b``.
    ``left_ticks``/``right_ticks``: cumulative int64 counts (N,) as for
    :func:`wheel_arc_lengths`; returns two (N-1,) arrays. Raises nothing of its own.
    """
    if _two_readings(left_ticks) and _two_readings(right_ticks):
        dl = int(left_ticks[1]) - int(left_ticks[0])
        dr = int(right_ticks[1]) - int(right_ticks[0])
        if -_I64 <= dl < _I64 and -_I64 <= dr < _I64:  # np.diff's int64 would not have wrapped
            # one interval on floats (the motion prior adds a reading at a time, 50 a second: 14 µs
            # of array calls each for two numbers), the same operations in the same order
            ds, dth = _body(_arc(float(dl), calib.wheel_radius_left, calib),
                            _arc(float(dr), calib.wheel_radius_right, calib), calib)
            return np.array([ds]), np.array([dth])
    return _body(*wheel_arc_lengths(left_ticks, right_ticks, calib), calib)


def _body(ds_l, ds_r, calib: WheelCalibration):
    """Eq. 13 on the wheels' arcs (m), floats or arrays alike: ``Δs`` (m) and ``Δθ`` (rad)."""
    return 0.5 * (ds_l + ds_r), (ds_r - ds_l) / calib.track_width


_I64 = 2**63


def _two_readings(ticks: object) -> bool:
    """Two cumulative int64 counts: the motion prior's one interval at a time (the scalar path)."""
    return type(ticks) is np.ndarray and ticks.shape == (2,) and ticks.dtype == np.int64


def integrate_arcs(
    ds: np.ndarray, dtheta: np.ndarray, initial_pose: np.ndarray | tuple = (0.0, 0.0, 0.0)
) -> np.ndarray:
    """Chain constant-curvature arcs into poses (N+1, 3), exactly and vectorised.

    ``ds`` (N,) arc lengths (m) and ``dtheta`` (N,) heading changes (rad), as
    :func:`body_increments` gives them; ``initial_pose`` ``(x, y, yaw)`` (m, m, rad) is the
    first row of the result, in the same odometry frame.

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


def ticks_step(x0: float, y0: float, th0: float, dl: int, dr: int,
               calib: WheelCalibration) -> tuple[float, float, float] | None:
    """The pose ``(x, y, yaw)`` (m, m, rad) that ``dl``, ``dr`` counts of the left and right wheel
    lead to from ``(x0, y0, th0)``, as Python floats: :func:`body_increments` of the one interval then
    :func:`integrate_arc`, the same float operations in the same order, without their arrays (the
    motion prior adds one reading at a time, 50 a second). None where a count is beyond int64, which
    the array path wraps."""
    if not (-_I64 <= dl < _I64 and -_I64 <= dr < _I64):
        return None
    ds, dtheta = _body(_arc(float(dl), calib.wheel_radius_left, calib),
                       _arc(float(dr), calib.wheel_radius_right, calib), calib)
    mid = (th0 + 0.0) + 0.5 * dtheta
    if not math.isfinite(mid):  # integrate_arc's numpy branch
        return None
    chord = ds * sinc_of_float(dtheta / (2.0 * np.pi))
    return x0 + chord * math.cos(mid), y0 + chord * math.sin(mid), _wrap(th0 + dtheta)


def integrate_arc(ds: float, dtheta: float, pose: np.ndarray) -> np.ndarray:
    """The pose (3,) one arc of :func:`integrate_arcs` leads to from ``pose``: the same float operations
    on scalars (the motion prior adds one encoder reading at a time, 50 a second; the array version's
    concatenations and cumulative sums cost 60 us for that)."""
    x0, y0, th0 = (float(c) for c in pose)
    ds, dtheta = float(ds), float(dtheta)
    mid = (th0 + 0.0) + 0.5 * dtheta
    chord = ds * sinc_of_float(dtheta / (2.0 * np.pi))  # np.sinc's operations, on a float
    if not math.isfinite(mid):  # math.cos raises on ±inf where numpy gives NaN
        return np.array([x0 + chord * np.cos(mid), y0 + chord * np.sin(mid), wrap_angle(th0 + dtheta)])
    # math's cos and sin are numpy's float64 ones here (:mod:`fmcwlog.geometry`)
    return np.array([x0 + chord * math.cos(mid), y0 + chord * math.sin(mid), wrap_angle(th0 + dtheta)])
