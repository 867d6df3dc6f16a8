"""What estimation reads from a log, as numpy records: sweeps, wheel ticks, odometry poses, each
checked once, as it is decoded.

Only the topics ``fmcwlog process`` is told to use are decoded (LOG_FORMAT.md,
"What processing may read"): ``/fmcw/points`` or another scan topic, and
``/wheel/ticks`` or an Odometry topic as the motion prior. Estimation never
touches ``/ground_truth/*`` or ``fmcwlog.world``.

The skipping policy lives here (:class:`LogInputs`). A message whose fields are
inconsistent with its schema or physically impossible is damage local to that
message: it is skipped and counted, one warning per kind with its count. So is a
message out of order on its topic (a stamp repeated or going backwards), and one
whose stamp jumps more than :data:`MAX_CLOCK_GAP_S` ahead when the next message
comes back before it (held back until then: otherwise one damaged stamp would
make every later message go backwards); a jump the next message confirms is a
gap in the recording. A log with nothing usable left is one :class:`LogError`
saying what was skipped. What cannot be skipped away is refused: a motion prior
whose clock is far from the scans' (:data:`MAX_CLOCK_GAP_S`), since every sweep
would get an extrapolated prior.

The bounds (:class:`InputLimits`) and why:

- point times ``t`` in ``[0, 1/scan_rate]``: ``header.stamp`` is the first beam's
  time (LOG_FORMAT.md) and a sweep ends before the next begins; 1 s where the
  calibration gives no rate (no scanning LiDAR sweeps slower than 1 Hz);
- points within twice the calibration's ``max_range`` of the sensor (bright targets
  return beyond the rated range; the logs here reach 30.0000004 m of 30 m), else 1 km
  (beyond every planar LiDAR; the longest-range ones reach ~300 m): a damaged
  coordinate would otherwise grow the occupancy grid to terabytes;
- a motion-prior message moves the robot at most :data:`MAX_SPEED` (100 m/s, beyond
  any wheeled robot carrying a 2-D LiDAR) since the last one, plus 2 ticks or 1 cm of
  quantisation; a 32-bit counter wrap (a jump of exactly ±2^32 ticks) is unwrapped;
- radial (Doppler) velocities within ±2·MAX_SPEED: a target and the sensor each
  move at most MAX_SPEED;
- odometry positions within 1e8 m (beyond any map frame on Earth; UTM northings
  reach 1e7 m).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LogError
from ..geometry import compose, inverse
from ..types import MAX_CLOCK_GAP_S, Calibration, InputTopics, OdomInput, SweepInput, TicksInput, WheelCalibration
from .mcap_log import LogReader, UndecodableMessage
from .messages import POINTFIELD_DTYPES, odometry_pose_twist, pointcloud_columns, stamp_ns
from .topics import GROUND_TRUTH_PREFIX, POINTS_TOPIC, TICKS_TOPIC

MAX_SPEED = 100.0  # m/s
MAX_ODOM_POSITION = 1e8  # m
_WRAP = 1 << 32


@dataclass(frozen=True)
class InputLimits:
    """Bounds beyond which a decoded value is damage, not a measurement (module docstring).

    max_sweep_s: latest point time in a sweep, s. max_range_m: farthest point from the sensor, m.
    """

    max_sweep_s: float = 1.0
    max_range_m: float = 1000.0

    @classmethod
    def from_calibration(cls, cal: Calibration) -> InputLimits:
        return cls(1.0 / cal.scan_rate if cal.scan_rate else 1.0,
                   2.0 * cal.max_range if cal.max_range else 1000.0)


class Rejected(LogError):
    """A message that cannot be used: ``kind`` names the check it failed, ``detail`` how."""

    def __init__(self, path: Path, what: str, ns: int | None, kind: str, detail: str):
        at = f"at {ns * 1e-9:.3f} s: " if ns is not None else ""
        super().__init__(f"{path}: {what} {at}{detail}")
        self.kind = kind
        self.detail = at + detail


def _stamp(path: Path, what: str, header: Any) -> int:
    sec, nsec = int(header.stamp.sec), int(header.stamp.nanosec)
    if sec < 0 or not 0 <= nsec < 1_000_000_000:
        raise Rejected(path, what, None, "stamp", f"invalid stamp {sec} s {nsec} ns")
    return stamp_ns(header.stamp)


def _cloud_layout_problem(msg: Any, wanted: list[str]) -> str | None:
    """Why a PointCloud2's layout cannot be read (None: it can): fields against point_step and data."""
    if msg.is_bigendian:
        return "big-endian PointCloud2 is not supported"
    step, n = int(msg.point_step), int(msg.width) * int(msg.height)
    spans = []
    for f in msg.fields:
        dtype = POINTFIELD_DTYPES.get(f.datatype)
        if dtype is None:
            if f.name in wanted:
                return f"field {f.name!r} has unknown datatype {f.datatype}"
            continue
        if f.name in wanted and f.count < 1:
            return f"field {f.name!r} has count {f.count}"
        spans.append((int(f.offset), int(f.offset) + np.dtype(dtype).itemsize * max(int(f.count), 1), f.name))
    spans.sort()
    end = max((e for _, e, _ in spans), default=0)
    if step < end or step == 0:
        return f"point_step {step} is smaller than its fields ({end} bytes)"
    for (_, e0, a), (s1, _, b) in zip(spans, spans[1:]):
        if s1 < e0:
            return f"fields {a!r} and {b!r} overlap"
    if int(msg.height) > 1 and int(msg.row_step) != int(msg.width) * step:
        return f"rows padded (row_step {msg.row_step}, width × point_step {int(msg.width) * step}) are not supported"
    if len(msg.data) < n * step:
        return f"data holds {len(msg.data)} bytes, width × height × point_step is {n * step}"
    return None


