"""`fmcwlog report` on hand-made output folders with known answers, and on a real one.

The hand-made folders hold trajectories derived from the sample log's ground
truth by a known transform (offset, rotation, scale drift) and maps made of the
log's static points placed with those poses, so the expected errors are known
without running any front end. (A distortion of the map that feature lengths
must show is tested in test_features.py, on maps of known geometry.)
"""

from __future__ import annotations

import dataclasses
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
from helpers import SAMPLE_LOGS

from fmcwlog.evaluation.evaluate import evaluate
from fmcwlog.evaluation.ground_truth import read_ground_truth
from fmcwlog.evaluation.pages import write_report
from fmcwlog.geometry import compose, interpolate_poses, inverse, transform_points
from fmcwlog.io.mcap_log import LogReader, LogWriter
from fmcwlog.io.messages import odometry_message, pointcloud_columns, pointcloud_message
from fmcwlog.io.outputs import write_grid, write_tum
from fmcwlog.kernels.occupancy import OccupancyGrid

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


@pytest.mark.slow
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


@pytest.mark.slow
def test_unaligned_offset_is_the_offset(folders):
    from fmcwlog.evaluation.metrics import ate
    from fmcwlog.io.outputs import read_tum

    t, est = read_tum(folders["offset"] / "improved.tum")
    gt_ns, gt = read_ground_truth(LogReader(LOG))
    ref = interpolate_poses(t, gt_ns * 1e-9, gt)
    assert ate(est, ref, "none").rmse == pytest.approx(math.hypot(3.0, 2.0), abs=1e-4)


@pytest.mark.slow
def test_scale_drift_shows_in_rpe(folders):
    r = evaluate(folders["scaled"]).result["methods"]["improved"]
    assert r["rpe_1m_pct"] == pytest.approx(2.0, abs=0.05)  # every step 2 % too long
    assert r["rpe_10m_pct"] == pytest.approx(2.0, abs=0.05)
    assert r["ate_rmse_m"] > 0.01


@pytest.mark.slow
def test_pages_hold_every_table_and_image(folders, tmp_path):
    folder = tmp_path / "pages"
    shutil.copytree(folders["scaled"], folder)
    ev = evaluate(folder)
    write_report(ev)
    html = (folder / "report.html").read_text()
    for heading in ("Trajectory, segmentation, speed", "Map feature lengths", "Maps", "Notes", "Parameters",
                    "Position error along the path", "Relative pose error against distance travelled",
                    "Heading error", "Time per sweep"):
        assert heading in html
    # trajectory, evo_ape's statistics, time per sweep, features (the header has its own class)
    assert html.count("<table>") == 4
    alts = ["trajectories over the world", "position error along the path", "relative error of each feature",
            "x, y and yaw over time, with ground truth", "distribution of the position error",
            "relative pose error of each pair against distance travelled", "heading error over time",
            "time per sweep of each method"]
    alts += [f"{m} trajectory coloured by its position error" for m in ("improved", "baseline", "wheel odometry")]
    for alt in alts:
        assert f'alt="{alt}' in html
    assert html.count('src="data:image/png;base64,') == html.count("<img ") >= len(alts)
    # self-contained: nothing fetched, no script
    assert "http://" not in html and "https://" not in html and "<script" not in html and "<link" not in html
    md = (folder / "report.md").read_text()
    assert "| method | ATE RMSE cm" in md and "| feature | name | true mm" in md
    data = json.loads((folder / "report.json").read_text())
    for m in ("improved", "baseline", "wheel_odometry"):
        for key in ("ate_rmse_m", "ate_std_m", "ate_min_m", "rpe_1m_pct", "rpe_10m_pct", "features", "feature_avg_rel_error_pct",
                    "segmentation", "ms_per_sweep_median", "notes", "heading_rmse_deg", "heading_max_deg",
                    "ms_per_sweep_max"):
            assert key in data["methods"][m]
    assert data["methods"]["wheel_odometry"]["features"] is None and data["methods"]["wheel_odometry"]["notes"]
    # the report's own gt.tum is not read back as a trajectory the next time
    assert (folder / "gt.tum").is_file() and set(evaluate(folder).result["methods"]) == set(data["methods"])


