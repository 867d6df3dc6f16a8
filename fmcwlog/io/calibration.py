"""The calibration processing uses: the ``fmcwlog.calibration`` metadata record as numbers
(docs/log-format.md), each checked against its physical range, with a calibration file before it
and the log's tf after it, for the mount.

Each group of values comes from the first source that gives it (:func:`load_calibration`):

- the mount (``lidar_x``, ``lidar_y``, ``lidar_yaw``): ``--calibration FILE``, the record, the
  log's ``/tf_static`` (or a ``/tf`` transform that never changes) from the scan's frame to the
  base frame (:mod:`.tf_tree`), else 0, 0, 0 with a warning saying how to give it;
- ``lidar_upside_down`` (true: the sensor rolled by π about its x axis, its scan mirrored): the
  file, the record, else the log's tf where tf gives the mount (a sensor whose z axis points
  down), else false;
- the wheels, which wheel ticks need: the file, else the record;
- the other keys: the file's, else the record's.

MCAP allows several metadata records of one name: identical copies are one calibration (with a
note), copies that disagree are refused, naming the keys they disagree on: there is no telling
which one the robot had.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TypeVar

from ..errors import CalibrationError, LogError
from ..types import Calibration, WheelCalibration
from .calibration_file import UPSIDE_DOWN_KEY, read_calibration_file
from .tf_tree import MessageSource, TfMount, mount_from_tf
from .topics import BASE_FRAME, CALIBRATION_KEY

T = TypeVar("T")


class LogSource(MessageSource, Protocol):
    """What calibration reads of a log: a reader's public interface."""

    def metadata_all(self, name: str) -> list[dict[str, str]]: ...

    def damage_note(self) -> str: ...

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


def _flag(values: dict[str, str], key: str) -> bool:
    """A key that is true or false (``true``, ``false``, any case)."""
    text = str(values[key]).strip().lower()
    if text not in ("true", "false"):
        raise CalibrationError(f"calibration {key!r} must be true or false, got {values[key]!r}")
    return text == "true"


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


def _mount(values: dict[str, str], source: str) -> tuple[float, float, float]:
    """The mount's keys of a source that gives some of them; a missing one is 0, with a warning naming
    ``source`` and the key: the log format (docs/log-format.md) lists them, and a writer that left
    one out would otherwise have its lidar moved without a word (a 12 s crowd log whose record
    lacked them all: the baseline's trajectory 11 cm off)."""
    missing = [k for k in MOUNT_KEYS if k not in values]
    if missing:
        warnings.warn(f"{source}: {CALIBRATION_KEY} has no {', '.join(missing)}: taken as 0 (the lidar "
                      "at base_link's origin, facing forward)", stacklevel=3)
    x, y, yaw = (_number(values, k) if k in values else 0.0 for k in MOUNT_KEYS)
    return x, y, yaw


def _wheels(values: dict[str, str]) -> WheelCalibration:
    r_left, r_right, track, ticks = (_number(values, k) for k in WHEEL_KEYS)
    if ticks != int(ticks):
        raise CalibrationError(f"calibration 'ticks_per_revolution' = {values['ticks_per_revolution']} "
                               "is not a whole number")
    return WheelCalibration(r_left, r_right, track, int(ticks))


# ----------------------------------------------------------------------------- the sources, in order

RECORD_SOURCE = f"log record {CALIBRATION_KEY}"
NO_MOUNT = "none (assumed 0, 0, 0)"
NO_WHEELS = "not used (no wheel ticks read)"
MOUNT_EXAMPLE = "{lidar_x: 0.35, lidar_y: 0.0, lidar_yaw: 0.0}"
WHEELS_EXAMPLE = "{wheel_radius_left: 0.1, wheel_radius_right: 0.1, track_width: 0.45, ticks_per_revolution: 4096}"
MOUNT_AGREES_M = 1e-3  # m: a record and tf closer than this (and MOUNT_AGREES_RAD) agree
MOUNT_AGREES_RAD = 1e-3  # rad


def mount_hint(log: str | Path, base_frame: str = BASE_FRAME) -> str:
    """How to give the mount: the option, a one-line file, and the command that estimates one."""
    return (f"give it with --calibration calib.yaml, a file such as '{MOUNT_EXAMPLE}' (m, m, rad in {base_frame}), "
            f"or estimate it with 'fmcwlog calibrate {log} -o calib.yaml' (needs Doppler and wheel ticks)")


def wheels_hint(log: str | Path) -> str:
    """How to give the wheels: the option, a one-line file, and the command that refines one."""
    return (f"give it with --calibration calib.yaml, a file such as '{WHEELS_EXAMPLE}' (m and encoder counts), "
            f"which 'fmcwlog calibrate {log} --calibration calib.yaml -o better.yaml' refines from the log's Doppler")