def _check_points(path: Path, what: str, ns: int, xy: np.ndarray, t: np.ndarray, velocity: np.ndarray | None,
                  limits: InputLimits) -> None:
    """Finite values, point times within the sweep, points within the sensor's reach."""
    if len(t) == 0:
        raise Rejected(path, what, ns, "empty", "no points")
    for name, a in (("x or y", xy), ("t", t), ("velocity", velocity)):
        if a is not None and not np.all(np.isfinite(a)):
            raise Rejected(path, what, ns, "nonfinite", f"{name} holds NaN or infinite values")
    if t.min() < 0.0 or t.max() > limits.max_sweep_s:
        raise Rejected(path, what, ns, "times", f"point times span [{t.min():g}, {t.max():g}] s")
    reach = float(np.max(np.hypot(xy[:, 0], xy[:, 1])))
    if reach > limits.max_range_m:
        raise Rejected(path, what, ns, "range", f"a point lies {reach:.4g} m from the sensor")
    if velocity is not None and float(np.max(np.abs(velocity))) > 2 * MAX_SPEED:
        raise Rejected(path, what, ns, "velocity", f"a radial velocity of {float(np.max(np.abs(velocity))):.4g} m/s")


def sweep_from_pointcloud(path: Path, msg: Any, limits: InputLimits = InputLimits()) -> SweepInput:
    """A PointCloud2 of the log format to a :class:`SweepInput` (fields by name and offset);
    :class:`Rejected` if its layout or values cannot be used."""
    ns = _stamp(path, "PointCloud2", msg.header)
    names = {f.name for f in msg.fields}
    missing = {"x", "y"} - names
    if missing:
        raise Rejected(path, "PointCloud2", ns, "layout", f"no field {sorted(missing)[0]!r}")
    wanted = [n for n in ("x", "y", "t", "velocity", "intensity") if n in names]
    problem = _cloud_layout_problem(msg, wanted)
    if problem is not None:
        raise Rejected(path, "PointCloud2", ns, "layout", problem)
    try:
        cols = pointcloud_columns(msg, wanted)
    except (ValueError, KeyError) as exc:
        raise Rejected(path, "PointCloud2", ns, "layout", str(exc)) from None
    n = len(cols["x"])
    t = cols.get("t", np.zeros(n))
    vel, inten = cols.get("velocity"), cols.get("intensity")
    xy = np.column_stack([cols["x"], cols["y"]])
    _check_points(path, "PointCloud2", ns, xy, t, vel, limits)
    return SweepInput(ns, xy, t, vel, inten)


