"""Real 2-D laser logs: CARMEN (``FLASER``, ``RLASER``, ``ROBOTLASER1``, ``ODOM``, ``PARAM``) and the
CMU Wean Hall course format (``O``/``L`` lines in centimetres), parsed into numpy records.

Pure parsing, no MCAP: :mod:`fmcwlog.importer` writes the records as a log.

CARMEN conventions followed (``carmen/src/logger``):

- ``FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp``: ranges in m,
  beams evenly over the front laser's field of view (``PARAM robot_front_laser_fov``, default 180°),
  from the right (−fov/2) counter-clockwise, ``fov/n`` apart (``fov/(n−1)`` for an odd count such as
  181); the laser sits ``robot_frontlaser_offset`` m ahead of the robot. ``RLASER`` likewise, facing
  backwards (``robot_rearlaser_offset``).
- ``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r1..rn m [rem1..remm]
  laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv fsd ssd turn_axis ipc_timestamp host
  logger_timestamp``: the laser's pose relative to the robot is ``inv(robot) ⊕ laser``.
- ``ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp``.
- ``PARAM name value ipc_timestamp host logger_timestamp``.

Times are the ``ipc_timestamp`` (s), which benchmark relations refer to. Ranges at or beyond the maximum
range are no returns. A malformed line is counted and reported by number, never fatal on its own.
"""

from __future__ import annotations

import gzip
import lzma
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import between


@dataclass
class ScanRecord:
    stamp: float  # s
    angle_min: float  # rad, in the laser frame
    angle_increment: float  # rad
    ranges: np.ndarray  # (n,) m; inf where no return
    range_max: float  # m
    laser_pose: tuple[float, float, float]  # laser in the robot frame
    odom_pose: tuple[float, float, float] | None  # the robot's odometry pose at the scan, if the line has it
    topic: str = "/scan"


@dataclass
class OdomRecord:
    stamp: float
    pose: tuple[float, float, float]


@dataclass
class ParsedLog:
    path: Path
    format: str  # "carmen" or "cmu"
    scans: list[ScanRecord] = field(default_factory=list)
    odometry: list[OdomRecord] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)
    bad_lines: list[tuple[int, str]] = field(default_factory=list)  # (line number, why)
    ignored: dict[str, int] = field(default_factory=dict)  # message types not used, with counts


def open_text(path: Path):
    """Open a plain, ``.xz`` or ``.gz`` text file."""
    if path.suffix == ".xz":
        return lzma.open(path, "rt", errors="replace")
    if path.suffix == ".gz":
        return gzip.open(path, "rt", errors="replace")
    return open(path, errors="replace")


class _Bad(ValueError):
    pass


def _floats(tokens: list[str], what: str) -> list[float]:
    try:
        vals = [float(t) for t in tokens]
    except ValueError:
        raise _Bad(f"{what}: not a number") from None
    if not all(math.isfinite(v) or math.isinf(v) for v in vals):
        raise _Bad(f"{what}: NaN")
    return vals


def _param(params: dict[str, str], name: str, default: float) -> float:
    try:
        return float(params[name])
    except (KeyError, ValueError):
        return default


def _flaser(tok: list[str], params: dict[str, str], rear: bool) -> ScanRecord:
    n = int(tok[1])
    if n <= 0 or len(tok) < 2 + n + 7:
        raise _Bad(f"expected {n} ranges and 7 more fields, got {len(tok) - 2} fields")
    ranges = np.array(_floats(tok[2:2 + n], "ranges"))
    x, y, th, ox, oy, oth, stamp = _floats(tok[2 + n:2 + n + 7], "pose or timestamp")
    side = "rear" if rear else "front"
    fov = math.radians(_param(params, f"robot_{side}_laser_fov", 180.0))
    # An even count (180, 360) spans the field of view in steps of fov/n from -fov/2 (the Intel and
    # Freiburg logs: beam i at -90 deg + i deg); an odd one (181, 361) includes both ends.
    increment = fov / (n - 1) if n % 2 else fov / n
    angle_min = -fov / 2
    offset = _param(params, f"robot_{side}laser_offset", 0.0)
    max_range = _param(params, f"robot_{side}_laser_max", 81.0)
    ranges = np.where(ranges >= max_range - 1e-6, np.inf, ranges)
    mount = (-offset, 0.0, math.pi) if rear else (offset, 0.0, 0.0)
    return ScanRecord(stamp, angle_min, increment, ranges, max_range, mount, (ox, oy, oth),
                      "/rear_scan" if rear else "/scan")


