"""Calibration files: the ``fmcwlog.calibration`` record's keys in a YAML file of one's own.

``fmcwlog calibrate LOG -o calib.yaml`` writes one (the log's record with the values the
log itself shows in place of its own, each with its uncertainty in a comment), and
``fmcwlog process LOG --calibration calib.yaml`` takes it instead of the log's record.
The keys and units are the record's (metres, radians; docs/log-format.md); a file may also be
written by hand, in YAML, JSON or TOML (by its suffix), with numbers or numeric strings, and
``lidar_upside_down`` true or false.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..config import read_structured_file
from ..errors import CalibrationError
from .atomic import write_text

UPSIDE_DOWN_KEY = "lidar_upside_down"  # true: the lidar is rolled by pi about its x axis (its scan mirrored)
FLAG_KEYS = (UPSIDE_DOWN_KEY,)  # the keys that are true or false, not numbers


def read_calibration_file(path: str | Path) -> dict[str, str]:
    """The file's keys and values as the record holds them (strings), for :func:`.calibration.load_calibration`.

    Raises :class:`CalibrationError` naming the file for anything that is not a flat table of numbers
    (true or false for :data:`FLAG_KEYS`, held as ``true`` and ``false``).
    """
    path = Path(path)
    data = read_structured_file(path, CalibrationError, default_format="yaml")
    if not isinstance(data, dict) or not data:
        raise CalibrationError(f"{path}: expected a table of calibration values (lidar_x: 0.35, ...)")
    values = {}
    for key, value in data.items():
        if str(key) in FLAG_KEYS:
            if isinstance(value, bool) or (isinstance(value, str) and value.strip().lower() in ("true", "false")):
                values[str(key)] = str(value).strip().lower()
                continue
            raise CalibrationError(f"{path}: {key!r} must be true or false, got {value!r}")
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise CalibrationError(f"{path}: {key!r} must be a number, got {value!r}")
        values[str(key)] = repr(value) if isinstance(value, float) else str(value)
    return values


def calibration_file_text(values: dict[str, str | float], notes: list[str]) -> str:
    """YAML text of ``values`` (the record's keys), ``notes`` as comments above them."""
    lines = [f"# {n}" for n in notes]
    for key, value in values.items():
        if isinstance(value, float):
            if not math.isfinite(value):
                raise CalibrationError(f"calibration {key!r} is not finite")
            value = repr(value)
        lines.append(f"{key}: {value}")
    return "\n".join(lines) + "\n"


def write_calibration_file(path: str | Path, values: dict[str, str | float], notes: list[str]) -> None:
    """Write :func:`calibration_file_text` to ``path`` atomically (never half-written)."""
    write_text(path, calibration_file_text(values, notes))