def wheels_missing(ticks: str, path: Path | None) -> str:
    """Why wheel ticks on ``ticks`` cannot be used: no source holds the wheels (``path``: the calibration file given)."""
    where = f"neither {path} nor the log's {CALIBRATION_KEY} record" if path is not None else \
        f"no {CALIBRATION_KEY} record in the log and no --calibration file"
    return (f"{ticks} holds wheel ticks, but nothing gives the wheels' geometry they need ({where} holds "
            f"{', '.join(WHEEL_KEYS)})")


@dataclass(frozen=True)
class CalibrationSources:
    """Where each group of the calibration came from, as ``run.json`` says it.

    mount: a calibration file's path, ``log record fmcwlog.calibration``, ``tf /tf_static
    base_link->laser`` (the topics and the frames) or :data:`NO_MOUNT`. wheels: a file's path or the
    record; None where no wheel ticks are read. upside_down: the source of ``lidar_upside_down``
    (a file, the record, or tf where its sensor's z axis points down); None where none gives it
    (the sensor upright).
    """

    mount: str
    wheels: str | None
    upside_down: str | None = None

    def describe(self) -> str:
        """``run.json``'s ``calibration_source``: the one source where it gave all that was used, else each group's."""
        groups = [("mount", self.mount), (UPSIDE_DOWN_KEY, self.upside_down), ("wheels", self.wheels)]
        given = [(name, src) for name, src in groups if src is not None]
        if all(src == self.mount for _, src in given):
            return self.mount
        return "; ".join(f"{name} from {src}" for name, src in given)

    def to_json(self) -> dict[str, str]:
        """``run.json``'s ``calibration_sources`` (``upside_down`` only where a source gives it)."""
        out = {"mount": self.mount, "wheels": self.wheels if self.wheels is not None else NO_WHEELS}
        if self.upside_down is not None:
            out["upside_down"] = self.upside_down
        return out


@dataclass(frozen=True)
class LoadedCalibration:
    """What :func:`load_calibration` found: the calibration (its ``wheels`` None where ticks need them and
    nothing gives them: the caller decides), each group's source, and the values as a record holds
    them, each from its source (what ``fmcwlog calibrate`` starts its file from)."""

    cal: Calibration
    sources: CalibrationSources
    values: dict[str, str]


@dataclass(frozen=True)
class _Source:
    label: str  # as run.json says it
    values: dict[str, str]
    names: str  # what its warnings and errors name: the file or the log
    is_file: bool

    def gives(self, keys: tuple[str, ...]) -> bool:
        return any(k in self.values for k in keys)

    def parse(self, fn: Callable[[dict[str, str]], T], damage: str = "") -> T:
        """``fn(values)``; a bad value is an error naming the file (CalibrationError) or the log (LogError)."""
        try:
            return fn(self.values)
        except CalibrationError as exc:
            if self.is_file:
                raise CalibrationError(f"{self.names}: {str(exc).removeprefix(f'{self.names}: ')}") from None
            raise LogError(f"{self.names}: {exc}{damage}") from None


def _fmt_mount(mount: tuple[float, float, float], upside_down: bool = False) -> str:
    x, y, yaw = (round(v, 6) + 0.0 for v in mount)
    return f"x {x:g} m, y {y:g} m, yaw {yaw:g} rad{', upside down' if upside_down else ''}"