def sweep_from_laserscan(path: Path, msg: Any, limits: InputLimits = InputLimits()) -> SweepInput:
    """A ``sensor_msgs/LaserScan`` to a :class:`SweepInput` without Doppler.

    Ranges outside ``[range_min, range_max]`` or not finite are no return (REP-117). Angles
    must be finite, ``angle_increment`` non-zero, and ``angle_max`` within 1.5 beams of
    ``angle_min + (n - 1)·angle_increment`` (drivers differ by one beam in how they count).
    """
    ns = _stamp(path, "LaserScan", msg.header)
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
    ok = np.isfinite(r) & (r >= msg.range_min) & (r <= msg.range_max)
    inten = np.asarray(msg.intensities, dtype=float)[ok] if len(msg.intensities) == r.size else None
    xy = np.column_stack([r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])])
    t = (i * dt)[ok]
    _check_points(path, "LaserScan", ns, xy, t, None, limits)
    return SweepInput(ns, xy, t, None, inten)


@dataclass
class _Gate:
    """A motion-prior stream's physically impossible jumps (module docstring).

    A message that moves farther than ``MAX_SPEED`` allows since the last accepted one is
    skipped; if the next message moves plausibly from the skipped one, the jump was real (a
    counter reset, odometry re-zeroed): the skipped message becomes a new origin placed on the
    last accepted one, and the motion across the jump is lost (counted as a rebase).
    """

    last: tuple[float, Any] | None = None  # (s, value) of the last accepted message, after offsets
    pending: tuple[float, Any] | None = None  # the skipped message, raw
    rebases: int = 0


