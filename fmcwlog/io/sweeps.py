"""A scan message (PointCloud2 or LaserScan) decoded into a :class:`~fmcwlog.types.SweepInput`,
checked against physical bounds as it is decoded.

The bounds (:class:`InputLimits`) and why:

- point times ``t`` in ``[0, 1/scan_rate]``: ``header.stamp`` is the first beam's
  time (docs/log-format.md) and a sweep ends before the next begins; 1 s where the
  calibration gives no rate (no scanning LiDAR sweeps slower than 1 Hz). Both ends
  are widened by :func:`time_slack`, the precision of a float32 time at that bound:
  a 360° scanner's last beam falls on the period itself, and the period stored as
  float32 (0.1 s is 0.10000000149 s) lies beyond it;
- points within twice the calibration's ``max_range`` of the sensor (bright targets
  return beyond the rated range; the logs here reach 30.0000004 m of 30 m), else 1 km
  (beyond every planar LiDAR; the longest-range ones reach ~300 m): a damaged
  coordinate would otherwise grow the occupancy grid to terabytes;
- radial (Doppler) velocities within ±2·MAX_SPEED: a target and the sensor each
  move at most :data:`MAX_SPEED` (100 m/s, beyond any wheeled robot carrying a 2-D LiDAR).

A message outside them raises :class:`Rejected`, which :class:`fmcwlog.io.inputs.LogInputs`
counts and skips.

No-returns are not damage: a PointCloud2 point whose ``x``, ``y`` (``z``, ``velocity`` where read) is
NaN or infinite, or which lies exactly at the sensor's origin (what organised clouds publish where a
beam saw nothing), is dropped as it is decoded and counted (:attr:`CloudLayout.no_returns`); so is a
LaserScan range that is not finite, outside ``[range_min, range_max]`` or zero (REP-117). A sweep of
no-returns only has no points (``empty``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LogError
from ..types import Calibration, SweepInput
from .clouds import TIME_FIELD_HELP, CloudReading, TimeField, choose_time_field, is_3d, planar_doppler, plane_band, ring_field
from .messages import POINTFIELD_NUMPY, stamp_ns

MAX_SPEED = 100.0  # m/s: beyond any wheeled robot carrying a 2-D LiDAR
MAX_ODOM_POSITION = 1e8  # m: beyond any map frame on Earth (UTM northings reach 1e7 m)
TIME_SLACK_ULPS = 4  # float32 ulps of the period that a point time may lie beyond it (time_slack)


def time_slack(period_s: float) -> float:
    """How far (s) a point time may lie outside ``[0, period_s]`` and still be read as within it:
    :data:`TIME_SLACK_ULPS` float32 ulps of the period.

    Point times and LaserScan's ``time_increment`` are float32 (PointCloud2 ``t`` often, LaserScan
    always). A time stored as float32 is within half an ulp of the true one; a beam time computed
    as ``i · time_increment`` carries ``time_increment``'s relative rounding (2^-24) over at most
    the period, under one ulp of it; stored as float32 again, half an ulp more. That is under two
    ulps; four leaves a margin of two, and at 10 Hz is 30 ns, far below any damage the bound is
    there to catch (seconds, or 1e6 s).
    """
    return TIME_SLACK_ULPS * float(np.spacing(np.float32(period_s)))


@dataclass(frozen=True)
class InputLimits:
    """Bounds beyond which a decoded value is damage, not a measurement (module docstring).

    max_sweep_s: latest point time in a sweep, s. max_range_m: farthest point from the sensor, m.
    scan_rate: the calibration's ``scan_rate`` (Hz) ``max_sweep_s`` comes from; None where it gave none.
    """

    max_sweep_s: float = 1.0
    max_range_m: float = 1000.0
    scan_rate: float | None = None

    @classmethod
    def from_calibration(cls, cal: Calibration) -> InputLimits:
        return cls(1.0 / cal.scan_rate if cal.scan_rate else 1.0,
                   2.0 * cal.max_range if cal.max_range else 1000.0, cal.scan_rate or None)

    def sweep_bound(self) -> str:
        """``, beyond a sweep's 0.02 s (1 / the calibration's scan_rate, 50 Hz)``: where the bound of point
        times comes from, for a message refusing them; empty where no scan_rate set it."""
        if not self.scan_rate:
            return ""
        return f", beyond a sweep's {self.max_sweep_s:g} s (1 / the calibration's scan_rate, {self.scan_rate:g} Hz)"


class Rejected(LogError):
    """A message that cannot be used: ``kind`` names the check it failed, ``detail`` how."""

    def __init__(self, path: Path, what: str, ns: int | None, kind: str, detail: str):
        at = f"at {ns * 1e-9:.3f} s: " if ns is not None else ""
        super().__init__(f"{path}: {what} {at}{detail}")
        self.kind = kind
        self.detail = at + detail


def header_stamp(path: Path, what: str, header: Any) -> int:
    sec, nsec = int(header.stamp.sec), int(header.stamp.nanosec)
    if sec < 0 or not 0 <= nsec < 1_000_000_000:
        raise Rejected(path, what, None, "stamp", f"invalid stamp {sec} s {nsec} ns")
    return stamp_ns(header.stamp)


PointField = tuple[str, int, int, int]  # a PointField's name, offset, datatype, count


@dataclass(frozen=True)
class _CloudPlan:
    """What a PointCloud2's fields say, the same for every message of one layout: the fields by name
    (``types``: name -> datatype), the first of x, y that is missing, the time field (or why none can
    be read: ``time_error``), the ring field, the fields read (``wanted``: name, dtype, offset) and
    what of the layout check depends on the fields alone (:func:`_cloud_layout_problem`)."""

    types: dict[str, int]
    missing: str | None
    time: TimeField | None
    time_error: str | None
    ring: str | None
    wanted: tuple[tuple[str, np.dtype | None, int], ...]  # a None dtype only where field_problem says so
    field_problem: str | None  # a field read has an unknown datatype or no element
    end: int  # bytes a point's fields span
    overlap: str | None  # two fields share bytes


@lru_cache(maxsize=64)
def _cloud_plan(fields: tuple[PointField, ...], mapped: TimeField | None) -> _CloudPlan:
    """:class:`_CloudPlan` of a cloud with ``fields`` and ``--time-field`` ``mapped``. A log's clouds
    share their fields, so this runs once a layout (its checks cost a quarter of reading a sweep)."""
    types = {name: int(datatype) for name, _, datatype, _ in fields}
    names = set(types)
    missing = sorted({"x", "y"} - names)
    time, time_error = None, None
    try:
        time = choose_time_field(types, mapped)
    except LogError as exc:
        time_error = str(exc)
    ring = ring_field(types)
    # t is read even when another field holds the times: a damaged t is a damaged sweep, as it always was
    extra = [n for n in dict.fromkeys(("z", "t", time.name if time else None, ring)) if n is not None and n in names]
    wanted = [n for n in ("x", "y", "velocity", "intensity") if n in names] + extra
    field_problem, spans = None, []
    for name, offset, datatype, count in fields:
        dtype = POINTFIELD_NUMPY.get(datatype)
        if dtype is None:
            if name in wanted and field_problem is None:
                field_problem = f"field {name!r} has unknown datatype {datatype}"
            continue
        if name in wanted and count < 1 and field_problem is None:
            field_problem = f"field {name!r} has count {count}"
        spans.append((int(offset), int(offset) + dtype.itemsize * max(int(count), 1), name))
    spans.sort()
    overlap = next((f"fields {a!r} and {b!r} overlap" for (_, e0, a), (s1, _, b) in zip(spans, spans[1:]) if s1 < e0), None)
    by_name = {name: (POINTFIELD_NUMPY.get(datatype), int(offset)) for name, offset, datatype, _ in fields}
    return _CloudPlan(types, missing[0] if missing else None, time, time_error, ring,
                      tuple((n, *by_name[n]) for n in wanted), field_problem,
                      max((e for _, e, _ in spans), default=0), overlap)


def _cloud_layout_problem(msg: Any, plan: _CloudPlan) -> str | None:
    """Why a PointCloud2's layout cannot be read (None: it can): fields against point_step and data."""
    if msg.is_bigendian:
        return "big-endian PointCloud2 is not supported"
    if plan.field_problem is not None:
        return plan.field_problem
    step, n = int(msg.point_step), int(msg.width) * int(msg.height)
    if step < plan.end or step == 0:
        return f"point_step {step} is smaller than its fields ({plan.end} bytes)"
    if plan.overlap is not None:
        return plan.overlap
    if int(msg.height) > 1 and int(msg.row_step) != int(msg.width) * step:
        return f"rows padded (row_step {msg.row_step}, width × point_step {int(msg.width) * step}) are not supported"
    if len(msg.data) < n * step:
        return f"data holds {len(msg.data)} bytes, width × height × point_step is {n * step}"
    return None