def _agree(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
    dyaw = abs(math.remainder(a[2] - b[2], 2 * math.pi))
    return abs(a[0] - b[0]) <= MOUNT_AGREES_M and abs(a[1] - b[1]) <= MOUNT_AGREES_M and dyaw <= MOUNT_AGREES_RAD


def load_calibration(reader: LogSource, log: Path, scan_topic: str, need_wheels: bool, path: Path | None,
                     base_frame: str = BASE_FRAME) -> LoadedCalibration:
    """The calibration to process ``log`` with, each group from the first source that gives it.

    The mount (``lidar_x``, ``lidar_y``, ``lidar_yaw``): the calibration file at ``path``, the log's
    ``fmcwlog.calibration`` record, the log's tf from ``scan_topic``'s frame to ``base_frame``
    (:mod:`.tf_tree`), else 0, 0, 0 with a warning saying how to give it. A source gives the mount
    when it holds any of the three keys (one it lacks is 0, with a warning). ``lidar_upside_down``:
    the file's, the record's, else tf's where tf gives the mount, else false. Where the record gives
    the mount and tf another (upside down included), a warning names both and the one used. The wheels (``need_wheels``:
    wheel ticks are read): the file, else the record, else None (the caller falls back or fails).
    The other keys: the file's, else the record's.

    Raises :class:`~fmcwlog.errors.CalibrationError` (naming the file) for a bad file, and
    :class:`~fmcwlog.errors.LogError` (naming the log) for a bad record the calibration uses; a
    record that cannot be read (copies that disagree) is an error unless the file gives every group.
    """
    sources: list[_Source] = []
    if path is not None:
        try:
            sources.append(_Source(str(path), read_calibration_file(path), str(path), True))
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: {str(exc).removeprefix(f'{path}: ')}") from None
    complete = bool(sources) and sources[0].gives(MOUNT_KEYS) and (not need_wheels or sources[0].gives(WHEEL_KEYS))
    damage = reader.damage_note()
    try:
        record = calibration_record(reader.metadata_all(CALIBRATION_KEY), str(log))
    except CalibrationError as exc:
        if not complete:
            raise LogError(f"{log}: {exc}{reader.damage_note()}") from None
        warnings.warn(f"{log}: {exc}; {path} gives every value used", stacklevel=2)
        record = None
    if record is not None:
        sources.append(_Source(RECORD_SOURCE, record, str(log), False))

    values: dict[str, str] = {}
    mount_src = next((s for s in sources if s.gives(MOUNT_KEYS)), None)
    wheels_src = next((s for s in sources if s.gives(WHEEL_KEYS)), None) if need_wheels else None
    for s in sources:  # the keys as a record would hold them: each group from its source, the rest from the first
        for k, v in s.values.items():
            group = mount_src if k in MOUNT_KEYS else wheels_src if k in WHEEL_KEYS and need_wheels else None
            if (s is group or (group is None and k not in MOUNT_KEYS)) and k not in values:
                values[k] = v

    wheels = wheels_src.parse(_wheels, damage) if wheels_src is not None else None
    if mount_src is not None:
        names = mount_src.names
        mount = mount_src.parse(lambda v: _mount(v, names), damage)
    flag_src = next((s for s in sources if UPSIDE_DOWN_KEY in s.values), None)
    upside_down = flag_src.parse(functools.partial(_flag, key=UPSIDE_DOWN_KEY), damage) if flag_src else False
    flag_label = flag_src.label if flag_src is not None else None
    opt: dict[str, float | None] = {k: None for k in OPTIONAL_KEYS}
    for k in OPTIONAL_KEYS:
        src = next((s for s in sources if k in s.values), None)
        if src is not None:
            opt[k] = src.parse(functools.partial(_number, key=k), damage)
    if mount_src is not None:
        mount_label = mount_src.label
        if not mount_src.is_file:
            # the roll too, where the record says it or none does: a file's overrides both, unsaid
            flag = None if flag_src is not None and flag_src.is_file else upside_down
            _compare_with_tf(reader, log, scan_topic, base_frame, mount, flag)
    else:
        found, notes = mount_from_tf(reader, scan_topic, base_frame)
        for note in notes:
            warnings.warn(note, stacklevel=2)
        if isinstance(found, TfMount):
            mount, mount_label = found.mount, found.source
            values.update({k: repr(v) for k, v in zip(MOUNT_KEYS, mount)})
            if flag_src is None and found.upside_down:  # tf gives the mount, and says it
                upside_down, flag_label = True, found.source
                values[UPSIDE_DOWN_KEY] = "true"
                warnings.warn(found.upside_down_note(log, base_frame), stacklevel=2)
        else:
            mount, mount_label = (0.0, 0.0, 0.0), NO_MOUNT
            have = f"no {CALIBRATION_KEY} record" if record is None else f"{CALIBRATION_KEY} has no {', '.join(MOUNT_KEYS)}"
            warnings.warn(f"{log}: nothing gives the lidar's mount ({have}; tf: {found}): taken as 0, 0, 0 (the "
                          f"lidar at {base_frame}'s origin, facing forward); {mount_hint(log, base_frame)}", stacklevel=2)
    cal = Calibration(wheels, mount, opt["doppler_resolution"], opt["range_sigma"], opt["max_range"],
                      opt["scan_rate"] or None, upside_down)
    wheels_label = None if not need_wheels else wheels_src.label if wheels_src is not None else "none"
    return LoadedCalibration(cal, CalibrationSources(mount_label, wheels_label, flag_label), values)


def _compare_with_tf(reader: LogSource, log: Path, scan_topic: str, base_frame: str,
                     mount: tuple[float, float, float], upside_down: bool | None) -> None:
    """The record's mount against the log's tf, where it has one: a warning naming both where they
    differ (in x, y, yaw, or, unless ``upside_down`` is None, one upside down and the other not)."""
    found, notes = mount_from_tf(reader, scan_topic, base_frame)
    if not isinstance(found, TfMount):
        return
    for note in notes:
        warnings.warn(note, stacklevel=3)
    roll = found.upside_down if upside_down is None else upside_down
    if not _agree(mount, found.mount) or roll != found.upside_down:
        warnings.warn(f"{log}: {CALIBRATION_KEY} and tf disagree on the lidar's mount: the record has "
                      f"{_fmt_mount(mount, bool(upside_down))}, {found.source} has "
                      f"{_fmt_mount(found.mount, found.upside_down)}; used the record's "
                      "(--calibration FILE overrides both)", stacklevel=3)
