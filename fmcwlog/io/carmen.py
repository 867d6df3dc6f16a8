"""Real 2-D laser logs: CARMEN (``FLASER``, ``RLASER``, ``ROBOTLASER1``, ``RAWLASER1``/``2``, ``ODOM``,
``PARAM``) and the CMU Wean Hall course format (``O``/``L`` lines in centimetres), parsed into numpy records.

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
- ``RAWLASER1 type start_angle fov resolution max_range accuracy remission_mode n r1..rn m [rem1..remm]
  ipc_timestamp host logger_timestamp``: the front laser alone (``RAWLASER2`` the rear one), mounted as
  ``FLASER`` (``RLASER``) from ``PARAM``; used only where no ``FLASER``/``ROBOTLASER1`` (``RLASER``) line
  gives that laser, since the CARMEN logger writes the same scan as both. ``RAWLASER3``/``4`` are not read.
- ``ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp``.
- ``PARAM name value ipc_timestamp host logger_timestamp``.

Times are the ``ipc_timestamp`` (s), which benchmark relations refer to. A record older than the latest of
its stream (a laser's, or odometry) is kept and its line noted in :attr:`ParsedLog.backwards`: the importer
writes every stream in time order and warns, naming the line. Ranges at or beyond the maximum
range are no returns. A malformed line is counted and reported by number, never fatal on its own; so is a
line whose values are impossible: NaN anywhere, a negative or infinite time or one past 2038 (ROS 2 stamps
count seconds in an int32), a negative range, a pose beyond 1000 km or a heading beyond 1000 rad, a beam
count below 2, a PARAM value outside its range (the default is kept). A compressed file that ends early is
read up to its end (a warning); one whose compressed data are damaged is refused, since the lines before the
damage may be garbage too (gzip and xz check their CRC only at the end).
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CarmenImportError, excerpt
from ..geometry import between

MAX_STAMP_S = 2**31 - 1  # builtin_interfaces/Time.sec is an int32
MAX_POSITION_M = 1e6
MAX_HEADING_RAD = 1e3
# PARAM values read here and their valid ranges (deg or m)
PARAM_RANGES = {"robot_front_laser_fov": (1.0, 360.0), "robot_rear_laser_fov": (1.0, 360.0),
                "robot_frontlaser_offset": (-10.0, 10.0), "robot_rearlaser_offset": (-10.0, 10.0),
                "robot_front_laser_max": (0.1, 10_000.0), "robot_rear_laser_max": (0.1, 10_000.0)}


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
    raw: bool = False  # from a RAWLASERn line: kept only where no FLASER/ROBOTLASER1 (RLASER) line gives the laser


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
    lines: int = 0  # lines read
    stopped: str | None = None  # why reading stopped before the end of the file (a compressed file cut off)
    backwards: list[tuple[int, float]] = field(default_factory=list)  # (line number, s back): time went back


# A compressed file is known by its first bytes, not its name: logs ship as .gz, .GZ, .xz or .bz2, and a
# gzip stream saved as ``log.clf`` is common (a browser undoing nothing). Text is UTF-8 with an optional
# byte-order mark (Windows editors write one; left in, it would hide the first line's message name).
_MAGIC = ((b"\x1f\x8b", gzip.open), (b"\xfd7zXZ\x00", lzma.open), (b"BZh", bz2.open))


def open_text(path: Path):
    """Open a plain, xz, gzip or bzip2 text file (UTF-8, a byte-order mark dropped), known by its first bytes."""
    with open(path, "rb") as fh:
        head = fh.read(6)
    for magic, opener in _MAGIC:
        if head.startswith(magic):
            return opener(path, "rt", encoding="utf-8-sig", errors="replace")
    return open(path, encoding="utf-8-sig", errors="replace")


class _Bad(ValueError):
    pass


def _floats(tokens: list[str], what: str, finite: bool = True) -> list[float]:
    """Numbers of ``tokens``; NaN is always bad, infinity unless ``finite`` is False (ranges: no return)."""
    try:
        vals = [float(t) for t in tokens]
    except ValueError:
        raise _Bad(f"{what}: not a number") from None
    if any(math.isnan(v) or (finite and math.isinf(v)) for v in vals):
        raise _Bad(f"{what}: NaN or infinite")
    return vals


def _stamp(token: str) -> float:
    t = _floats([token], "timestamp")[0]
    if not 0.0 <= t <= MAX_STAMP_S:
        raise _Bad(f"timestamp {excerpt(token)} s is outside [0, {MAX_STAMP_S}] s")
    return t


def _pose(tokens: list[str], what: str, scale: float = 1.0) -> tuple[float, float, float]:
    x, y, th = _floats(tokens, what)
    x, y = x * scale, y * scale
    if max(abs(x), abs(y)) > MAX_POSITION_M or abs(th) > MAX_HEADING_RAD:
        raise _Bad(f"{what}: ({x:g} m, {y:g} m, {th:g} rad) is beyond {MAX_POSITION_M:g} m or {MAX_HEADING_RAD:g} rad")
    return x, y, th


def _ranges(tokens: list[str]) -> np.ndarray:
    r = np.array(_floats(tokens, "ranges", finite=False))
    if r.size and r.min() < 0:
        raise _Bad(f"ranges: a negative range ({r.min():g} m)")
    return r


def _count(token: str, low: int, what: str) -> int:
    n = int(token)
    if n < low:
        raise _Bad(f"{what} {n} is below {low}")
    return n


def _param(params: dict[str, str], name: str, default: float) -> float:
    try:
        return float(params[name])
    except (KeyError, ValueError):
        return default


def _flaser(tok: list[str], params: dict[str, str], rear: bool) -> ScanRecord:
    n = _count(tok[1], 2, "beam count")
    if len(tok) < 2 + n + 9:  # up to the logger timestamp: a line cut short (a file cut off) fails here
        raise _Bad(f"expected {n} ranges and 9 more fields, got {len(tok) - 2} fields")
    ranges = _ranges(tok[2:2 + n])
    _pose(tok[2 + n:2 + n + 3], "laser pose")
    ox, oy, oth = _pose(tok[2 + n + 3:2 + n + 6], "odometry pose")
    stamp = _stamp(tok[2 + n + 6])
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


def _laser_fields(tok: list[str]) -> tuple[float, float, float, np.ndarray, list[str]]:
    """``ROBOTLASER1``'s and ``RAWLASERn``'s common head: start angle, resolution (rad), maximum range (m),
    the ranges (inf at or past the maximum) and the fields after the remissions."""
    start, fov, res, max_range = _floats(tok[2:6], "angles or range")
    if not (abs(start) <= 2 * math.pi and 0 < fov <= 2 * math.pi + 1e-6 and 0 < res <= fov and 0.1 <= max_range <= 1e4):
        raise _Bad(f"start angle {start:g}, field of view {fov:g}, resolution {res:g} rad or "
                   f"maximum range {max_range:g} m out of range")
    n = _count(tok[8], 1, "beam count")
    if len(tok) < 10 + n:
        raise _Bad(f"expected {n} ranges, got {len(tok) - 9} fields")
    ranges = _ranges(tok[9:9 + n])
    m = _count(tok[9 + n], 0, "remission count")
    ranges = np.where(ranges >= max_range - 1e-6, np.inf, ranges)
    return start, res, max_range, ranges, tok[10 + n + m:]


def _robotlaser1(tok: list[str]) -> ScanRecord:
    start, res, max_range, ranges, rest = _laser_fields(tok)
    if len(rest) < 14:
        raise _Bad(f"expected 14 fields after the remissions, got {len(rest)}")
    lx, ly, lth = _pose(rest[0:3], "laser pose")
    rx, ry, rth = _pose(rest[3:6], "robot pose")
    stamp = _stamp(rest[11])
    mx, my, mth = (float(v) for v in between(np.array([rx, ry, rth]), np.array([lx, ly, lth])))
    mount = (mx, my, mth)
    return ScanRecord(stamp, start, res, ranges, max_range, mount, (rx, ry, rth))


def _rawlaser(tok: list[str], params: dict[str, str]) -> ScanRecord:
    """``RAWLASER1`` (the front laser) or ``RAWLASER2`` (the rear one): the laser alone, no pose; its
    mount from ``PARAM`` as for ``FLASER``/``RLASER``, the robot's motion from ``ODOM``."""
    start, res, max_range, ranges, rest = _laser_fields(tok)
    if len(rest) < 3:
        raise _Bad(f"expected 3 fields after the remissions, got {len(rest)}")
    stamp = _stamp(rest[0])
    rear = tok[0] == "RAWLASER2"
    offset = _param(params, f"robot_{'rear' if rear else 'front'}laser_offset", 0.0)
    mount = (-offset, 0.0, math.pi) if rear else (offset, 0.0, 0.0)
    return ScanRecord(stamp, start, res, ranges, max_range, mount, None, "/rear_scan" if rear else "/scan", raw=True)


