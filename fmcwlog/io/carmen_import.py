"""``fmcwlog import``: real 2-D laser logs (CARMEN, CMU course format) as fmcwlog MCAP logs.

A scan becomes a ``sensor_msgs/msg/LaserScan`` on ``/scan`` in frame ``laser`` (``/rear_scan`` in
``rear_laser`` for ``RLASER``, ``RAWLASER2``), odometry a ``nav_msgs/msg/Odometry`` on ``/odom`` (frame
``odom``, child ``base_link``), stamped with the log's own times. Where the log has no odometry messages
(the Intel subset), the odometry pose each laser line carries is used. The laser's pose on the robot goes
into ``fmcwlog.calibration`` (``lidar_x``, ``lidar_y``, ``lidar_yaw``); ``fmcwlog.import`` records the
source, its format and what was skipped.

The tf tree a viewer needs (REP-105), so that every message resolves to ``map``:

- ``/tf_static``, once: ``base_link`` -> ``laser`` (and -> ``rear_laser``) at the lasers' poses on the
  robot, and ``map`` -> ``odom``. A CARMEN log has no map frame: ``map`` is put where the robot is at
  the first scan, the origin ``fmcwlog process`` gives every estimate, so that ``processed.mcap``
  overlays the import;
- ``/tf``: ``odom`` -> ``base_link`` with each odometry pose, and, for a scan before the first or after
  the last of them, the nearest one again at the scan's stamp (tf never extrapolates).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CarmenImportError, excerpt, os_reason
from ..geometry import interpolate_poses, inverse
from .atomic import created_parents, reported_write_errors
from .carmen import ParsedLog, ScanRecord, parse_log
from .mcap_log import LogWriter
from .messages import odometry_message, stamp, tf_message, transform_dict
from .topics import BASE_FRAME, CALIBRATION_KEY, IMPORT_KEY, MAP_FRAME, TF_STATIC_TOPIC, TF_TOPIC

logger = logging.getLogger(__name__)  # the command line prints its warnings as 'fmcwlog: warning: ...'


@dataclass
class ImportSummary:
    path: Path
    scans: int
    odometry: int
    odometry_source: str
    bad_lines: list[tuple[int, str]]
    span_s: float


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _no_scans(parsed: ParsedLog) -> str:
    """Why a parsed file gives no log: what its lines were instead."""
    readable = sorted(k for k in parsed.ignored if k.isascii() and k.isprintable())
    if len(readable) < len(parsed.ignored):
        other = f", {sum(parsed.ignored.values())} of binary data or unknown records: not a text log?"
    else:
        kinds = ", ".join(excerpt(k) for k in readable[:5]) + (", ..." if len(readable) > 5 else "")
        other = f", {sum(parsed.ignored.values())} of kinds not imported: {kinds}" if readable else ""
    first = f"; first malformed: line {parsed.bad_lines[0][0]}: {parsed.bad_lines[0][1]}" if parsed.bad_lines else ""
    stopped = f"; {parsed.stopped}" if parsed.stopped else ""
    odometry = f", {len(parsed.odometry)} of odometry" if parsed.odometry else ""
    return (f"{parsed.path}: no laser scans found in {parsed.lines} lines "
            f"({len(parsed.bad_lines)} malformed{odometry}{other}){first}{stopped}")


ODOM_FRAME = "odom"
LASER_FRAMES = {"/scan": "laser", "/rear_scan": "rear_laser"}  # each laser's frame, by topic


def _static_transforms(scans: list[ScanRecord], odom: list[tuple[float, tuple]], first_ns: int, ns: int) -> dict:
    """``/tf_static``: each laser's mount (its first scan's, as the calibration takes the front one's)
    and ``map`` -> ``odom``, with ``map``'s origin at the robot's odometry pose at ``first_ns`` (the
    first front scan's stamp), held at the first or last pose outside their span as processing holds it."""
    mounts: dict[str, tuple[float, float, float]] = {}
    for s in scans:
        mounts.setdefault(s.topic, s.laser_pose)
    origin = np.zeros(3)
    if odom:
        t = np.array([_ns(o[0]) for o in odom]) * 1e-9  # the stamps /odom carries
        origin = inverse(interpolate_poses(np.array(first_ns * 1e-9), t, np.array([o[1] for o in odom], float)))
    return tf_message([*(transform_dict(ns, BASE_FRAME, LASER_FRAMES[topic], np.asarray(m, float))
                         for topic, m in mounts.items()), transform_dict(ns, MAP_FRAME, ODOM_FRAME, origin)])


def _calibration(scans: list[ScanRecord]) -> dict[str, str]:
    """The ``fmcwlog.calibration`` record: the front laser's pose on the robot and its beams."""
    front = [s for s in scans if s.topic == "/scan"] or scans
    mount = front[0].laser_pose
    return {"lidar_x": repr(float(mount[0])), "lidar_y": repr(float(mount[1])), "lidar_yaw": repr(float(mount[2])),
            "max_range": repr(float(front[0].range_max)),
            "angular_resolution": repr(float(front[0].angle_increment)),
            "fov": repr(float(front[0].angle_increment * (len(front[0].ranges) - (len(front[0].ranges) % 2 == 0)))),
            "scan_rate": "0"}


def _import_record(parsed: ParsedLog, scans: int, odometry: int, source: str) -> dict[str, str]:
    """The ``fmcwlog.import`` record: the source, its format and what was skipped."""
    info = {"source": str(parsed.path), "format": parsed.format, "scans": str(scans), "odometry": str(odometry),
            "odometry_source": source, "bad_lines": json.dumps(parsed.bad_lines[:1000]),
            "ignored": json.dumps(parsed.ignored), "params": json.dumps(parsed.params)}
    if parsed.stopped:
        info["stopped"] = parsed.stopped
    return info


def _warn_order(parsed: ParsedLog) -> None:
    """Say where the log's time went backwards: its records are written in time order, which moves them."""
    if parsed.backwards:
        (line, back), n = parsed.backwards[0], len(parsed.backwards)
        more = f" and {n - 1} more" if n > 1 else ""
        logger.warning(f"{parsed.path}: time goes backwards at line {line} ({back:.3f} s before an earlier "
                       f"record of its kind){more}; wrote every stream in time order")


def write_mcap(parsed: ParsedLog, out: Path) -> ImportSummary:
    scans = [s for s in parsed.scans if s.topic == "/scan"] + [s for s in parsed.scans if s.topic != "/scan"]
    if not parsed.scans:
        raise CarmenImportError(_no_scans(parsed))
    if parsed.stopped:
        logger.warning(f"{parsed.path}: {parsed.stopped}; imported the lines before it")
    if parsed.odometry:
        odom = [(o.stamp, o.pose) for o in parsed.odometry]
        source = "odometry messages"
    else:
        odom = [(s.stamp, s.odom_pose) for s in parsed.scans if s.odom_pose is not None and s.topic == "/scan"]
        source = ("the odometry pose of each laser line" if odom
                  else "nowhere: the log has no ODOM lines and its laser lines no pose")
    _warn_order(parsed)
    events, repeated = _unique_stamps(sorted([(s.stamp, 0, i) for i, s in enumerate(scans)]
                                             + [(t, 1, i) for i, (t, _) in enumerate(odom)]), scans)
    for topic, n in repeated.items():
        logger.warning(f"{parsed.path}: skipped {n} {'scans' if topic != '/odom' else 'odometry poses'} whose "
                       f"stamp repeats the one before (kept the first; {topic})")
    n_scans = sum(kind == 0 for _, kind, _ in events)
    n_odom = len(events) - n_scans
    kept_odom = [odom[i] for _, kind, i in events if kind == 1]
    # a scan outside the odometry's span gets the nearest odometry pose again at its stamp on /tf
    scan_ns = [_ns(t) for t, kind, _ in events if kind == 0]
    held = {}
    if kept_odom:
        first, last = _ns(kept_odom[0][0]), _ns(kept_odom[-1][0])
        if scan_ns[0] < first:
            held[scan_ns[0]] = kept_odom[0][1]
        if scan_ns[-1] > last:
            held[scan_ns[-1]] = kept_odom[-1][1]
    with LogWriter(out) as w:
        w.add_metadata(CALIBRATION_KEY, _calibration(scans))
        w.add_metadata(IMPORT_KEY, _import_record(parsed, n_scans, n_odom, source))
        start = _ns(events[0][0])
        front = next(_ns(t) for t, kind, i in events if kind == 0 and scans[i].topic == scans[0].topic)
        w.write(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", _static_transforms(scans, kept_odom, front, start), start)
        for t, kind, i in events:
            ns = _ns(t)
            if kind == 0:
                s = scans[i]
                n = len(s.ranges)
                if ns in held:
                    w.write(TF_TOPIC, "tf2_msgs/msg/TFMessage", tf_message(
                        [transform_dict(ns, ODOM_FRAME, BASE_FRAME, np.asarray(held.pop(ns), float))]), ns)
                w.write(s.topic, "sensor_msgs/msg/LaserScan", {
                    "header": {"stamp": stamp(ns), "frame_id": LASER_FRAMES[s.topic]},
                    "angle_min": s.angle_min, "angle_max": s.angle_min + (n - 1) * s.angle_increment,
                    "angle_increment": s.angle_increment, "time_increment": 0.0, "scan_time": 0.0,
                    "range_min": 0.0, "range_max": s.range_max,
                    "ranges": np.asarray(s.ranges, np.float32).tolist(), "intensities": []}, ns)
            else:
                pose = np.asarray(odom[i][1], float)
                w.write("/odom", "nav_msgs/msg/Odometry", odometry_message(ns, ODOM_FRAME, BASE_FRAME, pose, np.zeros(3)), ns)
                w.write(TF_TOPIC, "tf2_msgs/msg/TFMessage", tf_message([transform_dict(ns, ODOM_FRAME, BASE_FRAME, pose)]), ns)
    return ImportSummary(out, n_scans, n_odom, source, parsed.bad_lines, events[-1][0] - events[0][0])


def _unique_stamps(events: list[tuple[float, int, int]], scans: list[ScanRecord]
                   ) -> tuple[list[tuple[float, int, int]], dict[str, int]]:
    """The events (stamp, kind, index) in stamp order with a repeated stamp on a topic left out (the
    first kept: a topic's stamps must increase), and how many each topic lost."""
    last: dict[str, int] = {}
    kept, repeated = [], {}
    for t, kind, i in events:
        ns, topic = _ns(t), scans[i].topic if kind == 0 else "/odom"
        if last.get(topic) == ns:
            repeated[topic] = repeated.get(topic, 0) + 1
            continue
        last[topic] = ns
        kept.append((t, kind, i))
    return kept, repeated


def import_carmen(source: str | Path, output: str | Path) -> tuple[ImportSummary, str]:
    """Convert a CARMEN or CMU course log into an fmcwlog MCAP log; returns the summary and the format."""
    try:
        parsed = parse_log(Path(source))
    except (OSError, EOFError, UnicodeDecodeError) as exc:  # a damaged .gz/.xz stream is an EOFError or OSError
        reason = os_reason(exc) if isinstance(exc, OSError) else str(exc) or type(exc).__name__
        raise CarmenImportError(f"{source}: cannot read ({reason})") from None
    with reported_write_errors(output), created_parents(output):
        return write_mcap(parsed, Path(output)), parsed.format
