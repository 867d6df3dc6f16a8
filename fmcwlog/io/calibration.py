"""The ``fmcwlog.calibration`` metadata record as numbers (LOG_FORMAT.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import CalibrationError

WHEEL_KEYS = ("wheel_radius_left", "wheel_radius_right", "track_width", "ticks_per_revolution")
MOUNT_KEYS = ("lidar_x", "lidar_y", "lidar_yaw")


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


@dataclass(frozen=True)
class Calibration:
    """What processing knows of the robot: wheels (None if not given) and the lidar mounting."""

    wheels: WheelCalibration | None
    mount: tuple[float, float, float]  # lidar pose in base_link: m, m, rad
    doppler_resolution: float | None  # m/s
    range_sigma: float | None  # m


def _number(values: dict[str, str], key: str) -> float:
    try:
        x = float(values[key])
    except KeyError:
        raise CalibrationError(f"calibration has no {key!r}") from None
    except ValueError:
        raise CalibrationError(f"calibration {key!r} is not a number: {values[key]!r}") from None
    if not math.isfinite(x):
        raise CalibrationError(f"calibration {key!r} is not finite")
    return x


def parse_calibration(values: dict[str, str] | None, need_wheels: bool) -> Calibration:
    """Parse the record; the wheel keys are required only when ticks are the motion prior.

    A log without a calibration record (e.g. an imported laser log) gets the
    lidar at the origin of base_link.
    """
    values = values or {}
    if need_wheels:
        if not values:
            raise CalibrationError("no fmcwlog.calibration record, which wheel ticks need")
        r_left, r_right, track = (_number(values, k) for k in WHEEL_KEYS[:3])
        wheels = WheelCalibration(r_left, r_right, track, int(_number(values, WHEEL_KEYS[3])))
        if min(wheels.wheel_radius_left, wheels.wheel_radius_right, wheels.track_width,
               wheels.ticks_per_revolution) <= 0:
            raise CalibrationError("wheel radii, track width and ticks per revolution must be positive")
    else:
        wheels = None
    x, y, yaw = (_number(values, k) if k in values else 0.0 for k in MOUNT_KEYS)
    mount = (x, y, yaw)
    opt = {k: _number(values, k) if k in values else None for k in ("doppler_resolution", "range_sigma")}
    return Calibration(wheels, mount, opt["doppler_resolution"], opt["range_sigma"])