def _cloud_columns(msg: Any, plan: _CloudPlan) -> dict[str, np.ndarray]:
    """The fields read, as float64 (N,), of a cloud whose layout :func:`_cloud_layout_problem` passed
    (as :func:`~fmcwlog.io.messages.pointcloud_columns` reads them, without its checks)."""
    n, step = int(msg.width) * int(msg.height), int(msg.point_step)
    if n == 0:
        return {name: np.zeros(0) for name, _, _ in plan.wanted}
    data = bytes(msg.data)
    return {name: np.ndarray((n,), dtype=dtype, buffer=data, offset=offset, strides=(step,)).astype(np.float64)
            for name, dtype, offset in plan.wanted}


def _check_points(path: Path, what: str, ns: int, xy: np.ndarray, t: np.ndarray, velocity: np.ndarray | None,
                  limits: InputLimits) -> None:
    """Finite values, point times within the sweep, points within the sensor's reach."""
    if len(t) == 0:
        raise Rejected(path, what, ns, "empty", "no points")
    # array methods rather than numpy's functions (np.all, np.max): the same reductions, without
    # the dispatch wrappers, a third of this check's time on a sweep of 1,000 points
    for name, a in (("x or y", xy), ("t", t), ("velocity", velocity)):
        if a is not None and not np.isfinite(a).all():
            raise Rejected(path, what, ns, "nonfinite", f"{name} holds NaN or infinite values")
    slack = time_slack(limits.max_sweep_s)
    t_min, t_max = t.min(), t.max()
    if t_min < -slack or t_max > limits.max_sweep_s + slack:
        raise Rejected(path, what, ns, "times", f"point times span [{t_min:.10g}, {t_max:.10g}] s"
                                                f"{limits.sweep_bound()}")
    reach = float(np.hypot(xy[:, 0], xy[:, 1]).max())
    if reach > limits.max_range_m:
        raise Rejected(path, what, ns, "range", f"a point lies {reach:.4g} m from the sensor")
    fastest = float(np.abs(velocity).max()) if velocity is not None else 0.0
    if fastest > 2 * MAX_SPEED:
        raise Rejected(path, what, ns, "velocity", f"a radial velocity of {fastest:.4g} m/s")


