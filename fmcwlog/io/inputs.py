"""What estimation reads from a log, as numpy records: sweeps, wheel ticks, odometry poses, each
checked once, as it is decoded.

Only the topics ``fmcwlog process`` is told to use are decoded (docs/log-format.md,
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
saying what was skipped; one that lost more than :data:`MANY_SKIPPED_SHARE` of its
sweeps is said, with the main reason (:meth:`LogInputs.skipped_share`), and one
that lost more than :data:`MOST_SKIPPED_SHARE` is for the caller to refuse. What cannot be skipped away is refused: a motion prior
whose clock is far from the scans' (:data:`MAX_CLOCK_GAP_S`), since every sweep
would get an extrapolated prior.

What a message must satisfy: the bounds of a sweep's points (:mod:`fmcwlog.io.sweeps`) and of
the motion prior's jumps (:mod:`fmcwlog.io.prior_gates`); the topics are chosen by
:mod:`fmcwlog.io.topic_choice`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import LogError
from ..types import MAX_CLOCK_GAP_S, Calibration, InputTopics, OdomInput, SweepInput, TicksInput
from .clouds import CloudReading
from .logs import Log
from .mcap_log import UndecodableMessage
from .messages import odometry_pose_twist
from .prior_gates import PoseGate, TickGate
from .sweeps import (
    MAX_ODOM_POSITION,
    MAX_SPEED,
    InputLimits,
    Rejected,
    header_stamp,
    mirrored,
    sweep_from_laserscan,
    sweep_from_pointcloud,
)

# Shares of a log's sweeps skipped beyond which a run says so where it is seen (the last line,
# run.json, the report's header), and beyond which it is no measurement of the log at all (refused
# unless the caller goes on): a few damaged sweeps are the recording's bad luck; more than one in
# twenty, a writer or a sensor that the checks do not fit, whose results must not pass unremarked.
MANY_SKIPPED_SHARE = 0.05
MOST_SKIPPED_SHARE = 0.5

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


@dataclass(frozen=True)
class SkippedShare:
    """The sweeps a log lost: ``skipped`` of ``read`` on ``topic``; ``kind``, the kind most of them
    were skipped as, and ``reason``, its warning (count, bound and first case)."""

    topic: str
    skipped: int
    read: int
    kind: str
    reason: str

    @property
    def share(self) -> float:
        return self.skipped / self.read

    @property
    def many(self) -> bool:
        return self.share > MANY_SKIPPED_SHARE

    @property
    def most(self) -> bool:
        return self.share > MOST_SKIPPED_SHARE

    def text(self, verdict: str) -> str:
        """``540 of 600 sweeps on /scan skipped (90.0 %, VERDICT); the main reason: ...``"""
        return (f"{self.skipped} of {self.read} sweeps on {self.topic} skipped ({100 * self.share:.1f} %, {verdict}); "
                f"the main reason: {self.reason}")


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

    Iterate once. ``reading``: how a PointCloud2's point times and a 3-D cloud are read
    (:mod:`fmcwlog.io.clouds`). :meth:`notes` gives one warning per kind of skipped message; :attr:`skipped`
    the counts by kind. A sensor mounted upside down (``cal.upside_down``) has every sweep's points
    mirrored back (y -> -y, :func:`.sweeps.mirrored`) here, once, so that every reader of the inputs
    (process, calibrate, fleets) sees the scan of an upright sensor. Raises :class:`LogError` at the
    end if nothing usable was left on the scan topic or the prior topic, and as soon as the two
    clocks are found far apart.
    """

    def __init__(self, reader: Log, topics: InputTopics, cal: Calibration, reading: CloudReading = CloudReading()):
        self.reader = reader
        self._decode = getattr(reader, "decode_input", reader.decode)  # an MCAP log's fast path
        self.reading = reading
        self.path = reader.path
        self.topics = topics
        self.limits = InputLimits.from_calibration(cal)
        self.upside_down = cal.upside_down
        self.scan = _Stream(topics.scan)
        self.prior = _Stream(topics.prior) if topics.prior else None
        if topics.ticks is not None and cal.wheels is None:
            raise LogError(f"{self.path}: wheel ticks on {topics.ticks} need the wheels' calibration")
        self._ticks = TickGate(cal.wheels) if topics.ticks is not None and cal.wheels is not None else None
        self._poses = PoseGate()
        self.untimed_sweeps = 0  # PointCloud2 sweeps without a time field: taken at their stamp
        self.time_fields: dict[str, int] = {}  # how point times were read, other than the log format's t: sweeps
        self.clouds_3d = [0, 0, 0]  # 3-D sweeps, their points, those kept within the band
        self.cloud_points = [0, 0]  # points of the PointCloud2 sweeps read, those dropped as no-returns

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

    def skipped_share(self) -> SkippedShare | None:
        """The share of the scan topic's sweeps skipped, and why most were (None: none was)."""
        if not self.scan.skipped:
            return None
        kind = max(self.scan.skipped, key=lambda k: self.scan.skipped[k])  # ties: the first seen
        read = self.scan.accepted + self.skipped_sweeps
        return SkippedShare(self.scan.topic, self.skipped_sweeps, read, kind, self._skip_text(self.scan, kind))

    @property
    def repeated_prior_stamps(self) -> int:
        return self.prior.skipped.get("prior_repeated", 0) if self.prior is not None else 0

    def __iter__(self) -> Iterator[SweepInput | TicksInput | OdomInput]:
        wanted = [t for t in (self.topics.scan, self.topics.ticks, self.topics.odom) if t]
        for schema, channel, rec in self.reader.raw_messages_by_time(wanted):
            stream = self.scan if channel.topic == self.topics.scan else self.prior
            assert stream is not None
            try:
                m = self._decode(schema, channel, rec)
                ns, fields = self._read_sweep(m) if stream is self.scan else self._read_prior(m)
                if rec.log_time != ns and not self.reader.receive_times:  # the log format has them equal; a
                    # bag's are receive times. Estimation goes by header.stamp
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
                elif (item := self._accept(stream, *held)) is not None:
                    yield item
            if stream.last_ns is not None and (ns - stream.last_ns) * 1e-9 > MAX_CLOCK_GAP_S:
                stream.held = (ns, fields)  # a lone damaged stamp, or a gap in the recording: the next says
                continue
            if (item := self._accept(stream, ns, fields)) is not None:
                yield item
        for stream in (self.scan, self.prior):
            if stream is not None and stream.held is not None:  # the log ends after the jump: a gap
                held, stream.held = stream.held, None
                if (item := self._accept(stream, *held)) is not None:
                    yield item
        self._check_usable()

    def _accept(self, stream: _Stream, ns: int, fields: Any) -> SweepInput | TicksInput | OdomInput | None:
        """The input a message accepted in order makes (None: its gate skipped it)."""
        item = fields if stream is self.scan else self._prior_item(ns, fields)
        if item is None:
            return None
        stream.last_ns = ns
        if stream.first_ns is None:
            stream.first_ns = ns
        stream.accepted += 1
        self._check_clocks()
        return item

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
            sweep, layout = sweep_from_pointcloud(self.path, m.msg, self.limits, self.reading)
            if layout.time is None:
                self.untimed_sweeps += 1
            elif (layout.time.name, layout.time.unit) != ("t", "s"):  # other than the log format's t
                what = layout.time.describe(layout.time_datatype)
                self.time_fields[what] = self.time_fields.get(what, 0) + 1
            self.cloud_points = [self.cloud_points[0] + layout.points, self.cloud_points[1] + layout.no_returns]
            if layout.kept is not None:
                self.clouds_3d = [a + b for a, b in zip(self.clouds_3d, (1, layout.points, layout.kept))]
        else:
            sweep = sweep_from_laserscan(self.path, m.msg, self.limits)
        if self.upside_down:
            sweep = mirrored(sweep)
        return sweep.stamp_ns, sweep

    def _read_prior(self, m: Any) -> tuple[int, tuple[int, int] | np.ndarray]:
        """The stamp and the counts (ticks) or pose (odometry) of a motion-prior message."""
        if self._ticks is not None and not (hasattr(m.msg, "header") and hasattr(m.msg, "left") and hasattr(m.msg, "right")):
            raise LogError(f"{self.path}: {m.topic} is {m.datatype} without the fields header, left and right of "
                           "fmcwlog_msgs/msg/WheelTicks (docs/log-format.md)")
        ns = header_stamp(self.path, "motion prior", m.msg.header)
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

    def _skip_text(self, stream: _Stream, kind: str) -> str:
        """The warning for one kind of skipped message: count, topic, bound and (but for a repeated
        stamp, which is its own case) the first case."""
        values = {"max_sweep_s": self.limits.max_sweep_s, "max_range_m": self.limits.max_range_m,
                  "max_speed": MAX_SPEED, "max_velocity": 2 * MAX_SPEED, "max_gap": MAX_CLOCK_GAP_S}
        text = _SKIP_TEXT[kind].format(n=stream.skipped[kind], topic=stream.topic, **values)
        return text if kind.endswith("_repeated") else f"{text} (first: {stream.first_detail[kind]})"

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

    def _no_returns_note(self) -> str | None:
        """The warning where more than :data:`MANY_SKIPPED_SHARE` of the cloud points read were no-returns
        (NaN, infinite or at the origin: dropped as decoded), louder where more than :data:`MOST_SKIPPED_SHARE`
        were; None where fewer."""
        points, dropped = self.cloud_points
        if not points or dropped <= MANY_SKIPPED_SHARE * points:
            return None
        text = (f"dropped {dropped} of {points} points ({100 * dropped / points:.1f} %) on {self.topics.scan} as "
                "no-returns (x, y or velocity NaN or infinite, or the point at the sensor's origin)")
        if dropped > MOST_SKIPPED_SHARE * points:
            return (f"MOST POINTS ARE NO-RETURNS: {text}; the results stand on the {points - dropped} left: "
                    "check the sensor (blocked or facing open space) and its driver")
        return text

    def notes(self) -> list[str]:
        """One warning per kind of skipped message, with its count and the first case."""
        out = []
        for stream in (self.scan, self.prior):
            if stream is None:
                continue
            for kind in stream.skipped:
                text = self._skip_text(stream, kind)
                out.append(text if kind.endswith("_repeated") else f"skipped {text}")
        for stream in (self.scan, self.prior):
            if stream is not None and stream.off_log_time:
                out.append(f"{stream.off_log_time} messages on {stream.topic} have a log_time other than their "
                           f"header.stamp (first: {stream.first_off_log_time}), which the log format has equal: "
                           "processed by header.stamp")
        if self.untimed_sweeps:  # the log format requires t; without it nothing can be deskewed
            out.append(f"{self.untimed_sweeps} sweeps on {self.topics.scan} have no field 't' (each point's time "
                       "after the stamp): their points were taken as measured at the sweep's stamp, not deskewed")
        for what, n in self.time_fields.items():
            out.append(f"point times of {n} sweeps on {self.topics.scan}: {what}")
        no_returns = self._no_returns_note()
        if no_returns:
            out.append(no_returns)
        sweeps, points, kept = self.clouds_3d
        if sweeps:
            band = self.reading.inputs.plane_band_deg
            out.append(f"3-D cloud: kept {kept} of {points} points ({100 * kept / points:.1f} %) of {sweeps} sweeps on "
                       f"{self.topics.scan} within ±{band:g}° of the sensor plane (inputs.plane_band_deg), projected "
                       "onto it, their Doppler corrected for elevation")
        gates = [(self._ticks, "wheel-tick counter"), (self._poses, "odometry")]
        for gate, what in gates:
            if gate is not None and gate.rebases:
                out.append(f"{gate.rebases} {what} jumps on {self.topics.prior} confirmed by the next message "
                           "(a reset) were taken as a new origin; the motion across each is lost")
        if self._ticks is not None and self._ticks.wraps:
            out.append(f"unwrapped {self._ticks.wraps} 32-bit wheel-tick counter wraps on {self.topics.ticks}")
        return out