class _TickGate(_Gate):
    def __init__(self, wheels: WheelCalibration):
        super().__init__()
        # ticks per metre of each wheel
        self.per_m = tuple(wheels.ticks_per_revolution / (2 * math.pi * r)
                           for r in (wheels.wheel_radius_left, wheels.wheel_radius_right))
        # added to the counts read (python ints, as the int64 counts are); set at the first message to
        # start the counts at 0: the prior integrates differences of counts held as int64 and float64,
        # exact only below 2**53, and a counter that started near 2**63 overflowed int64 after a reset
        self.offset: tuple[int, int] | None = None
        self.wraps = 0

    def _plausible(self, t0: float, c0: tuple[int, int], t1: float, c1: tuple[int, int]) -> bool:
        return all(abs(b - a) <= k * MAX_SPEED * (t1 - t0) + 2 for a, b, k in zip(c0, c1, self.per_m))

    def feed(self, t: float, left: int, right: int) -> tuple[int, int] | None:
        """The counts to integrate (unwrapped, rebased), or None to skip this message."""
        if self.offset is None:
            self.offset = (-left, -right)
        counts = (left + self.offset[0], right + self.offset[1])
        if self.last is None:
            return self._accept(t, counts)
        t0, c0 = self.last
        if self._plausible(t0, c0, t, counts):
            return self._accept(t, counts)
        # the nearest counts modulo 2^32: the same if the jump was exactly one 32-bit wrap
        near = tuple(a + (b - a + _WRAP // 2) % _WRAP - _WRAP // 2 for a, b in zip(c0, counts))
        if all(abs(n - c) in (0, _WRAP) for n, c in zip(near, counts)) and self._plausible(t0, c0, t, near):
            self.wraps += sum(n != c for n, c in zip(near, counts))
            self.offset = (self.offset[0] + near[0] - counts[0], self.offset[1] + near[1] - counts[1])
            return self._accept(t, (near[0], near[1]))
        raw = (left, right)
        if self.pending is not None and self._plausible(self.pending[0], self.pending[1], t, raw):
            self.offset = (c0[0] - self.pending[1][0], c0[1] - self.pending[1][1])
            self.rebases += 1
            return self._accept(t, (left + self.offset[0], right + self.offset[1]))
        self.pending = (t, raw)
        return None

    def _accept(self, t: float, counts: tuple[int, int]) -> tuple[int, int]:
        self.last = (t, counts)
        self.pending = None
        return counts


class _PoseGate(_Gate):
    def __init__(self) -> None:
        super().__init__()
        self.offset: np.ndarray | None = None  # applied once a jump has been rebased

    def feed(self, t: float, raw: np.ndarray) -> np.ndarray | None:
        pose = compose(self.offset, raw) if self.offset is not None else raw
        if self.last is None or self._plausible(self.last, t, pose):
            self.last, self.pending = (t, pose), None
            return pose
        if self.pending is not None and self._plausible((self.pending[0], self.pending[1]), t, raw):
            self.offset = compose(self.last[1], inverse(self.pending[1]))
            self.rebases += 1
            pose = compose(self.offset, raw)
            self.last, self.pending = (t, pose), None
            return pose
        self.pending = (t, raw)
        return None

    @staticmethod
    def _plausible(last: tuple[float, np.ndarray], t: float, pose: np.ndarray) -> bool:
        return bool(math.hypot(*(pose[:2] - last[1][:2])) <= MAX_SPEED * (t - last[0]) + 0.01)


# What each kind of skipped message is, for the warnings (count, topic and bound filled in).
_SKIP_TEXT = {
    "undecodable": "{n} messages on {topic} that do not decode",
    "stamp": "{n} messages on {topic} with an invalid header stamp",
    "layout": "{n} sweeps on {topic} whose point layout cannot be read",
    "angles": "{n} sweeps on {topic} whose beam angles are unusable",
    "nonfinite": "{n} sweeps on {topic} holding NaN or infinite values",
    "times": "{n} sweeps on {topic} whose point times lie outside [0, {max_sweep_s:g} s]",
    "range": "{n} sweeps on {topic} with points farther than {max_range_m:g} m from the sensor",
    "velocity": "{n} sweeps on {topic} with radial velocities beyond ±{max_velocity:g} m/s",
    "empty": "{n} sweeps on {topic} with no points",
    "sweep_backwards": "{n} sweeps on {topic} whose stamps go backwards",
    "sweep_repeated": "{n} sweeps with a repeated stamp were skipped",
    "prior_backwards": "{n} motion-prior messages on {topic} whose stamps go backwards",
    "prior_repeated": "{n} motion-prior messages with a repeated stamp were skipped",
    "stamp_jump": "{n} messages on {topic} whose stamps jump more than {max_gap:g} s ahead of their neighbours",
    "ticks_jump": "{n} wheel-tick messages on {topic} whose counts jump farther than a wheel rolls at "
                  "{max_speed:g} m/s",
    "odom_invalid": "{n} odometry messages on {topic} with a NaN, infinite or absurd pose",
    "odom_jump": "{n} odometry messages on {topic} whose pose jumps farther than {max_speed:g} m/s allows",
}


@dataclass
class _Stream:
    """Accepted stamps of one topic, and what was skipped on it."""

    topic: str
    first_ns: int | None = None
    last_ns: int | None = None
    accepted: int = 0
    held: tuple[int, Any] | None = None  # a message whose stamp jumped forward, until the next one says
    skipped: dict[str, int] = field(default_factory=dict)
    first_detail: dict[str, str] = field(default_factory=dict)
    off_log_time: int = 0  # messages whose log_time is not their header.stamp
    first_off_log_time: str = ""


class LogInputs:
    """The estimator's inputs from ``reader`` in time order (``log_time``, however the writer interleaved
    the topics: :meth:`LogReader.raw_messages_by_time`): sweeps, and ticks or odometry as the
    motion prior; each message checked once, as it is decoded (module docstring).

    Iterate once. :meth:`notes` gives one warning per kind of skipped message; :attr:`skipped`
    the counts by kind. Raises :class:`LogError` at the end if nothing usable was left on the
    scan topic or the prior topic, and as soon as the two clocks are found far apart.
    """

    def __init__(self, reader: LogReader, topics: InputTopics, cal: Calibration):
        self.reader = reader
        self.path = reader.path
        self.topics = topics
        self.limits = InputLimits.from_calibration(cal)
        self.scan = _Stream(topics.scan)
        self.prior = _Stream(topics.prior) if topics.prior else None
        if topics.ticks is not None and cal.wheels is None:
            raise LogError(f"{self.path}: wheel ticks on {topics.ticks} need the wheels' calibration")
        self._ticks = _TickGate(cal.wheels) if topics.ticks is not None and cal.wheels is not None else None
        self._poses = _PoseGate()
        self.untimed_sweeps = 0  # PointCloud2 sweeps without the field t: taken at their stamp

    @property
    def skipped(self) -> dict[str, int]:
        """Skipped messages by kind (prefixed ``prior_`` where the kind is on the prior topic)."""
        out = dict(self.scan.skipped)
        if self.prior is not None:
            out.update({k if k.startswith(("prior_", "ticks_", "odom_")) else f"prior_{k}": n
                        for k, n in self.prior.skipped.items()})
        return out

    @property
    def skipped_sweeps(self) -> int:
        return sum(self.scan.skipped.values())

    @property
    def repeated_prior_stamps(self) -> int:
        return self.prior.skipped.get("prior_repeated", 0) if self.prior is not None else 0

    def __iter__(self) -> Iterator[SweepInput | TicksInput | OdomInput]:
        wanted = [t for t in (self.topics.scan, self.topics.ticks, self.topics.odom) if t]
        for schema, channel, rec in self.reader.raw_messages_by_time(wanted):
            stream = self.scan if channel.topic == self.topics.scan else self.prior
            assert stream is not None
            try:
                m = self.reader.decode(schema, channel, rec)
                ns, fields = self._read_sweep(m) if stream is self.scan else self._read_prior(m)
                if rec.log_time != ns:  # LOG_FORMAT.md: equal; estimation goes by header.stamp
                    stream.off_log_time += 1
                    stream.first_off_log_time = stream.first_off_log_time or \
                        f"log_time {rec.log_time * 1e-9:.3f} s, header.stamp {ns * 1e-9:.3f} s"
            except UndecodableMessage as exc:
                self._skip(stream, "undecodable", str(exc))
                continue
            except Rejected as exc:
                self._skip(stream, exc.kind, exc.detail)
                continue
            if not self._order(stream, ns):
                continue
            if stream.held is not None:  # a jump held back: this message decides
                held, stream.held = stream.held, None
                if ns < held[0]:
                    self._skip(stream, "stamp_jump", f"{held[0] * 1e-9:.3f} s between {(stream.last_ns or 0) * 1e-9:.3f} "
                                                     f"s and {ns * 1e-9:.3f} s")
                else:
                    yield from self._accept(stream, *held)
            if stream.last_ns is not None and (ns - stream.last_ns) * 1e-9 > MAX_CLOCK_GAP_S:
                stream.held = (ns, fields)  # a lone damaged stamp, or a gap in the recording: the next says
                continue
            yield from self._accept(stream, ns, fields)
        for stream in (self.scan, self.prior):
            if stream is not None and stream.held is not None:  # the log ends after the jump: a gap
                held, stream.held = stream.held, None
                yield from self._accept(stream, *held)
        self._check_usable()

    def _accept(self, stream: _Stream, ns: int, fields: Any) -> Iterator[SweepInput | TicksInput | OdomInput]:
        item = fields if stream is self.scan else self._prior_item(ns, fields)
        if item is None:
            return
        stream.last_ns = ns
        if stream.first_ns is None:
            stream.first_ns = ns
        stream.accepted += 1
        self._check_clocks()
        yield item

    def _skip(self, stream: _Stream, kind: str, detail: str) -> None:
        stream.skipped[kind] = stream.skipped.get(kind, 0) + 1
        stream.first_detail.setdefault(kind, detail)

    def _order(self, stream: _Stream, ns: int) -> bool:
        """Whether ``ns`` comes after the stream's last accepted stamp (else skipped and counted)."""
        kind = "sweep" if stream is self.scan else "prior"
        if stream.last_ns is not None and ns <= stream.last_ns:
            self._skip(stream, f"{kind}_repeated" if ns == stream.last_ns else f"{kind}_backwards",
                       f"{ns * 1e-9:.3f} s after {stream.last_ns * 1e-9:.3f} s")
            return False
        return True

    def _read_sweep(self, m: Any) -> tuple[int, SweepInput]:
        if m.datatype.endswith("PointCloud2"):
            sweep = sweep_from_pointcloud(self.path, m.msg, self.limits)
            if not any(f.name == "t" for f in m.msg.fields):
                self.untimed_sweeps += 1
        else:
            sweep = sweep_from_laserscan(self.path, m.msg, self.limits)
        return sweep.stamp_ns, sweep

    def _read_prior(self, m: Any) -> tuple[int, tuple[int, int] | np.ndarray]:
        """The stamp and the counts (ticks) or pose (odometry) of a motion-prior message."""
        if self._ticks is not None and not all(hasattr(m.msg, f) for f in ("header", "left", "right")):
            raise LogError(f"{self.path}: {m.topic} is {m.datatype} without the fields header, left and right of "
                           "fmcwlog_msgs/msg/WheelTicks (LOG_FORMAT.md)")
        ns = _stamp(self.path, "motion prior", m.msg.header)
        if self._ticks is not None:
            return ns, (int(m.msg.left), int(m.msg.right))
        pose, _ = odometry_pose_twist(m.msg)
        q = m.msg.pose.pose.orientation
        qnorm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
        if not (np.all(np.isfinite(pose)) and np.all(np.abs(pose[:2]) <= MAX_ODOM_POSITION) and qnorm > 1e-6):
            raise Rejected(self.path, "Odometry", ns, "odom_invalid", f"pose {pose.tolist()}")
        return ns, pose

    def _prior_item(self, ns: int, fields: Any) -> TicksInput | OdomInput | None:
        """The prior message through its jump gate (None: skipped and counted)."""
        assert self.prior is not None
        if self._ticks is not None:
            counts = self._ticks.feed(ns * 1e-9, *fields)
            if counts is None:
                self._skip(self.prior, "ticks_jump", f"at {ns * 1e-9:.3f} s: counts {fields[0]}, {fields[1]}")
                return None
            return TicksInput(ns, *counts)
        gated = self._poses.feed(ns * 1e-9, fields)
        if gated is None:
            self._skip(self.prior, "odom_jump", f"at {ns * 1e-9:.3f} s: pose {fields.tolist()}")
            return None
        return OdomInput(ns, gated)

    def _check_clocks(self) -> None:
        """Refuse a motion prior whose clock is far from the scans': it would never cover a sweep."""
        p, s = self.prior, self.scan
        if p is None or s.first_ns is None:
            return
        assert s.last_ns is not None
        if p.first_ns is None:
            if (s.last_ns - s.first_ns) * 1e-9 > MAX_CLOCK_GAP_S:
                raise LogError(f"{self.path}: no usable message on {p.topic}, the motion prior, in the first "
                               f"{MAX_CLOCK_GAP_S:g} s of {s.topic}{self._skipped_text(p)}{self.reader.damage_note()}")
            return
        assert p.last_ns is not None
        # the first sweep against the span of prior stamps seen so far
        gap = max(p.first_ns - s.first_ns, s.first_ns - p.last_ns, 0) * 1e-9
        if gap > MAX_CLOCK_GAP_S:
            raise LogError(f"{self.path}: the clocks of {s.topic} and {p.topic} are {gap:.1f} s apart "
                           f"(first sweep at {s.first_ns * 1e-9:.3f} s, motion prior from {p.first_ns * 1e-9:.3f} s "
                           f"to {p.last_ns * 1e-9:.3f} s): the motion prior would never cover a sweep")

    def _skipped_text(self, stream: _Stream) -> str:
        if not stream.skipped:
            return ""
        parts = [f"{n} {k.replace('_', ' ')} ({stream.first_detail[k]})" for k, n in sorted(stream.skipped.items())]
        return "; skipped " + ", ".join(parts)

    def _check_usable(self) -> None:
        if self.scan.accepted == 0:
            raise LogError(f"{self.path}: no usable sweep on {self.scan.topic}"
                           f"{self._skipped_text(self.scan)}{self.reader.damage_note()}")
        if self.prior is not None and self.prior.accepted == 0:
            raise LogError(f"{self.path}: no usable message on {self.prior.topic}, the motion prior"
                           f"{self._skipped_text(self.prior)}{self.reader.damage_note()}")

    def notes(self) -> list[str]:
        """One warning per kind of skipped message, with its count and the first case."""
        values = {"max_sweep_s": self.limits.max_sweep_s, "max_range_m": self.limits.max_range_m,
                  "max_speed": MAX_SPEED, "max_velocity": 2 * MAX_SPEED, "max_gap": MAX_CLOCK_GAP_S}
        out = []
        for stream in (self.scan, self.prior):
            if stream is None:
                continue
            for kind, n in stream.skipped.items():
                text = _SKIP_TEXT[kind].format(n=n, topic=stream.topic, **values)
                if kind.endswith("_repeated"):
                    out.append(text)
                else:
                    out.append(f"skipped {text} (first: {stream.first_detail[kind]})")
        for stream in (self.scan, self.prior):
            if stream is not None and stream.off_log_time:
                out.append(f"{stream.off_log_time} messages on {stream.topic} have a log_time other than their "
                           f"header.stamp (first: {stream.first_off_log_time}), which LOG_FORMAT.md has equal: "
                           "processed by header.stamp")
        if self.untimed_sweeps:  # LOG_FORMAT.md requires t; without it nothing can be deskewed
            out.append(f"{self.untimed_sweeps} sweeps on {self.topics.scan} have no field 't' (each point's time "
                       "after the stamp): their points were taken as measured at the sweep's stamp, not deskewed")
        gates = [(self._ticks, "wheel-tick counter"), (self._poses, "odometry")]
        for gate, what in gates:
            if gate is not None and gate.rebases:
                out.append(f"{gate.rebases} {what} jumps on {self.topics.prior} confirmed by the next message "
                           "(a reset) were taken as a new origin; the motion across each is lost")
        if self._ticks is not None and self._ticks.wraps:
            out.append(f"unwrapped {self._ticks.wraps} 32-bit wheel-tick counter wraps on {self.topics.ticks}")
        return out


def choose_topics(reader: LogReader, scan: str | None = None, ticks: str | None = None,
                  odom: str | None = None) -> InputTopics:
    """The topics to read: those named, else ``/fmcw/points`` (or ``/scan``, or the log's only
    scan topic) with ``/wheel/ticks`` (or ``/odom``) as the motion prior."""
    topics = reader.topics
    path = reader.path
    if scan is None:
        if POINTS_TOPIC in topics:
            scan = POINTS_TOPIC
        elif "/scan" in topics:
            scan = "/scan"
        else:
            scans = [t for t, s in topics.items()
                     if s.endswith(("PointCloud2", "LaserScan")) and not t.startswith(GROUND_TRUTH_PREFIX)]
            if len(scans) != 1:
                found = ", ".join(sorted(scans)) or "none"
                raise LogError(f"{path}: no usable scan topic (PointCloud2 or LaserScan; found: {found}); "
                               f"name one with --scan-topic{reader.damage_note()}")
            scan = scans[0]
    _check_named_topic(reader, scan, ("PointCloud2", "LaserScan"), "PointCloud2 or LaserScan")
    if odom is not None:
        _check_named_topic(reader, odom, ("Odometry",), "nav_msgs/msg/Odometry")
        return InputTopics(scan, None, odom)
    if ticks is None and TICKS_TOPIC in topics:
        ticks = TICKS_TOPIC
    if ticks is None and topics.get("/odom", "").endswith("Odometry"):  # an imported or ROS log
        return InputTopics(scan, None, "/odom")
    if ticks is not None:
        _check_named_topic(reader, ticks, ("WheelTicks",), "fmcwlog_msgs/msg/WheelTicks")
    return InputTopics(scan, ticks, None)


def _check_named_topic(reader: LogReader, topic: str, type_names: tuple[str, ...], expected: str) -> None:
    """An input topic (scan or motion prior) must exist, be of one of ``type_names`` (any package's:
    the fields are checked as the messages are read) and not be ground truth, which estimation never
    reads (``--odom-topic /ground_truth/odom`` once scored the ground truth against itself)."""
    topics, path = reader.topics, reader.path
    if topic not in topics:
        raise LogError(f"{path}: no topic {topic}{reader.damage_note()}")
    if topic.startswith(GROUND_TRUTH_PREFIX):
        raise LogError(f"{path}: {topic} is ground truth, which estimation never reads; name the robot's own topic")
    if topics[topic].rsplit("/", 1)[-1] not in type_names:
        raise LogError(f"{path}: {topic} is {topics[topic] or 'of no known type'}, not a {expected}")