@dataclass(frozen=True)
class CloudLayout:
    """What :func:`sweep_from_pointcloud` found in a cloud beside its sweep: ``time`` how its point times
    were read (None: no time field, every point at the stamp), ``time_datatype`` that field's
    PointField datatype; of a 3-D cloud (``kept`` not None), ``kept`` of its ``points`` within the band;
    ``no_returns`` of its ``points`` dropped as no-returns (module docstring)."""

    time: TimeField | None
    time_datatype: int
    points: int
    kept: int | None
    no_returns: int = 0


def _drop_no_returns(cols: dict[str, np.ndarray], names: tuple[str, ...]) -> int:
    """Remove from every column of ``cols`` the points that are no-returns: a non-finite value in one
    of ``names`` (those read), or ``x`` = ``y`` (= ``z``) = 0. Returns how many were removed."""
    read = [cols[k] for k in names if k in cols]
    keep = np.isfinite(read[0])  # and-ed in place, column by column (no stacked (k, N) temporary)
    for a in read[1:]:
        keep &= np.isfinite(a)
    origin = [cols[k] for k in ("x", "y", "z") if k in cols]
    at_origin = origin[0] == 0
    for a in origin[1:]:
        at_origin &= a == 0
    keep &= ~at_origin
    dropped = int(keep.size - np.count_nonzero(keep))
    if dropped:
        for k in cols:
            cols[k] = cols[k][keep]
    return dropped


