"""Which topics of a log ``fmcwlog process`` reads: a scan topic and at most one motion prior (wheel
ticks, or odometry where the ticks have no wheel geometry to go with them)."""

from __future__ import annotations

import warnings
from pathlib import Path

from ..errors import LogError
from ..types import InputTopics
from .calibration import wheels_hint, wheels_missing
from .logs import Log
from .topics import GROUND_TRUTH_PREFIX, POINTS_TOPIC, TICKS_TOPIC


def choose_topics(reader: Log, scan: str | None = None, ticks: str | None = None,
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


def _check_named_topic(reader: Log, topic: str, type_names: tuple[str, ...], expected: str) -> None:
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


def odometry_instead_of_ticks(reader: Log, topics: InputTopics, ticks_named: bool,
                              calibration_file: Path | None = None) -> InputTopics:
    """Wheel ticks that nothing gives the wheels' geometry for (a log converted by a tool that keeps the
    topics and drops fmcwlog's metadata): the log's ``/odom`` as the motion prior instead, said in one
    warning; where it has none, or the ticks were named (``--ticks-topic``), one error naming
    ``--calibration`` and a file that would do."""
    path = reader.path
    why = wheels_missing(topics.ticks or "", calibration_file)
    has_odom = reader.topics.get("/odom", "").endswith("Odometry")
    if has_odom and not ticks_named:
        warnings.warn(f"{path}: {why}: used /odom as the motion prior instead; to use the ticks, {wheels_hint(path)}",
                      stacklevel=2)
        return InputTopics(topics.scan, None, "/odom")
    other = "; or --odom-topic /odom for the log's odometry" if has_odom else ""
    raise LogError(f"{path}: {why}: {wheels_hint(path)}{other}{reader.damage_note()}")