def _cmu_laser(tok: list[str]) -> ScanRecord:
    if len(tok) != 188:
        raise _Bad(f"an L line has 188 fields, this one {len(tok)}")
    robot = _pose(tok[1:4], "robot pose", 0.01)  # cm -> m
    laser = _pose(tok[4:7], "laser pose", 0.01)
    ranges = _ranges(tok[7:187]) / 100.0
    stamp = _stamp(tok[187])
    mx, my, mth = (float(v) for v in between(np.array(robot), np.array(laser)))
    mount = (mx, my, mth)
    ranges = np.where(ranges >= 81.8, np.inf, ranges)  # 8183-8191 cm: no return
    # 180 beams over 180 degrees from the right, 1 degree apart (instruct.txt); -90 deg first (see SOURCE.md)
    return ScanRecord(stamp, -math.pi / 2, math.pi / 180, ranges, 81.8, mount, robot)


def _cmu_line(tok: list[str], out: ParsedLog) -> None:
    kind = tok[0]
    if kind == "O":
        if len(tok) != 5:
            raise _Bad(f"an O line has 5 fields, this one {len(tok)}")
        out.odometry.append(OdomRecord(_stamp(tok[4]), _pose(tok[1:4], "pose", 0.01)))
    elif kind == "L":
        out.scans.append(_cmu_laser(tok))
    else:
        raise _Bad(f"unknown record {kind!r} in a CMU course log")


