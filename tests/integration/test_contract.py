"""The log-format contract (docs/log-format.md) as estimation sees it.

- Estimation reads ``/fmcw/points``, ``/wheel/ticks`` and ``fmcwlog.calibration`` only: every other
  topic and metadata record replaced by garbage changes no estimate.
- Point fields are located by name and offset, whatever their order, padding or float width.
- A LaserScan with a robot's own (drifting) odometry as the prior, no Doppler, no ground truth: the
  improved method still corrects the odometry's drift.

Logs are rewritten here with plain ``mcap`` + ``mcap_ros2``; ground truth is read the same way.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from helpers import ROOT, SAMPLE_LOGS, ate_rmse, copy_log, decoded, ground_truth, tum, wheel_odometry
from mcap.reader import make_reader
from mcap_ros2.writer import Writer

from fmcwlog.api import ProcessOptions, process, report
from fmcwlog.errors import LogError, ReportError
from fmcwlog.io.mcap_log import LogReader

pytestmark = pytest.mark.slow  # end to end: process and report on logs

CORRIDOR = SAMPLE_LOGS / "corridor_30s.mcap"
ESTIMATES = ("improved.tum", "baseline.tum", "wheel_odometry.tum", "improved_map.pgm", "baseline_map.pgm",
             "improved_map.yaml", "baseline_map.yaml")


def _same_estimates(out: Path, ref: Path) -> None:
    for name in ESTIMATES:
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name
    a = pq.read_table(out / "trajectories.parquet").drop(["ms"])
    b = pq.read_table(ref / "trajectories.parquet").drop(["ms"])
    assert a.equals(b)


def _metadata(path: Path) -> dict[str, dict[str, str]]:
    with open(path, "rb") as fh:
        return {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}


def test_estimates_depend_only_on_the_processed_topics(processed, tmp_path):
    """Ground truth, the world and the simulator's own record (which holds the true wheel radii)
    are replaced by garbage, not removed: a leak of any of them into estimation would show."""
    rng = np.random.default_rng(99)
    garbage = tmp_path / "garbage.mcap"

    def scramble(topic, i, msg):
        if topic == "/ground_truth/odom":
            msg.pose.pose.position.x, msg.pose.pose.position.y = rng.uniform(-50, 50, 2)
            msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(i), math.cos(i)
            msg.twist.twist.linear.x, msg.twist.twist.angular.z = rng.uniform(-5, 5, 2)
        elif topic == "/ground_truth/point_labels":
            msg.moving = rng.integers(0, 2, len(msg.moving), dtype=np.uint8).tobytes()
        elif topic in ("/ground_truth/tf", "/tf"):  # the true pose, and its own tree on /tf
            for tr in msg.transforms:
                if topic == "/ground_truth/tf" or tr.child_frame_id.startswith("ground_truth/"):
                    tr.transform.translation.x, tr.transform.translation.y = rng.uniform(-50, 50, 2)

    meta = _metadata(CORRIDOR)
    sim = dict(meta["fmcwlog.sim"], true_wheel_radius_left="0.13", true_wheel_radius_right="0.07",
               config=json.dumps({"robot": {"wheel_radius": 0.5}, "sensor": {"mount_x": -3.0}}), seed="12345")
    world = {"features": json.dumps([{"id": 1, "name": "junk", "a": [0, 0], "b": [99, 99]}]),
             "walls": json.dumps([[0, 0, 1, 1]])}
    copy_log(CORRIDOR, garbage, drop_metadata=("fmcwlog.sim", "fmcwlog.world"), edit=scramble,
             extra_metadata={"fmcwlog.sim": sim, "fmcwlog.world": world})
    assert _metadata(garbage)["fmcwlog.sim"]["true_wheel_radius_left"] == "0.13"
    out = tmp_path / "out"
    process(garbage, out, ProcessOptions())
    _same_estimates(out, processed["corridor_30s"])


def test_point_fields_are_found_by_name_and_offset(processed, tmp_path):
    """The same sweeps with the fields reordered, padded, and x, y, t as FLOAT64: the same estimates."""
    layout = [("t", 8), None, ("velocity", 7), ("y", 8), None, ("intensity", 7), ("z", 7), ("x", 8), None]
    size = {7: 4, 8: 8}
    dtype_of = {7: "<f4", 8: "<f8"}
    pad = 3  # bytes of padding where the layout says None

    def reorder(topic, i, msg):
        if topic != "/fmcw/points":
            return None
        n = msg.width * msg.height
        cols = {f.name: np.ndarray((n,), "<f4", bytes(msg.data), f.offset, (msg.point_step,)) for f in msg.fields}
        offset, fields, spans = 0, [], []
        for entry in layout:
            if entry is None:
                offset += pad
                continue
            name, datatype = entry
            fields.append({"name": name, "offset": offset, "datatype": datatype, "count": 1})
            spans.append((name, offset, datatype))
            offset += size[datatype]
        step = offset
        buf = np.zeros((n, step), np.uint8)
        for name, off, datatype in spans:
            col = cols[name].astype(dtype_of[datatype])
            buf[:, off:off + size[datatype]] = col.view(np.uint8).reshape(n, size[datatype])
        msg.fields = fields
        msg.point_step, msg.row_step, msg.data = step, step * n, buf.tobytes()
        return None

    shuffled = tmp_path / "shuffled.mcap"
    copy_log(CORRIDOR, shuffled, edit=reorder)
    first = next(m for _, c, _, m in decoded(shuffled, ["/fmcw/points"]))
    assert [f.name for f in first.fields][:2] == ["t", "velocity"] and first.point_step == 8 + 3 + 4 + 8 + 3 + 4 + 4 + 8 + 3
    out = tmp_path / "out"
    process(shuffled, out, ProcessOptions())
    _same_estimates(out, processed["corridor_30s"])


def test_laserscan_with_the_robots_own_odometry(tmp_path):
    """No Doppler, no ground truth in the prior: the robot's drifting wheel odometry on /odom."""
    src = CORRIDOR
    dst = tmp_path / "scan.mcap"
    schemas = ROOT / "schemas"
    header = ("=" * 80 + "\nMSG: std_msgs/msg/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
              + "=" * 80 + "\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n")
    odometry = wheel_odometry(src)
    with open(dst, "wb") as out:
        w = Writer(out)
        w.add_metadata("fmcwlog.calibration", _metadata(src)["fmcwlog.calibration"])  # where the lidar sits
        scan_schema = w.register_msgdef("sensor_msgs/msg/LaserScan",
                                        (schemas / "sensor_msgs" / "msg" / "LaserScan.msg").read_text() + header)
        with open(src, "rb") as fh:
            summary = make_reader(fh).get_summary()
        odom_text = next(sc.data.decode() for sc in summary.schemas.values() if sc.name == "nav_msgs/msg/Odometry")
        odom_schema = w.register_msgdef("nav_msgs/msg/Odometry", odom_text)
        n, res = 1081, math.radians(0.25)
        queue = iter(odometry)
        pending = next(queue, None)
        for _, _, message, msg in decoded(src, ["/fmcw/points"]):
            while pending is not None and pending[0] <= message.log_time + 100_000_000:
                ns, pose = pending
                w.write_message("/odom", odom_schema, {
                    "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": "odom"},
                    "child_frame_id": "base_link",
                    "pose": {"pose": {"position": {"x": pose[0], "y": pose[1], "z": 0.0},
                                      "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(pose[2] / 2),
                                                      "w": math.cos(pose[2] / 2)}}, "covariance": [0.0] * 36},
                    "twist": {"twist": {"linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                                        "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}, "covariance": [0.0] * 36},
                }, log_time=ns, publish_time=ns)
                pending = next(queue, None)
            pts = np.frombuffer(bytes(msg.data), np.float32).reshape(-1, 6)
            beam = np.rint((np.arctan2(pts[:, 1], pts[:, 0]) + math.radians(135)) / res).astype(int)
            ranges = np.full(n, np.inf, np.float32)
            ranges[beam] = np.hypot(pts[:, 0], pts[:, 1])
            w.write_message("/scan", scan_schema, {
                "header": {"stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec}, "frame_id": "laser"},
                "angle_min": -math.radians(135), "angle_max": math.radians(135), "angle_increment": res,
                "time_increment": 0.075 / 1080, "scan_time": 0.1, "range_min": 0.1, "range_max": 30.0,
                "ranges": ranges.tolist(), "intensities": []}, log_time=message.log_time, publish_time=message.log_time)
        w.finish()
    out = tmp_path / "out"
    s = process(dst, out, ProcessOptions())
    assert not s.doppler and s.sweeps == 300 and s.prior == "odometry (/odom)"
    run = json.loads((out / "run.json").read_text())
    assert run["doppler"] is False and any("no Doppler" in w for w in run["warnings"])
    gt = ground_truth(src)
    errors = {m: ate_rmse(tum(out / f"{m}.tum"), gt) for m in ("improved", "baseline", "wheel_odometry")}
    assert errors["improved"] < 0.10, errors  # measured 4.9 cm
    assert errors["wheel_odometry"] > 2 * errors["improved"], errors  # measured 15.2 cm: its drift is corrected
    assert errors["baseline"] > 2 * errors["improved"], errors  # measured 36.7 cm


def test_how_a_writer_interleaves_topics_does_not_change_the_estimates(processed, tmp_path):
    """The log format (docs/log-format.md) leaves the order of topics in the file to the writer (MCAP orders nothing):
    every wheel tick written before the first sweep, or every sweep before the first tick, must
    give the estimates of the log written in time order. (Read in file order, the ticks-first log
    gave the sweeps a motion prior from the log's end: the improved trajectory up to 2.2 m and the
    baseline's 0.97 m from those of the time-ordered log, and the improved method stopped trusting
    the wheel ticks.)"""
    for first in ("/wheel/ticks", "/fmcw/points"):
        grouped = tmp_path / f"{first.strip('/').replace('/', '_')}_first.mcap"
        copy_log(CORRIDOR, grouped, order=lambda topic, log_time, first=first: (topic != first, log_time))
        with open(grouped, "rb") as fh:
            topics = [c.topic for _, c, _ in make_reader(fh).iter_messages(log_time_order=False)]
        n = topics.count(first)
        assert set(topics[:n]) == {first} and first not in topics[n:], "the writer did not group the topic"
        out = tmp_path / f"out_{grouped.stem}"
        process(grouped, out, ProcessOptions())
        _same_estimates(out, processed["corridor_30s"])


@pytest.mark.parametrize("hold_bytes", [0, 50_000, None])
def test_the_time_ordered_read_is_the_log_time_order_whether_it_reads_once_or_a_topic_at_a_time(tmp_path, hold_bytes):
    """The reader's merge (one pass while its queues stay under ``hold_bytes``, then a pass per topic
    resuming where the first left off) against plain mcap's messages sorted by (log_time, topic's
    place in the request), stably: the same sequence for a log in time order and for grouped ones."""
    wanted = ["/fmcw/points", "/wheel/ticks"]
    for first in (None, "/wheel/ticks", "/fmcw/points"):
        log = CORRIDOR
        if first is not None:
            log = tmp_path / f"{first.strip('/').replace('/', '_')}_first.mcap"
            if not log.exists():
                copy_log(CORRIDOR, log, order=lambda topic, log_time, first=first: (topic != first, log_time))
        with open(log, "rb") as fh:
            in_file = [(m.log_time, c.topic) for _, c, m in make_reader(fh).iter_messages(log_time_order=False)
                       if c.topic in wanted]
        expected = sorted(in_file, key=lambda x: (x[0], wanted.index(x[1])))
        reader = LogReader(log)
        kw = {} if hold_bytes is None else {"hold_bytes": hold_bytes}
        got = [(m.log_time, c.topic) for _, c, m in reader.raw_messages_by_time(wanted, **kw)]
        assert got == expected, (first, hold_bytes)


def _baseline_warnings(log: Path, out: Path) -> list[str]:
    return process(log, out, ProcessOptions(methods=("baseline",), backend="none"), jobs=1).warnings


def test_sweeps_without_point_times_are_said(crowd_log, tmp_path):
    """The log format (docs/log-format.md) requires the field ``t``: a cloud without it cannot be deskewed, and its points
    are taken at the sweep's stamp; that is said once, with the count of such sweeps (it was silent,
    and on a 12 s crowd log the improved trajectory moved 3 m)."""
    untimed = tmp_path / "untimed.mcap"

    def drop_t(topic, i, msg):
        if topic == "/fmcw/points":
            msg.fields = [f for f in msg.fields if f.name != "t"]

    copy_log(crowd_log, untimed, edit=drop_t)
    sweeps = sum(1 for _ in decoded(untimed, ["/fmcw/points"]))
    said = [w for w in _baseline_warnings(untimed, tmp_path / "out") if "no field 't'" in w]
    assert said == [f"{sweeps} sweeps on /fmcw/points have no field 't' (each point's time after the stamp): their "
                    "points were taken as measured at the sweep's stamp, not deskewed"]
    assert not [w for w in _baseline_warnings(crowd_log, tmp_path / "ref") if "no field" in w]


def test_a_calibration_record_without_the_mount_is_said_naming_the_keys(crowd_log, tmp_path):
    """The log format (docs/log-format.md) lists lidar_x, lidar_y, lidar_yaw in ``fmcwlog.calibration``; a record without
    some of them puts the lidar at base_link's origin, which is said, naming the log and the keys."""
    record = _metadata(crowd_log)["fmcwlog.calibration"]
    log = tmp_path / "no_mount.mcap"
    copy_log(crowd_log, log, drop_metadata=("fmcwlog.calibration",),
             extra_metadata={"fmcwlog.calibration": {k: v for k, v in record.items() if k not in ("lidar_x", "lidar_yaw")}})
    said = [w for w in _baseline_warnings(log, tmp_path / "out") if "lidar" in w and "taken as 0" in w]
    assert said == [f"{log}: fmcwlog.calibration has no lidar_x, lidar_yaw: taken as 0 (the lidar at base_link's "
                    "origin, facing forward)"]


def _rewritten(src: Path, dst: Path, edit) -> Path:
    """``src`` written again by mcap_ros2's writer (not fmcwlog's), its metadata as they were and each
    message through ``edit(topic, schema_name, schema_text, msg, log_time)``, which returns the four
    to write (publish_time = log_time)."""
    with open(dst, "wb") as fh:
        w = Writer(fh)
        schemas: dict[str, object] = {}
        for name, values in _metadata(src).items():
            w.add_metadata(name, values)
        for schema, channel, message, msg in decoded(src):
            name, text, out, log_time = edit(channel.topic, schema.name, schema.data.decode(), msg, message.log_time)
            if name not in schemas:
                schemas[name] = w.register_msgdef(name, text)
            w.write_message(channel.topic, schemas[name], out, log_time=log_time, publish_time=log_time)
        w.finish()
    return dst


def test_a_log_time_other_than_the_header_stamp_is_said_and_report_names_it(crowd_log, tmp_path):
    """The log format (docs/log-format.md): a message's log_time equals its header.stamp. A writer that logs receive times
    (sweeps 80 ms late) gets a warning from process, which goes by header.stamp, and a report error
    that says so (it said the log, whose sha256 run.json holds, 'does not belong' to its outputs)."""
    def receive_times(topic, name, text, msg, log_time):
        return name, text, msg, log_time + (80_000_000 if topic == "/fmcw/points" else 0)

    late = _rewritten(crowd_log, tmp_path / "late.mcap", receive_times)
    sweeps = sum(1 for _ in decoded(late, ["/fmcw/points"]))
    out = tmp_path / "out"
    said = [w for w in _baseline_warnings(late, out) if "log_time" in w]
    assert len(said) == 1 and said[0].startswith(f"{sweeps} messages on /fmcw/points have a log_time other than "
                                                 "their header.stamp")
    with pytest.raises(ReportError, match="log_time of its /fmcw/points messages differs from their header.stamp"):
        report(out)


@pytest.mark.parametrize("type_name, words", [
    ("other_msgs/msg/Encoders", "/wheel/ticks is other_msgs/msg/Encoders, not a fmcwlog_msgs/msg/WheelTicks"),
    ("fmcwlog_msgs/msg/WheelTicks", "/wheel/ticks is fmcwlog_msgs/msg/WheelTicks without the fields header, left and "
                                    "right of fmcwlog_msgs/msg/WheelTicks"),
])
def test_wheel_ticks_of_another_layout_are_one_error_naming_the_type(crowd_log, tmp_path, type_name, words):
    """The log format (docs/log-format.md) fixes /wheel/ticks as fmcwlog_msgs/msg/WheelTicks (int64 left, right). Encoder
    counts of another type, or under that name with other fields, were a traceback (AttributeError)."""
    def encoders(topic, name, text, msg, log_time):
        if topic != "/wheel/ticks":
            return name, text, msg, log_time
        text = text.replace("int64 left", "int32 left_ticks").replace("int64 right", "int32 right_ticks")
        out = {"header": {"stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec},
                          "frame_id": msg.header.frame_id}, "left_ticks": msg.left, "right_ticks": msg.right}
        return type_name, text, out, log_time

    log = _rewritten(crowd_log, tmp_path / "encoders.mcap", encoders)
    with pytest.raises(LogError) as info:
        process(log, tmp_path / "out", ProcessOptions(methods=("baseline",), backend="none"), jobs=1)
    expected = f"{log}: {words} (docs/log-format.md)" if "without" in words else f"{log}: {words}"
    assert str(info.value) == expected
    assert not (tmp_path / "out").exists()


def test_an_odometry_topic_of_another_type_is_one_error_naming_the_type(crowd_log, tmp_path):
    """``--odom-topic`` naming a topic that is no nav_msgs/msg/Odometry was a traceback (AttributeError)."""
    with pytest.raises(LogError) as info:
        process(crowd_log, tmp_path / "out", ProcessOptions(odom_topic="/fmcw/points"), jobs=1)
    assert str(info.value) == f"{crowd_log}: /fmcw/points is sensor_msgs/msg/PointCloud2, not a nav_msgs/msg/Odometry"
