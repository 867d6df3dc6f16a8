"""What estimation reads from a log, as numpy records: sweeps, wheel ticks, odometry poses.

Only the topics ``fmcwlog process`` is told to use are decoded (LOG_FORMAT.md,
"What processing may read"): ``/fmcw/points`` or another scan topic, and
``/wheel/ticks`` or an Odometry topic as the motion prior. Estimation never
touches ``/ground_truth/*`` or ``fmcwlog.world``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LogError
from .mcap_log import LogReader
from .messages import odometry_pose_twist, pointcloud_columns, stamp_ns
from .topics import GROUND_TRUTH_PREFIX, POINTS_TOPIC, TICKS_TOPIC


@dataclass
class SweepInput:
    """One sweep in the sensor frame: points where the sensor saw them at their own time."""

    stamp_ns: int  # first beam
    xy: np.ndarray  # (N, 2) m, frame lidar
    t: np.ndarray  # (N,) s after stamp_ns
    velocity: np.ndarray | None  # (N,) m/s radial Doppler, None without Doppler
    intensity: np.ndarray | None


@dataclass
class TicksInput:
    stamp_ns: int
    left: int
    right: int


@dataclass
class OdomInput:
    stamp_ns: int
    pose: np.ndarray  # (3,) x, y, yaw in the odometry frame


def _finite(path: Path, what: str, stamp_ns_: int, *arrays: np.ndarray | None) -> None:
    for a in arrays:
        if a is not None and not np.all(np.isfinite(a)):
            raise LogError(f"{path}: {what} at stamp {stamp_ns_} holds NaN or infinite values")


def sweep_from_pointcloud(path: Path, msg: Any) -> SweepInput:
    """A PointCloud2 of the log format to a :class:`SweepInput` (fields by name and offset)."""
    ns = stamp_ns(msg.header.stamp)
    names = {f.name for f in msg.fields}
    missing = {"x", "y"} - names
    if missing:
        raise LogError(f"{path}: PointCloud2 at stamp {ns} has no field {sorted(missing)[0]!r}")
    wanted = [n for n in ("x", "y", "t", "velocity", "intensity") if n in names]
    try:
        cols = pointcloud_columns(msg, wanted)
    except ValueError as exc:
        raise LogError(f"{path}: PointCloud2 at stamp {ns}: {exc}") from None
    n = len(cols["x"])
    t = cols.get("t", np.zeros(n))
    vel, inten = cols.get("velocity"), cols.get("intensity")
    _finite(path, "PointCloud2", ns, cols["x"], cols["y"], t, vel)
    return SweepInput(ns, np.column_stack([cols["x"], cols["y"]]), t, vel, inten)


def sweep_from_laserscan(path: Path, msg: Any) -> SweepInput:
    """A ``sensor_msgs/LaserScan`` to a :class:`SweepInput` without Doppler.

    Ranges outside ``[range_min, range_max]`` or not finite are no return (REP-117).
    """
    ns = stamp_ns(msg.header.stamp)
    r = np.asarray(msg.ranges, dtype=float)
    i = np.arange(r.size)
    ang = msg.angle_min + i * msg.angle_increment
    ok = np.isfinite(r) & (r >= msg.range_min) & (r <= msg.range_max)
    inten = np.asarray(msg.intensities, dtype=float)[ok] if len(msg.intensities) == r.size else None
    xy = np.column_stack([r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])])
    return SweepInput(ns, xy, (i * float(msg.time_increment))[ok], None, inten)


def iter_inputs(reader: LogReader, topics: InputTopics) -> Iterator[SweepInput | TicksInput | OdomInput]:
    """The estimator's inputs in file order: sweeps, and ticks or odometry as the motion prior."""
    for m in reader.messages([t for t in (topics.scan, topics.ticks, topics.odom) if t]):
        if m.topic == topics.scan:
            if m.datatype.endswith("PointCloud2"):
                yield sweep_from_pointcloud(reader.path, m.msg)
            else:
                yield sweep_from_laserscan(reader.path, m.msg)
        elif m.topic == topics.ticks:
            yield TicksInput(stamp_ns(m.msg.header.stamp), int(m.msg.left), int(m.msg.right))
        else:
            pose, _ = odometry_pose_twist(m.msg)
            _finite(reader.path, "Odometry", m.log_time_ns, pose)
            yield OdomInput(stamp_ns(m.msg.header.stamp), pose)


@dataclass(frozen=True)
class InputTopics:
    """The topics one run reads: a scan topic and at most one motion-prior topic."""

    scan: str
    ticks: str | None
    odom: str | None

    @property
    def prior(self) -> str | None:
        return self.ticks or self.odom


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
                               "name one with --scan-topic")
            scan = scans[0]
    if scan not in topics:
        raise LogError(f"{path}: no topic {scan}")
    if not topics[scan].endswith(("PointCloud2", "LaserScan")):
        raise LogError(f"{path}: {scan} is {topics[scan]}, not a PointCloud2 or LaserScan")
    if odom is not None:
        if odom not in topics:
            raise LogError(f"{path}: no topic {odom}")
        return InputTopics(scan, None, odom)
    if ticks is None and TICKS_TOPIC in topics:
        ticks = TICKS_TOPIC
    if ticks is None and topics.get("/odom", "").endswith("Odometry"):  # an imported or ROS log
        return InputTopics(scan, None, "/odom")
    if ticks is not None and ticks not in topics:
        raise LogError(f"{path}: no topic {ticks}")
    return InputTopics(scan, ticks, None)