def _robotlaser1(tok: list[str]) -> ScanRecord:
    start, fov, res, max_range = _floats(tok[2:6], "angles or range")
    n = int(tok[8])
    ranges = np.array(_floats(tok[9:9 + n], "ranges"))
    m = int(tok[9 + n])
    rest = tok[10 + n + m:]
    if len(rest) < 12:
        raise _Bad(f"expected 12 fields after the remissions, got {len(rest)}")
    lx, ly, lth, rx, ry, rth = _floats(rest[0:6], "poses")
    stamp = _floats([rest[11]], "timestamp")[0]
    mount = tuple(float(v) for v in between(np.array([rx, ry, rth]), np.array([lx, ly, lth])))
    ranges = np.where(ranges >= max_range - 1e-6, np.inf, ranges)
    return ScanRecord(stamp, start, res, ranges, max_range, mount, (rx, ry, rth))


def _cmu_laser(tok: list[str]) -> ScanRecord:
    if len(tok) != 188:
        raise _Bad(f"an L line has 188 fields, this one {len(tok)}")
    x, y, th, xl, yl, thl = _floats(tok[1:7], "poses")
    ranges = np.array(_floats(tok[7:187], "ranges")) / 100.0  # cm -> m
    stamp = _floats([tok[187]], "timestamp")[0]
    mount = tuple(float(v) for v in between(np.array([x / 100, y / 100, th]), np.array([xl / 100, yl / 100, thl])))
    ranges = np.where(ranges >= 81.8, np.inf, ranges)  # 8183-8191 cm: no return
    # 180 beams over 180 degrees from the right, 1 degree apart (instruct.txt); -90 deg first (see SOURCE.md)
    return ScanRecord(stamp, -math.pi / 2, math.pi / 180, ranges, 81.8, mount, (x / 100, y / 100, th))


def parse_log(path: str | Path) -> ParsedLog:
    """Parse a CARMEN or CMU course log; the format is recognised from its first data line."""
    path = Path(path)
    out = ParsedLog(path, "carmen")
    fmt = None
    with open_text(path) as fh:
        for lineno, line in enumerate(fh, 1):
            tok = line.split()
            if not tok or tok[0].startswith("#"):
                continue
            kind = tok[0]
            if fmt is None:
                fmt = "cmu" if kind in ("O", "L") else "carmen"
                out.format = fmt
            try:
                if fmt == "cmu":
                    if kind == "O":
                        if len(tok) != 5:
                            raise _Bad(f"an O line has 5 fields, this one {len(tok)}")
                        x, y, th, ts = _floats(tok[1:5], "pose or timestamp")
                        out.odometry.append(OdomRecord(ts, (x / 100, y / 100, th)))
                    elif kind == "L":
                        out.scans.append(_cmu_laser(tok))
                    else:
                        raise _Bad(f"unknown record {kind!r} in a CMU course log")
                elif kind == "PARAM":
                    if len(tok) < 3:
                        raise _Bad("PARAM without a value")
                    out.params[tok[1]] = tok[2]
                elif kind in ("FLASER", "RLASER"):
                    out.scans.append(_flaser(tok, out.params, rear=kind == "RLASER"))
                elif kind == "ROBOTLASER1":
                    out.scans.append(_robotlaser1(tok))
                elif kind == "ODOM":
                    if len(tok) < 8:
                        raise _Bad(f"ODOM has at least 8 fields, this one {len(tok)}")
                    x, y, th = _floats(tok[1:4], "pose")
                    out.odometry.append(OdomRecord(_floats([tok[7]], "timestamp")[0], (x, y, th)))
                else:
                    out.ignored[kind] = out.ignored.get(kind, 0) + 1
            except (_Bad, IndexError, ValueError) as exc:
                why = str(exc) if isinstance(exc, _Bad) else f"{kind}: too few or malformed fields"
                out.bad_lines.append((lineno, why))
    return out
