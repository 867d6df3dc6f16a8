"""`fmcwlog report` on hand-made output folders with known answers, and on a real one.

The hand-made folders hold trajectories derived from the sample log's ground
truth by a known transform (offset, rotation, scale drift) and maps made of the
log's static points placed with those poses, so the expected errors are known
without running any front end. (A distortion of the map that feature lengths
must show is tested in test_features.py, on maps of known geometry.)
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import SAMPLE_LOGS

from fmcwlog.evaluation.evaluate import evaluate
from fmcwlog.evaluation.ground_truth import read_ground_truth
from fmcwlog.evaluation.pages import write_report
from fmcwlog.frontend.occupancy import OccupancyGrid
from fmcwlog.geometry import compose, interpolate_poses, inverse, transform_points
from fmcwlog.io.mcap_log import LogReader, LogWriter
from fmcwlog.io.messages import odometry_message, pointcloud_columns, pointcloud_message
from fmcwlog.io.outputs import write_grid, write_tum

LOG = SAMPLE_LOGS / "corridor_30s.mcap"
TRUE_LENGTHS = [2.344, 6.775, 6.686, 1.064, 8.094, 1.029, 7.901, 26.681, 25.534]


def _sweeps_in_world(log: Path):
    """Per sweep: stamp, GT pose at the stamp, its static points in base_link at the stamp (each point
    moved from the pose of its own beam's time: deskewed with the truth) and the lidar's mount."""
    reader = LogReader(log)
    cal = reader.metadata["fmcwlog.calibration"]
    mount = np.array([float(cal["lidar_x"]), float(cal["lidar_y"]), float(cal["lidar_yaw"])])
    gt_ns, gt = read_ground_truth(reader)
    labels = {m.log_time_ns: np.frombuffer(bytes(m.msg.moving), np.uint8) for m in reader.messages(["/ground_truth/point_labels"])}
    for m in reader.messages(["/fmcw/points"]):
        cols = pointcloud_columns(m.msg, ("x", "y", "t"))
        static = labels[m.log_time_ns] == 0
        xy = np.column_stack([cols["x"], cols["y"]])[static]
        pose = interpolate_poses(np.array(m.log_time_ns * 1e-9), gt_ns * 1e-9, gt)
        beam = interpolate_poses(m.log_time_ns * 1e-9 + cols["t"][static], gt_ns * 1e-9, gt)
        sensor = compose(compose(inverse(pose), beam), mount)  # (N, 3): the lidar at each beam, in base_link
        c, s = np.cos(sensor[:, 2]), np.sin(sensor[:, 2])
        base_xy = sensor[:, :2] + np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]])
        yield m.log_time_ns, pose, base_xy, mount


def make_folder(folder: Path, distort) -> Path:
    """``distort(pose, t)`` gives the 'estimated' pose from the true one at t seconds into the log."""
    # A process-like output folder whose 'improved' and 'baseline' poses are the distorted true ones,
    # whose static points are placed with those poses, and whose occupancy maps are built from them
    # as the front ends build theirs (fmcwlog's grid, a scan every 0.5 m).
    folder.mkdir(parents=True)
    stamps, poses = [], []
    grid, last = OccupancyGrid(), None
    with LogWriter(folder / "processed.mcap") as w:
        t0 = None
        for ns, pose, base_xy, mount in _sweeps_in_world(LOG):
            t0 = ns if t0 is None else t0
            est = distort(pose, (ns - t0) * 1e-9)
            stamps.append(ns)
            poses.append(est)
            pts = transform_points(est, base_xy)
            if last is None or np.hypot(*(est[:2] - last[:2])) >= 0.5:
                grid.integrate(compose(est, mount)[:2], pts)
                last = est
            for m in ("improved", "baseline"):
                w.write(f"/{m}/odom", "nav_msgs/msg/Odometry", odometry_message(ns, "map", "base_link", est, np.zeros(3)), ns)
                w.write(f"/{m}/points/static", "sensor_msgs/msg/PointCloud2",
                        pointcloud_message(ns, "map", {"x": pts[:, 0], "y": pts[:, 1], "z": np.zeros(len(pts))}), ns)
    stamps, poses = np.array(stamps), np.array(poses)
    for m in ("improved", "baseline", "wheel_odometry"):
        write_tum(folder / f"{m}.tum", stamps, poses)
    for m in ("improved", "baseline"):
        write_grid(folder, f"{m}_map", grid)
    n = len(stamps)
    pq.write_table(pa.table({"method": ["improved"] * n + ["baseline"] * n, "stamp_ns": np.tile(stamps, 2),
                             "ms": np.full(2 * n, 2.0)}), folder / "trajectories.parquet")
    (folder / "run.json").write_text(json.dumps({"log": str(LOG), "sweeps": n, "scan_topic": "/fmcw/points",
                                                 "prior": "test", "doppler": True, "params": {}}))
    return folder


def _offset(p, t):
    return compose(np.array([3.0, -2.0, 0.0]), p)


def _rotated(p, t):
    return compose(np.array([1.0, 4.0, 0.7]), p)


def _scaled(p, t):
    return np.array([1.02 * p[0], 1.02 * p[1], p[2]])


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    return {name: make_folder(root / name, f) for name, f in
            (("exact", lambda p, t: p), ("offset", _offset), ("rotated", _rotated), ("scaled", _scaled))}


@pytest.mark.parametrize("name", ["exact", "offset", "rotated"])
def test_rigid_transforms_of_the_truth_have_no_aligned_error(folders, name):
    r = evaluate(folders[name]).result["methods"]["improved"]
    assert r["ate_rmse_m"] < 1e-5 and r["ate_first_aligned_rmse_m"] < 1e-5
    assert r["rpe_1m_pct"] < 1e-3 and r["rpe_10m_pct"] < 1e-3
    # a rigid motion of the map changes no length: measured in the map, to the map's cells
    assert [f["true_m"] for f in r["features"]] == pytest.approx(TRUE_LENGTHS, abs=1e-9)
    seen = [f for f in r["features"] if f["measured_m"] is not None]
    assert {f["id"] for f in seen} >= {4, 5, 6}  # 30 s: the south corridor's openings and the hall's SE corner
    # measured: at most 2 cm in place, 7 cm turned by 0.7 rad (its walls fall on other cells; one jamb is sparse)
    assert all(f["measurable"] and f["abs_error_m"] < 0.15 for f in seen)
    assert r["feature_avg_rel_error_pct"] == pytest.approx(np.mean([f["rel_error_pct"] for f in seen]))
    unseen = [f for f in r["features"] if f["measured_m"] is None]
    assert unseen and all(f["reason"] and f["abs_error_m"] is None for f in unseen)
    assert any("not measurable in this method's map" in n for n in r["notes"])


def test_unaligned_offset_is_the_offset(folders):
    from fmcwlog.evaluation.metrics import ate
    from fmcwlog.io.outputs import read_tum

    t, est = read_tum(folders["offset"] / "improved.tum")
    gt_ns, gt = read_ground_truth(LogReader(LOG))
    ref = interpolate_poses(t, gt_ns * 1e-9, gt)
    assert ate(est, ref, "none").rmse == pytest.approx(math.hypot(3.0, 2.0), abs=1e-4)


def test_scale_drift_shows_in_rpe(folders):
    r = evaluate(folders["scaled"]).result["methods"]["improved"]
    assert r["rpe_1m_pct"] == pytest.approx(2.0, abs=0.05)  # every step 2 % too long
    assert r["rpe_10m_pct"] == pytest.approx(2.0, abs=0.05)
    assert r["ate_rmse_m"] > 0.01


def test_pages_hold_every_table_and_image(folders, tmp_path):
    folder = tmp_path / "pages"
    shutil.copytree(folders["scaled"], folder)
    ev = evaluate(folder)
    write_report(ev)
    html = (folder / "report.html").read_text()
    for heading in ("Trajectory, segmentation, speed", "Map feature lengths", "Maps", "Notes", "Parameters"):
        assert heading in html
    assert html.count("<table>") == 2
    for alt in ("trajectories over the world", "position error along the path", "relative error of each feature"):
        assert f'alt="{alt}' in html
    assert html.count("data:image/png;base64,") >= 3
    assert "http://" not in html and "https://" not in html  # self-contained
    md = (folder / "report.md").read_text()
    assert "| method | ATE RMSE cm" in md and "| feature | name | true mm" in md
    data = json.loads((folder / "report.json").read_text())
    for m in ("improved", "baseline", "wheel_odometry"):
        for key in ("ate_rmse_m", "rpe_1m_pct", "rpe_10m_pct", "features", "feature_avg_rel_error_pct",
                    "segmentation", "ms_per_sweep_median", "notes"):
            assert key in data["methods"][m]
    assert data["methods"]["wheel_odometry"]["features"] is None and data["methods"]["wheel_odometry"]["notes"]


def test_report_agrees_with_evo_on_a_processed_log(tmp_path):
    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.tools import file_interface

    from fmcwlog.api import ProcessOptions
    from fmcwlog.api import process as process_log

    out = tmp_path / "out"
    process_log(LOG, out, ProcessOptions())
    result = evaluate(out).result
    gt_ns, gt = read_ground_truth(LogReader(LOG))
    write_tum(tmp_path / "gt.tum", gt_ns, gt)
    ref = file_interface.read_tum_trajectory_file(str(tmp_path / "gt.tum"))
    for m in ("improved", "baseline", "wheel_odometry"):
        est = file_interface.read_tum_trajectory_file(str(out / f"{m}.tum"))
        r, e = sync.associate_trajectories(ref, est, max_diff=0.001)
        e.align(r, correct_scale=False)
        ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
        ape.process_data((r, e))
        assert result["methods"][m]["ate_rmse_m"] == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), abs=1e-6)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=600)


def test_not_a_process_folder_or_a_foreign_log_is_one_line(tmp_path, folders, crowd_log):
    (tmp_path / "empty").mkdir()
    for args, words in (((str(tmp_path / "empty"),), "not a 'fmcwlog process' output"),
                        ((str(folders["exact"]), "--log", str(crowd_log)), "does not belong")):
        proc = _cli("report", *args)
        lines = [x for x in proc.stderr.splitlines() if x.strip()]
        assert proc.returncode == 2 and len(lines) == 1 and words in lines[0], proc.stderr


def test_missing_ground_truth_is_said_not_invented(tmp_path, folders):
    from test_process import copy_log

    stripped = tmp_path / "stripped.mcap"
    copy_log(LOG, stripped, drop_topics=("/ground_truth/odom", "/ground_truth/point_labels"),
             drop_metadata=("fmcwlog.world",))
    ev = evaluate(folders["exact"], stripped)
    r = ev.result
    assert r["methods"]["improved"]["ate_rmse_m"] is None and r["methods"]["improved"]["features"] is None
    assert r["methods"]["improved"]["segmentation"] is None
    assert any("ground_truth/odom" in n for n in r["notes"])
    assert r["methods"]["improved"]["ms_per_sweep_median"] == pytest.approx(2.0)


def test_run_does_record_process_report_into_one_folder(tmp_path):
    out = tmp_path / "demo"
    proc = _cli("run", "-o", str(out), "--duration", "8")
    assert proc.returncode == 0, proc.stderr
    assert (out / "log.mcap").is_file() and (out / "results" / "improved.tum").is_file()
    page = out / "results" / "report.html"
    assert page.is_file() and str(page.resolve()) in proc.stdout
    data = json.loads((out / "results" / "report.json").read_text())
    assert data["methods"]["improved"]["ate_rmse_m"] is not None
