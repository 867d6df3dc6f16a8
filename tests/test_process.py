"""`fmcwlog process` end to end: accuracy against ground truth, outputs, other writers, bad input.

Ground truth and labels are read here with plain ``mcap`` + ``mcap_ros2``, and
the trajectory error uses a small alignment written for the test (2-D Kabsch),
not fmcwlog's metrics.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import SAMPLE_LOGS
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from fmcwlog.api import ProcessOptions
from fmcwlog.api import process as process_log

# ----------------------------------------------------------------------------- helpers


def decoded(path: Path, topics=None):
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        yield from reader.iter_decoded_messages(topics=topics)


def copy_log(src: Path, dst: Path, drop_topics=(), drop_metadata=(), edit=None) -> None:
    """Re-encode a log message by message; ``edit(topic, index, msg)`` may change a message or
    return False to drop it."""
    with open(src, "rb") as fh:
        meta = {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}
    counts: dict[str, int] = {}
    with open(dst, "wb") as out:
        w = Writer(out)
        schemas = {}
        for name, values in meta.items():
            if name not in drop_metadata:
                w.add_metadata(name, values)
        for schema, channel, message, msg in decoded(src):
            if channel.topic in drop_topics:
                continue
            i = counts.get(channel.topic, 0)
            counts[channel.topic] = i + 1
            if edit is not None and edit(channel.topic, i, msg) is False:
                continue
            if schema.name not in schemas:
                schemas[schema.name] = w.register_msgdef(schema.name, schema.data.decode())
            w.write_message(channel.topic, schemas[schema.name], msg, log_time=message.log_time,
                            publish_time=message.publish_time)
        w.finish()


def ground_truth(path: Path):
    rows = []
    for _, _, message, m in decoded(path, ["/ground_truth/odom"]):
        p, q = m.pose.pose.position, m.pose.pose.orientation
        rows.append([message.log_time * 1e-9, p.x, p.y, math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z)])
    return np.array(rows)


def tum(path: Path) -> np.ndarray:
    a = np.loadtxt(path, ndmin=2)
    return np.column_stack([a[:, 0], a[:, 1], a[:, 2], 2 * np.arctan2(a[:, 6], a[:, 7])])


def ate_rmse(est: np.ndarray, gt: np.ndarray) -> float:
    """RMSE of positions after the best rigid 2-D alignment (Kabsch), GT interpolated at est stamps."""
    ref = np.column_stack([np.interp(est[:, 0], gt[:, 0], gt[:, i]) for i in (1, 2)])
    p = est[:, 1:3] - est[:, 1:3].mean(0)
    q = ref - ref.mean(0)
    u, _, vt = np.linalg.svd(p.T @ q)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, d]) @ u.T
    return float(np.sqrt(np.mean(np.sum((p @ r.T - q) ** 2, axis=1))))


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    """The two committed sample logs, processed once with both methods."""
    out = {}
    for name in ("corridor_30s", "crowd_30s"):
        d = tmp_path_factory.mktemp(name) / "out"
        process_log(SAMPLE_LOGS / f"{name}.mcap", d, ProcessOptions())
        out[name] = d
    return out


# ----------------------------------------------------------------------------- accuracy


@pytest.mark.parametrize("name, target", [("corridor_30s", 0.05), ("crowd_30s", 0.10)])
def test_improved_beats_baseline_and_wheel_odometry(processed, name, target):
    gt = ground_truth(SAMPLE_LOGS / f"{name}.mcap")
    errors = {m: ate_rmse(tum(processed[name] / f"{m}.tum"), gt) for m in ("improved", "baseline", "wheel_odometry")}
    assert errors["improved"] < target, errors
    assert errors["improved"] < errors["baseline"] and errors["improved"] < errors["wheel_odometry"], errors


@pytest.mark.parametrize("name", ["corridor_30s", "crowd_30s"])
def test_moving_points_found_with_precision_and_recall_above_90_percent(processed, name):
    truth = {msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec: np.frombuffer(bytes(msg.moving), np.uint8)
             for _, _, _, msg in decoded(SAMPLE_LOGS / f"{name}.mcap", ["/ground_truth/point_labels"])}
    tp = fp = fn = 0
    n = 0
    for _, _, message, msg in decoded(processed[name] / "processed.mcap", ["/improved/moving_labels"]):
        est = np.frombuffer(bytes(msg.moving), np.uint8).astype(bool)
        ref = truth[message.log_time].astype(bool)
        assert est.shape == ref.shape
        tp += int(np.sum(est & ref))
        fp += int(np.sum(est & ~ref))
        fn += int(np.sum(~est & ref))
        n += 1
    assert n == len(truth)
    assert tp + fn > 500  # there were movers to find
    precision, recall = tp / (tp + fp), tp / (tp + fn)
    assert precision > 0.9 and recall > 0.9, (precision, recall)


def test_long_corridor_does_not_slide(tmp_path):
    """Geometry cannot fix the position along a bare corridor; the Doppler speed can."""
    from fmcwlog.sim import scenarios
    from fmcwlog.sim.config import SimConfig, apply_overrides
    from fmcwlog.sim.recorder import record

    log = tmp_path / "long.mcap"
    record(scenarios.long_corridor(), apply_overrides(SimConfig(), {"run": {"duration": 60.0}}), log)
    out = tmp_path / "out"
    process_log(log, out, ProcessOptions())
    gt = ground_truth(log)
    # compare distance travelled from the start, the along-axis motion (the route is straight here)
    along = {}
    for m in ("improved", "baseline"):
        est = tum(out / f"{m}.tum")
        ref = np.column_stack([np.interp(est[:, 0], gt[:, 0], gt[:, i]) for i in (1, 2)])
        along[m] = abs(np.hypot(*(est[-1, 1:3] - est[0, 1:3])) - np.hypot(*(ref[-1] - ref[0])))
    assert along["improved"] < 0.2, along
    assert along["baseline"] > 5 * along["improved"], along


# ----------------------------------------------------------------------------- contract


def test_estimates_never_read_ground_truth(processed, tmp_path):
    stripped = tmp_path / "stripped.mcap"
    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", stripped,
             drop_topics=("/ground_truth/odom", "/ground_truth/point_labels"), drop_metadata=("fmcwlog.world",))
    out = tmp_path / "out"
    process_log(stripped, out, ProcessOptions())
    ref = processed["corridor_30s"]
    for name in ("improved.tum", "baseline.tum", "wheel_odometry.tum", "improved_map.pgm", "baseline_map.pgm"):
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name
    a = pq.read_table(out / "trajectories.parquet").drop(["ms"])
    b = pq.read_table(ref / "trajectories.parquet").drop(["ms"])
    assert a.equals(b)


def test_outputs_open_in_the_usual_tools(processed):
    from evo.tools import file_interface

    out = processed["corridor_30s"]
    traj = file_interface.read_tum_trajectory_file(str(out / "improved.tum"))
    assert traj.num_poses == 300
    table = pq.read_table(out / "trajectories.parquet").to_pandas()
    assert set(table.method) == {"improved", "baseline"}
    assert {"t", "x", "y", "yaw", "icp_iterations", "correspondences", "moving_points", "ms"} <= set(table.columns)
    assert len(table) == 600
    import yaml

    info = yaml.safe_load((out / "improved_map.yaml").read_text())
    assert info["image"] == "improved_map.pgm" and info["resolution"] == pytest.approx(0.05)
    pgm = (out / "improved_map.pgm").read_bytes()
    assert pgm.startswith(b"P5")
    topics = {c.topic for _, c, _, _ in decoded(out / "processed.mcap")}
    assert {"/improved/odom", "/baseline/odom", "/improved/map", "/improved/points/static",
            "/improved/points/moving", "/wheel_odometry/odom"} <= topics
    run = json.loads((out / "run.json").read_text())
    assert run["doppler"] is True and run["params"]["segmentation"]["v_th"] > 0 and run["fmcwlog_version"]


def test_other_writers_logs_process_like_ours(shared_dir, tmp_path):
    lz4 = shared_dir / "conformance" / "other-writer-lz4.mcap"
    s = process_log(lz4, tmp_path / "lz4", ProcessOptions())
    assert s.sweeps == 200 and s.doppler
    run = json.loads((tmp_path / "lz4" / "run.json").read_text())
    assert run["mount"] == [0.45, 0.05, 0.03]
    gt = ground_truth(lz4)
    assert ate_rmse(tum(tmp_path / "lz4" / "improved.tum"), gt) < 0.05

    cut = shared_dir / "conformance" / "other-writer-cut-off.mcap"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = process_log(cut, tmp_path / "cut", ProcessOptions())
    assert s.sweeps == 80 and s.truncated
    assert any("ends early" in w for w in json.loads((tmp_path / "cut" / "run.json").read_text())["warnings"])


def test_laserscan_with_odometry_prior_runs_without_doppler(tmp_path):
    """A log with a LaserScan (no Doppler) and an Odometry topic as the prior."""
    src = SAMPLE_LOGS / "corridor_30s.mcap"
    dst = tmp_path / "scan.mcap"
    with open(dst, "wb") as out:
        w = Writer(out)
        scan_schema = w.register_msgdef("sensor_msgs/msg/LaserScan", (Path(__file__).parents[1] / "schemas" / "sensor_msgs"
                                                                     / "msg" / "LaserScan.msg").read_text()
                                        + "=" * 80 + "\nMSG: std_msgs/msg/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
                                        + "=" * 80 + "\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n")
        odom_schema = None
        n = 1081
        res = math.radians(0.25)
        for schema, channel, message, msg in decoded(src, ["/fmcw/points", "/ground_truth/odom"]):
            if channel.topic == "/ground_truth/odom":  # stands in for a robot's own odometry here
                if odom_schema is None:
                    odom_schema = w.register_msgdef(schema.name, schema.data.decode())
                w.write_message("/odom", odom_schema, msg, log_time=message.log_time, publish_time=message.log_time)
                continue
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
    s = process_log(dst, out, ProcessOptions(odom_topic="/odom"))
    assert not s.doppler and s.sweeps == 300
    run = json.loads((out / "run.json").read_text())
    assert run["doppler"] is False and any("no Doppler" in w for w in run["warnings"])
    assert run["prior"] == "odometry (/odom)"


# ----------------------------------------------------------------------------- bad input


def _assert_clean_failure(proc, out: Path, *words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("fmcwlog: error:") and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    assert not out.exists()
    assert not list(out.parent.glob(f".{out.name}.partial*"))


def _short(tmp_path: Path, name: str, **kw) -> Path:
    dst = tmp_path / name
    user_edit = kw.pop("edit", None)

    def edit(topic, i, msg):
        if topic == "/fmcw/points" and i >= 20:
            return False
        if topic != "/fmcw/points" and i >= 100:
            return False
        return user_edit(topic, i, msg) if user_edit else None

    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", dst, edit=edit, **kw)
    return dst


def _junk(path: Path) -> Path:
    path.write_bytes(b"not a log at all")
    return path


def _nan_points(topic, i, msg):
    if topic == "/fmcw/points" and i == 5:
        data = bytearray(msg.data)
        data[0:4] = np.float32(np.nan).tobytes()
        msg.data = bytes(data)


def _backwards(topic, i, msg):
    if topic == "/fmcw/points" and i == 7:
        msg.header.stamp.sec -= 1


def _empty(topic, i, msg):
    if topic == "/fmcw/points" and i == 3:
        msg.width, msg.row_step, msg.data = 0, 0, b""


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda p: _junk(p / "junk.mcap"), ["junk.mcap", "not an MCAP"]),
        (lambda p: _short(p, "noscan.mcap", drop_topics=("/fmcw/points",)), ["noscan.mcap", "scan topic"]),
        (lambda p: _short(p, "nocal.mcap", drop_metadata=("fmcwlog.calibration",)), ["nocal.mcap", "calibration"]),
        (lambda p: _short(p, "nan.mcap", edit=_nan_points), ["nan.mcap", "NaN"]),
        (lambda p: _short(p, "back.mcap", edit=_backwards), ["back.mcap", "backwards"]),
        (lambda p: _short(p, "empty.mcap", edit=_empty), ["empty.mcap", "no points"]),
    ],
)
def test_bad_input_is_one_line_and_leaves_nothing(tmp_path, make, words):
    log = make(tmp_path)
    out = tmp_path / "out"
    _assert_clean_failure(run_cli("process", str(log), "-o", str(out)), out, *words)


def test_repeated_sweep_stamp_is_skipped_with_a_warning(tmp_path):
    def repeat(topic, i, msg):
        if topic == "/fmcw/points" and i == 4:
            msg.header.stamp.nanosec -= 100_000_000  # same stamp as sweep 3

    log = _short(tmp_path, "rep.mcap", edit=repeat)
    out = tmp_path / "out"
    s = process_log(log, out, ProcessOptions())
    assert s.skipped_sweeps == 1 and s.sweeps == 19
    assert any("repeated stamp" in w for w in json.loads((out / "run.json").read_text())["warnings"])


def test_non_empty_output_folder_is_refused_without_force(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    log = _short(tmp_path, "s.mcap")
    proc = run_cli("process", str(log), "-o", str(out))
    assert proc.returncode == 2 and "--force" in proc.stderr
    assert (out / "keep.txt").read_text() == "mine"
    proc = run_cli("process", str(log), "-o", str(out), "--force")
    assert proc.returncode == 0, proc.stderr
    assert not (out / "keep.txt").exists() and (out / "improved.tum").exists()


def test_config_file_and_set_reach_nested_stages(tmp_path):
    from fmcwlog.config import parse_set_option, read_config_file
    from fmcwlog.errors import ConfigError
    from fmcwlog.frontend.params import load_frontend_params as load_params

    cfg = tmp_path / "p.toml"
    cfg.write_text("[segmentation]\nv_th = 0.25\n[icp.gmmsc]\nw_th = 0.6\n[frontend]\nvoxel_size = 0.1\n")
    p = load_params(read_config_file(cfg), parse_set_option(("icp.gmmsc.n_components=3", "icp.huber_delta=0.04")))
    assert (p.segmentation.v_th, p.icp.gmmsc.w_th, p.voxel_size) == (0.25, 0.6, 0.1)
    assert (p.icp.gmmsc.n_components, p.icp.huber_delta) == (3, 0.04)
    with pytest.raises(ConfigError, match="icp.gmmsc.nope"):
        load_params(None, parse_set_option(("icp.gmmsc.nope=1",)))
    proc = run_cli("process", "--config", str(cfg), "--show-config")
    assert proc.returncode == 0 and json.loads(proc.stdout)["icp"]["gmmsc"]["w_th"] == 0.6
