"""The ``fmcwlog.calibration`` metadata record as numbers (docs/log-format.md), each checked against its
physical range.

MCAP allows several metadata records of one name: identical copies are one calibration (with a
note), copies that disagree are refused, naming the keys they disagree on: there is no telling
which one the robot had.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import CalibrationError, LogError
from ..types import Calibration, WheelCalibration
from .calibration_file import read_calibration_file
from .topics import CALIBRATION_KEY

if TYPE_CHECKING:
    from .logs import Log

WHEEL_KEYS = ("wheel_radius_left", "wheel_radius_right", "track_width", "ticks_per_revolution")
MOUNT_KEYS = ("lidar_x", "lidar_y", "lidar_yaw")
OPTIONAL_KEYS = ("doppler_resolution", "range_sigma", "max_range", "scan_rate")

# The valid range of each key processing reads (inclusive, SI units), wide enough for any robot
# that carries a planar LiDAR and narrow enough that a damaged value cannot pass:
RANGES: dict[str, tuple[float, float, str]] = {
    "wheel_radius_left": (0.005, 2.0, "m"),  # a 1 cm micro-robot wheel to a 4 m mining-truck tyre
    "wheel_radius_right": (0.005, 2.0, "m"),
    "track_width": (0.02, 10.0, "m"),
    "ticks_per_revolution": (1, 1e8, ""),  # a whole number; a 2^20-count encoder behind a 50:1 gear is 5e7
    "lidar_x": (-10.0, 10.0, "m"),  # the sensor sits on the robot
    "lidar_y": (-10.0, 10.0, "m"),
    "lidar_yaw": (-2 * math.pi, 2 * math.pi, "rad"),
    "doppler_resolution": (0.0, 10.0, "m/s"),
    "range_sigma": (0.0, 1.0, "m"),
    "max_range": (0.1, 10_000.0, "m"),
    "scan_rate": (0.0, 1000.0, "Hz"),  # 0: not known (fmcwlog import writes it so)
}


def _number(values: dict[str, str], key: str) -> float:
    try:
        x = float(values[key])
    except KeyError:
        raise CalibrationError(f"calibration has no {key!r}") from None
    except ValueError:
        raise CalibrationError(f"calibration {key!r} is not a number: {values[key]!r}") from None
    if not math.isfinite(x):
        raise CalibrationError(f"calibration {key!r} is not finite")
    low, high, unit = RANGES[key]
    if not low <= x <= high:
        u = f" {unit}" if unit else ""
        raise CalibrationError(f"calibration {key!r} = {values[key]}{u} is outside its valid range "
                               f"[{low:g}, {high:g}]{u}")
    return x


def _same(a: str | None, b: str | None) -> bool:
    """Whether two values of a key are equal, as numbers where both are ('0.1' equals '0.10')."""
    if a is None or b is None:
        return a == b
    try:
        return float(a) == float(b) or a == b
    except ValueError:
        return a == b


def calibration_record(records: list[dict[str, str]], source: str) -> dict[str, str] | None:
    """The one calibration among a log's ``fmcwlog.calibration`` records (None if it has none).

    Identical records are one (a warning notes the copies); records that disagree raise
    :class:`CalibrationError` naming the keys.
    """
    if not records:
        return None
    first = records[0]
    for other in records[1:]:
        differ = sorted(k for k in set(first) | set(other) if not _same(first.get(k), other.get(k)))
        if differ:
            shown = ", ".join(f"{k} ({first.get(k, 'absent')} against {other.get(k, 'absent')})" for k in differ[:4])
            more = f" and {len(differ) - 4} more" if len(differ) > 4 else ""
            raise CalibrationError(f"its {len(records)} {CALIBRATION_KEY} records disagree on {shown}{more}: "
                                   "there is no telling which is the robot's")
    if len(records) > 1:
        warnings.warn(f"{source}: {len(records)} identical {CALIBRATION_KEY} records; used them as one", stacklevel=2)
    return first


def parse_calibration(values: dict[str, str] | None, need_wheels: bool, source: str = "the calibration") -> Calibration:
    """Parse the record; the wheel keys are required only when ticks are the motion prior.

    A log without a calibration record (e.g. an imported laser log) gets the
    lidar at the origin of base_link. So does a record without the mount's keys, with a
    warning naming ``source`` and the keys: the log format (docs/log-format.md) lists them, and a writer that left
    them out would otherwise have its lidar moved to the rear axle without a word (a 12 s crowd
    log so rewritten: the baseline's trajectory 11 cm off). Every value read must lie in its
    range (:data:`RANGES`).
    """
    missing_mount = [k for k in MOUNT_KEYS if k not in values] if values else []
    if missing_mount:
        warnings.warn(f"{source}: {CALIBRATION_KEY} has no {', '.join(missing_mount)}: taken as 0 (the lidar "
                      "at base_link's origin, facing forward)", stacklevel=2)
    values = values or {}
    if need_wheels:
        if not values:
            raise CalibrationError(f"no {CALIBRATION_KEY} record, which wheel ticks need: name a calibration file "
                                   "with --calibration")
        r_left, r_right, track, ticks = (_number(values, k) for k in WHEEL_KEYS)
        if ticks != int(ticks):
            raise CalibrationError(f"calibration 'ticks_per_revolution' = {values['ticks_per_revolution']} "
                                   "is not a whole number")
        wheels = WheelCalibration(r_left, r_right, track, int(ticks))
    else:
        wheels = None
    x, y, yaw = (_number(values, k) if k in values else 0.0 for k in MOUNT_KEYS)
    opt = {k: _number(values, k) if k in values else None for k in OPTIONAL_KEYS}
    return Calibration(wheels, (x, y, yaw), opt["doppler_resolution"], opt["range_sigma"], opt["max_range"],
                       opt["scan_rate"] or None)


def load_calibration(reader: Log, log: Path, need_wheels: bool, path: Path | None) -> tuple[Calibration, str]:
    """The calibration to process ``log`` with: the calibration file at ``path`` if given, else the
    log's ``fmcwlog.calibration`` record; and where it came from (the path, or ``log record ...``).

    ``need_wheels``: the wheels' keys must be there (wheel ticks are read). Raises
    :class:`~fmcwlog.errors.CalibrationError` (naming the file) for a bad file, and
    :class:`~fmcwlog.errors.LogError` (naming the log) for a missing or bad record. A calibration
    that leaves out some of the mount's keys is warned of by :func:`parse_calibration`."""
    if path is not None:
        try:
            return parse_calibration(read_calibration_file(path), need_wheels, str(path)), str(path)
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: {str(exc).removeprefix(f'{path}: ')}") from None
    try:
        record = calibration_record(reader.metadata_all(CALIBRATION_KEY), str(log))
        return parse_calibration(record, need_wheels, str(log)), f"log record {CALIBRATION_KEY}"
    except CalibrationError as exc:
        raise LogError(f"{log}: {exc}{reader.damage_note()}") from None