def _carmen_line(tok: list[str], out: ParsedLog) -> None:
    kind = tok[0]
    if kind == "PARAM":
        if len(tok) < 3:
            raise _Bad("PARAM without a value")
        if tok[1] in PARAM_RANGES:
            low, high = PARAM_RANGES[tok[1]]
            value = _floats([tok[2]], f"PARAM {tok[1]}")[0]
            if not low <= value <= high:
                raise _Bad(f"PARAM {tok[1]} = {tok[2]} is outside [{low:g}, {high:g}]; kept the default")
        out.params[tok[1]] = tok[2]
    elif kind in ("FLASER", "RLASER"):
        out.scans.append(_flaser(tok, out.params, rear=kind == "RLASER"))
    elif kind == "ROBOTLASER1":
        out.scans.append(_robotlaser1(tok))
    elif kind in ("RAWLASER1", "RAWLASER2"):
        out.scans.append(_rawlaser(tok, out.params))
    elif kind == "ODOM":
        if len(tok) < 10:
            raise _Bad(f"ODOM has at least 10 fields, this one {len(tok)}")
        out.odometry.append(OdomRecord(_stamp(tok[7]), _pose(tok[1:4], "pose")))
    else:
        out.ignored[kind] = out.ignored.get(kind, 0) + 1


def _check_order(out: ParsedLog, lineno: int, counts: tuple[int, int], latest: dict[str, float]) -> None:
    """Note the line if the record it added is older than the latest of its stream (a laser's or odometry)."""
    if len(out.scans) > counts[0]:
        stream, t = out.scans[-1].topic, out.scans[-1].stamp
    elif len(out.odometry) > counts[1]:
        stream, t = "/odom", out.odometry[-1].stamp
    else:
        return
    if t < latest.get(stream, -math.inf):
        out.backwards.append((lineno, latest[stream] - t))
    latest[stream] = max(t, latest.get(stream, -math.inf))


def _drop_raw_duplicates(out: ParsedLog) -> None:
    """A log with ``FLASER`` or ``ROBOTLASER1`` lines holds the same scans as ``RAWLASER1`` lines (the
    CARMEN logger writes both); keep the ones with the robot's pose and count the raw ones as ignored."""
    posed = {s.topic for s in out.scans if not s.raw}
    dropped = [s for s in out.scans if s.raw and s.topic in posed]
    for s in dropped:
        kind = "RAWLASER2" if s.topic == "/rear_scan" else "RAWLASER1"
        out.ignored[kind] = out.ignored.get(kind, 0) + 1
    if dropped:
        out.scans = [s for s in out.scans if not (s.raw and s.topic in posed)]


def parse_log(path: str | Path) -> ParsedLog:
    """Parse a CARMEN or CMU course log; the format is recognised from its first data line.

    A compressed file cut off is parsed up to its end (:attr:`ParsedLog.stopped` says so; the
    importer warns); damaged compressed data raise :class:`CarmenImportError`.
    """
    path = Path(path)
    out = ParsedLog(path, "carmen")
    data_lines = 0
    latest: dict[str, float] = {}
    fh = open_text(path)  # a file that cannot be opened is the caller's OSError, never 'damaged data'
    try:
        with fh:
            for lineno, line in enumerate(fh, 1):
                out.lines = lineno
                tok = line.split()
                if not tok or tok[0].startswith("#"):
                    continue
                data_lines += 1
                if data_lines == 1:
                    out.format = "cmu" if tok[0] in ("O", "L") else "carmen"
                counts = (len(out.scans), len(out.odometry))
                try:
                    (_cmu_line if out.format == "cmu" else _carmen_line)(tok, out)
                    _check_order(out, lineno, counts, latest)
                except (_Bad, IndexError, ValueError) as exc:
                    why = str(exc) if isinstance(exc, _Bad) else f"{excerpt(tok[0])}: too few or malformed fields"
                    out.bad_lines.append((lineno, why))
    except EOFError:
        out.stopped = f"the compressed file ends early, after line {out.lines}"
    except (lzma.LZMAError, zlib.error, OSError) as exc:  # gzip's and bzip2's damaged data are OSErrors
        if isinstance(exc, OSError) and not isinstance(fh.buffer, (gzip.GzipFile, bz2.BZ2File)):
            raise  # a plain file's read error is the caller's to report
        where = f"after line {out.lines}" if out.lines else "from its start"
        raise CarmenImportError(f"{path}: its compressed data are damaged {where} ({exc})") from None
    _drop_raw_duplicates(out)
    return out
