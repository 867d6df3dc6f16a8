"""Which topics of a log ``fmcwlog process`` reads: a scan topic and at most one motion prior."""

from __future__ import annotations

from ..errors import LogError
from ..types import InputTopics
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