def sweep_from_pointcloud(path: Path, msg: Any, limits: InputLimits = InputLimits(),
                          reading: CloudReading = CloudReading()) -> tuple[SweepInput, CloudLayout]:
    """A PointCloud2 to a :class:`SweepInput` (fields by name and offset; each point's time by its
    field's name and type, a 3-D cloud brought down to the sensor's plane: :mod:`fmcwlog.io.clouds`),
    with what was found in the cloud. :class:`Rejected` if its layout or values cannot be used; a
    time-like field whose layout is unknown raises :class:`~fmcwlog.errors.LogError` naming the
    fields (every sweep would be read wrong, so the log is refused rather than each sweep skipped)."""
    ns = header_stamp(path, "PointCloud2", msg.header)
    plan = _cloud_plan(tuple((f.name, int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields),
                       reading.time_field)
    types, time, ring = plan.types, plan.time, plan.ring
    if plan.missing is not None:
        raise Rejected(path, "PointCloud2", ns, "layout", f"no field {plan.missing!r}")
    if plan.time_error is not None:
        raise LogError(f"{path}: {plan.time_error}")
    problem = _cloud_layout_problem(msg, plan)
    if problem is not None:
        raise Rejected(path, "PointCloud2", ns, "layout", problem)
    cols = _cloud_columns(msg, plan)
    n = len(cols["x"])
    no_returns = _drop_no_returns(cols, ("x", "y", "z", "velocity"))
    t = time.seconds(cols[time.name], ns) if time is not None else np.zeros(n - no_returns)
    vel, inten = cols.get("velocity"), cols.get("intensity")
    xy = np.column_stack([cols["x"], cols["y"]])
    kept = None
    if n and no_returns == n:
        raise Rejected(path, "PointCloud2", ns, "empty", f"no points: all {n} are no-returns (NaN, infinite or at the origin)")
    if is_3d(cols.get("z"), cols.get(ring) if ring else None):
        xyz = np.column_stack([xy, cols["z"]])
        band = plane_band(xyz, reading.inputs.plane_band_deg)
        keep = band.keep
        if not keep.any():
            raise Rejected(path, "PointCloud2", ns, "empty", f"no point of the 3-D cloud's {n} within "
                                                             f"±{band.half_angle_deg:g}° of the sensor's plane")
        if vel is not None:
            vel = planar_doppler(xyz[keep], vel[keep])
        xy, t, kept = xy[keep], t[keep], int(keep.sum())
        inten = inten[keep] if inten is not None else None
    try:
        _check_points(path, "PointCloud2", ns, xy, t, vel, limits)
    except Rejected as exc:
        if exc.kind != "times" or time is None:
            raise
        raise Rejected(path, "PointCloud2", None, "times",
                       f"{exc.detail} ({time.describe(types[time.name])}; {TIME_FIELD_HELP})") from None
    layout = CloudLayout(time, types[time.name] if time else 0, n, kept, no_returns)
    return SweepInput(ns, xy, t, vel, inten), layout


def mirrored(sweep: SweepInput) -> SweepInput:
    """``sweep`` as an upright sensor at the same x, y, yaw sees it, from an upside-down one (rolled by π
    about its x axis, ``Calibration.upside_down``): each point (x, y) is (x, -y), a copy; the point
    order, times, radial Doppler (along the ray, which the mirror keeps) and intensities unchanged."""
    return dataclasses.replace(sweep, xy=sweep.xy * np.array([1.0, -1.0], dtype=sweep.xy.dtype))


def sweep_from_laserscan(path: Path, msg: Any, limits: InputLimits = InputLimits()) -> SweepInput:
    """A ``sensor_msgs/LaserScan`` to a :class:`SweepInput` without Doppler.

    Ranges outside ``[range_min, range_max]``, not finite or zero are no return (REP-117). Angles
    must be finite, ``angle_increment`` non-zero, and ``angle_max`` within 1.5 beams of
    ``angle_min + (n - 1)·angle_increment`` (drivers differ by one beam in how they count).

    Any field of view up to a full turn. A 360° scan that counts both ends (721 beams at 0.5°
    from -π to +π) ends on a beam whose direction repeats the first one's, a period later: the
    very measurement that begins the next sweep. That beam (any beam a full turn, less half a
    beam, past the first) is left out, so that a sweep never holds one surface twice, seen at
    its two ends, and a scanner's 721 beams give the same sweep as its 720.
    """
    ns = header_stamp(path, "LaserScan", msg.header)
    r = np.asarray(msg.ranges, dtype=float)
    inc, a0, a1, dt = (float(v) for v in (msg.angle_increment, msg.angle_min, msg.angle_max, msg.time_increment))
    if not all(math.isfinite(v) for v in (inc, a0, a1, dt, float(msg.range_min))) or inc == 0.0:
        raise Rejected(path, "LaserScan", ns, "angles",
                       f"angle_min {a0:g}, angle_max {a1:g}, angle_increment {inc:g}, time_increment {dt:g} "
                       "must be finite and angle_increment non-zero")
    if r.size and (abs(a0 + (r.size - 1) * inc - a1) > 1.5 * abs(inc) + 1e-6 or (r.size - 1) * abs(inc) > 2 * math.pi + abs(inc)):
        raise Rejected(path, "LaserScan", ns, "angles",
                       f"{r.size} ranges from {a0:g} rad in steps of {inc:g} rad do not end at angle_max {a1:g} rad")
    i = np.arange(r.size)
    ang = a0 + i * inc
    once_round = i * abs(inc) < 2 * math.pi - 0.5 * abs(inc)  # else the first beam's direction again
    ok = np.isfinite(r) & (r >= msg.range_min) & (r <= msg.range_max) & (r > 0) & once_round
    inten = np.asarray(msg.intensities, dtype=float)[ok] if len(msg.intensities) == r.size else None
    xy = np.column_stack([r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])])
    t = (i * dt)[ok]
    if r.size and not ok.any():
        raise Rejected(path, "LaserScan", ns, "empty", f"no points: none of its {r.size} ranges is a return (NaN, "
                                                       "infinite, zero or outside [range_min, range_max])")
    _check_points(path, "LaserScan", ns, xy, t, None, limits)
    return SweepInput(ns, xy, t, None, inten)