def _mcap_metadata(path: Path, name: str) -> dict[str, str]:
    """A metadata record read with plain ``mcap``, not fmcwlog's reader."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return next(dict(m.metadata) for m in make_reader(f).iter_metadata() if m.name == name)


@pytest.mark.slow
def test_header_says_what_was_run(folders, tmp_path):
    import datetime
    import hashlib

    import fmcwlog
    from fmcwlog.pipeline.params import ProcessParams

    folder = tmp_path / "header"
    shutil.copytree(folders["exact"], folder)
    run = json.loads((folder / "run.json").read_text())
    params = dataclasses.asdict(ProcessParams())
    run.update(params=dict(reversed(list(params.items()))), fmcwlog_version="9.9.9", methods=["improved", "baseline"])
    (folder / "run.json").write_text(json.dumps(run, indent=3))  # key order and layout must not matter
    ev = evaluate(folder)
    write_report(ev)
    h = json.loads((folder / "report.json").read_text())["header"]
    canonical = json.dumps(json.loads((folder / "run.json").read_text())["params"], sort_keys=True,
                           separators=(",", ":"))
    assert h["params_sha256_12"] == hashlib.sha256(canonical.encode()).hexdigest()[:12]
    assert len(h["params_sha256_12"]) == 12 and all(c in "0123456789abcdef" for c in h["params_sha256_12"])
    sim = _mcap_metadata(LOG, "fmcwlog.sim")
    assert h["scenario"] == sim["scenario"] == "corridor" and h["seed"] == int(sim["seed"])
    assert h["fmcwlog_version_processed"] == "9.9.9" and h["fmcwlog_version_report"] == fmcwlog.__version__
    assert h["log"] == str(LOG) and h["methods"] == ["improved", "baseline"]
    made = datetime.datetime.strptime(h["report_date_utc"], "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=datetime.UTC)
    assert abs((datetime.datetime.now(datetime.UTC) - made).total_seconds()) < 600
    html = (folder / "report.html").read_text()
    for text in (h["params_sha256_12"], "9.9.9", h["report_date_utc"], str(LOG), "corridor"):
        assert text in html
    # another parameter, another digest
    run["params"]["icp"]["huber_delta"] += 0.01
    (folder / "run.json").write_text(json.dumps(run))
    assert evaluate(folder).result["header"]["params_sha256_12"] != h["params_sha256_12"]


@pytest.mark.slow
def test_time_per_sweep_is_a_distribution(folders, tmp_path):
    folder = tmp_path / "speed"
    shutil.copytree(folders["exact"], folder)
    table = pq.read_table(folder / "trajectories.parquet")
    n = table.num_rows // 2
    ms = np.concatenate([np.arange(1.0, n + 1), np.full(n, 3.0)])  # improved: 1, 2, ..., n ms; baseline: 3 ms
    pq.write_table(table.set_column(2, "ms", pa.array(ms)), folder / "trajectories.parquet")
    ev = evaluate(folder)
    imp = ev.result["methods"]["improved"]
    assert imp["ms_per_sweep_max"] == n and imp["ms_per_sweep_mean"] == pytest.approx((n + 1) / 2)
    assert imp["ms_per_sweep_median"] == pytest.approx((n + 1) / 2)
    assert imp["ms_per_sweep_p95"] == pytest.approx(1 + 0.95 * (n - 1))  # numpy's linear percentile
    assert ev.result["methods"]["baseline"]["ms_per_sweep_max"] == 3.0
    write_report(ev)
    html = (folder / "report.html").read_text()
    assert 'alt="time per sweep of each method' in html and f"<td>{n:.2f}</td>" in html  # the max, in the table


def _l_path(step: float = 0.125, leg: float = 40.0) -> np.ndarray:
    """East ``leg`` m then north ``leg`` m in steps of ``step`` (exact in binary), yaw along the path."""
    k = int(round(leg / step))
    east = np.column_stack([np.arange(k + 1) * step, np.zeros(k + 1), np.zeros(k + 1)])
    north = np.column_stack([np.full(k, leg), np.arange(1, k + 1) * step, np.full(k, math.pi / 2)])
    return np.vstack([east, north])


@pytest.mark.parametrize("delta", [1.0, 10.0])
def test_rpe_per_pair_of_a_constant_scale_error(delta):
    from fmcwlog.evaluation.along_path import rpe_series

    ref = _l_path()
    est = ref * np.array([1.02, 1.02, 1.0])  # every displacement 2 % too long
    s = rpe_series(est, ref, delta)
    assert s.start_m == pytest.approx(np.arange(len(s.start_m)) * delta)  # pair k starts k * delta along the path
    straight = (s.start_m + delta <= 40.0) | (s.start_m >= 40.0)  # not across the corner
    assert straight.sum() >= len(s.start_m) - 1
    assert s.trans_pct[straight] == pytest.approx(2.0, abs=1e-9)
    assert np.all(s.trans_pct[~straight] < 2.0)  # across the corner the chord is shorter than the path
    assert s.rot_deg_per_m == pytest.approx(0.0, abs=1e-9)


@pytest.mark.slow
def test_rpe_per_pair_agrees_with_evo_and_with_the_table(folders):
    from evo.core import metrics as evo_metrics
    from evo.core.trajectory import PoseTrajectory3D

    from fmcwlog.evaluation.metrics import interpolate_reference
    from fmcwlog.geometry import yaw_to_quaternion
    from fmcwlog.io.outputs import read_tum

    ev = evaluate(folders["scaled"])
    t, est = read_tum(folders["scaled"] / "improved.tum")
    gt_ns, gt = read_ground_truth(LogReader(LOG))
    idx, ref = interpolate_reference(t, gt_ns * 1e-9, gt)

    def traj(p):
        q = yaw_to_quaternion(p[:, 2])[:, [3, 0, 1, 2]]  # evo: w x y z
        return PoseTrajectory3D(np.column_stack([p[:, :2], np.zeros(len(p))]), q, t[idx])

    for s in ev.rpe["improved"]:
        r = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta=s.delta,
                            delta_unit=evo_metrics.Unit.meters, all_pairs=False, pairs_from_reference=True)
        r.process_data((traj(ref), traj(est[idx])))
        assert s.trans_pct == pytest.approx(100.0 * np.asarray(r.error) / s.delta, abs=1e-6)
        assert ev.result["methods"]["improved"][f"rpe_{s.delta:g}m_pct"] == pytest.approx(np.mean(s.trans_pct))
        assert np.all(np.diff(s.start_m) >= s.delta - 1e-9) and s.start_m[0] == 0.0


@pytest.mark.slow
def test_heading_error_is_the_yaw_bias(folders, tmp_path):
    from fmcwlog.io.outputs import read_tum

    folder = tmp_path / "yaw"
    shutil.copytree(folders["rotated"], folder)
    t, est = read_tum(folder / "baseline.tum")
    write_tum(folder / "baseline.tum", np.round(t * 1e9).astype(np.int64), est + np.array([0.0, 0.0, math.radians(2.0)]))
    ev = evaluate(folder)
    imp, base = ev.result["methods"]["improved"], ev.result["methods"]["baseline"]
    assert imp["heading_max_deg"] < 1e-4  # a rigid motion of the truth: no heading error once aligned
    # positions alone fix the alignment, so a pure yaw bias stays whole
    assert base["heading_rmse_deg"] == pytest.approx(2.0, abs=1e-4) and base["heading_max_deg"] == pytest.approx(2.0, abs=1e-4)
    assert ev.heading["baseline"] == pytest.approx(2.0, abs=1e-4)


def test_disagreement_with_itself_a_rigid_copy_and_a_scaled_copy():
    from fmcwlog.evaluation.along_path import disagreement

    t = np.arange(len(_l_path())) * 0.1
    ref = _l_path()
    assert disagreement(t, ref, t, ref).stats.max < 1e-12
    moved = compose(np.array([5.0, -3.0, 1.1]), ref)  # another frame: a rigid motion of the whole path
    assert disagreement(t, ref, t, moved).stats.max < 1e-9
    # stamps in between the reference's (a peer's own clock), on a straight stretch at constant speed
    half = t[:300] + 0.05
    assert disagreement(t, ref, half, compose(np.array([1.0, 2.0, 0.3]), ref[:300] + [0.0625, 0.0, 0.0])).stats.max < 1e-9
    # a scaled straight path, once rigidly aligned, is |s - 1| times the distance from the middle away
    line = ref[:321]  # 40 m east
    d = disagreement(t[:321], line, t[:321], line * np.array([1.02, 1.02, 1.0]))
    assert d.along_m == pytest.approx(line[:, 0])
    assert d.gap_m == pytest.approx(0.02 * np.abs(d.along_m - d.along_m.mean()), abs=1e-9)
    slope = np.polyfit(d.along_m[d.along_m > 20.0], d.gap_m[d.along_m > 20.0], 1)[0]
    assert slope == pytest.approx(0.02, abs=1e-9) and d.stats.max == pytest.approx(0.02 * 20.0)


@pytest.mark.slow
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
        for stat in ("rmse", "mean", "median", "std", "min", "max"):  # evo_ape's set, every one on the page
            assert result["methods"][m][f"ate_{stat}_m"] == pytest.approx(
                ape.get_statistic(evo_metrics.StatisticsType(stat)), abs=1e-6), (m, stat)
        # a note under a method does not open with its name again (the page prefixes it)
        assert not any(n.startswith((m, m.replace("_", " "))) for n in result["methods"][m]["notes"]), m


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_not_a_process_folder_or_a_foreign_log_is_one_line(tmp_path, folders, crowd_log):
    (tmp_path / "empty").mkdir()
    for args, words in (((str(tmp_path / "empty"),), "not a 'fmcwlog process' output"),
                        ((str(folders["exact"]), "--log", str(crowd_log)), "does not belong")):
        proc = _cli("report", *args)
        lines = [x for x in proc.stderr.splitlines() if x.strip()]
        assert proc.returncode == 2 and len(lines) == 1 and words in lines[0], proc.stderr


@pytest.mark.slow
def test_missing_ground_truth_is_said_not_invented(tmp_path, folders):
    from test_process import copy_log

    from fmcwlog.io.outputs import read_tum

    stripped = tmp_path / "stripped.mcap"
    copy_log(LOG, stripped, drop_topics=("/ground_truth/odom", "/ground_truth/point_labels"),
             drop_metadata=("fmcwlog.world", "fmcwlog.sim"))
    folder = tmp_path / "nogt"
    shutil.copytree(folders["exact"], folder)
    t, imp = read_tum(folder / "improved.tum")
    ns = np.round(t * 1e9).astype(np.int64)
    write_tum(folder / "baseline.tum", ns, imp * np.array([1.02, 1.02, 1.0]))  # a 2 % scale error
    write_tum(folder / "wheel_odometry.tum", ns, compose(np.array([2.0, 1.0, 0.4]), imp))  # another frame
    ev = evaluate(folder, stripped)
    r = ev.result
    assert r["methods"]["improved"]["ate_rmse_m"] is None and r["methods"]["improved"]["features"] is None
    assert r["methods"]["improved"]["segmentation"] is None and r["methods"]["improved"]["heading_rmse_deg"] is None
    assert any("ground_truth/odom" in n for n in r["notes"])
    assert r["methods"]["improved"]["ms_per_sweep_median"] == pytest.approx(2.0)
    assert r["header"]["scenario"] is None and r["header"]["seed"] is None
    # the methods still compared: a scaled copy is 2 % of its distance from the centroid away, a rigid one not at all
    d = r["disagreement"]
    assert d["reference"] == "improved" and set(d["methods"]) == {"baseline", "wheel_odometry"}
    expected = 0.02 * np.linalg.norm(imp[:, :2] - imp[:, :2].mean(axis=0), axis=1)
    assert d["methods"]["baseline"]["rmse_m"] == pytest.approx(np.sqrt(np.mean(expected**2)), rel=1e-6)  # TUM keeps ~9 digits
    assert d["methods"]["baseline"]["max_m"] == pytest.approx(expected.max(), rel=1e-6)
    assert d["methods"]["baseline"]["final_m"] == pytest.approx(expected[-1], rel=1e-6)
    assert d["methods"]["wheel_odometry"]["max_m"] < 1e-6
    write_report(ev)
    html = (folder / "report.html").read_text()
    assert "How far the methods disagree" in html and "not an error" in html
    for alt in ("disagreement between the methods along the path", "trajectories aligned onto the reference one",
                "time per sweep of each method"):
        assert f'alt="{alt}' in html
    assert "ATE RMSE cm" not in html  # no column of dashes: the notes say why
    assert "— (not in the log)" in html


@pytest.mark.slow
def test_run_does_record_process_report_into_one_folder(tmp_path):
    out = tmp_path / "demo"
    proc = _cli("run", "-o", str(out), "--duration", "8")
    assert proc.returncode == 0, proc.stderr
    assert (out / "log.mcap").is_file() and (out / "results" / "improved.tum").is_file()
    page = out / "results" / "report.html"
    assert page.is_file() and str(page.resolve()) in proc.stdout
    data = json.loads((out / "results" / "report.json").read_text())
    assert data["methods"]["improved"]["ate_rmse_m"] is not None


def test_the_methods_feature_errors_are_compared_over_the_features_both_measure():
    """Each method's own average covers the features its map shows; the comparison (and the page's
    sentence) must use only those both maps show, and say "increase" when the improved method is worse."""
    from fmcwlog.evaluation.evaluate import _comparison
    from fmcwlog.evaluation.pages import _summary_line

    def feats(errors):
        return [{"id": i + 1, "rel_error_pct": e} for i, e in enumerate(errors)]

    methods = {"baseline": {"features": feats([1.3, None, None, 9.0]), "feature_avg_rel_error_pct": 5.15},
               "improved": {"features": feats([1.4, 3.0, 9.0, 6.0]), "feature_avg_rel_error_pct": 4.85}}
    cmp = _comparison(methods)
    assert cmp["features"] == 2
    assert cmp["baseline_avg_rel_error_pct"] == pytest.approx((1.3 + 9.0) / 2)
    assert cmp["improved_avg_rel_error_pct"] == pytest.approx((1.4 + 6.0) / 2)
    assert cmp["reduction_pct"] == pytest.approx(100 * (5.15 - 3.7) / 5.15)
    line = _summary_line({"feature_comparison": cmp})
    assert "2 features both maps measure" in line and "baseline 5.15 %, improved 3.70 %" in line and "reduction" in line
    worse = _comparison({"baseline": {"features": feats([1.3, None])}, "improved": {"features": feats([1.4, 8.0])}})
    assert worse["features"] == 1 and "a 7.7 % increase" in _summary_line({"feature_comparison": worse})
    assert _comparison({"baseline": {"features": feats([None])}, "improved": {"features": feats([2.0])}}) is None


@pytest.mark.slow
def test_each_trajectory_of_a_default_run_has_its_own_colour_and_a_readable_label(processed):
    """The five trajectories a default run writes share the report's legends: two lines of one
    colour cannot be told apart (improved_frontend and baseline_frontend once hashed to the same one)."""
    from matplotlib.colors import to_rgb

    from fmcwlog.evaluation.evaluate import _trajectories_in
    from fmcwlog.evaluation.plots import color, label

    folder = processed["corridor_30s"]
    names = [p.stem for p in folder.glob("*.tum") if p.name != "gt.tum"]
    assert {"improved_frontend", "baseline_frontend", "improved", "baseline", "wheel_odometry"} <= set(names)
    rgb = {m: np.array(to_rgb(color(m))) for m in [*names, "truth"]}
    for a in rgb:
        for b in rgb:
            if a < b:  # well apart in RGB (0-1 per channel), not merely different hex strings
                assert np.linalg.norm(rgb[a] - rgb[b]) > 0.2, (a, b, color(a), color(b))
    labels = [label(m) for m in names]
    assert len(set(labels)) == len(labels) and not any("_" in s for s in labels)
    # each method's front end alone follows the trajectories it belongs with, in the methods' order
    assert _trajectories_in(folder)[-2:] == ["improved_frontend", "baseline_frontend"]
