"""What ``fmcwlog process`` writes, read back with the field's own tools: evo, pandas, map_server's
YAML, and rosbags (the reader evo and KISS-ICP use) for ``processed.mcap`` and its tf tree."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml


def _rosbags(path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for con, t, raw in reader.messages():
            out.setdefault(con.topic, []).append((t, reader.deserialize(raw, con.msgtype)))
    return out


def _yaw(q) -> float:
    return 2 * math.atan2(q.z, q.w)


@pytest.mark.slow
def test_tum_parquet_and_maps_open_in_evo_pandas_and_map_server(processed):
    from evo.tools import file_interface

    out = processed["corridor_30s"]
    traj = file_interface.read_tum_trajectory_file(str(out / "improved.tum"))
    assert traj.num_poses == 300
    table = pq.read_table(out / "trajectories.parquet")
    df = table.to_pandas()
    assert list(df.groupby("method").size().sort_index().items()) == [("baseline", 300), ("improved", 300),
                                                                     ("wheel_odometry", 300)]
    meta = {k.decode(): v.decode() for k, v in table.schema.metadata.items()}
    for column in df.columns:  # every column says what it is
        assert f"fmcwlog.column.{column}" in meta, column
    assert "rad" in meta["fmcwlog.column.yaw"] and "m/s" in meta["fmcwlog.column.v"]
    wheel = df[df.method == "wheel_odometry"]
    assert wheel.ms.isna().all() and wheel.icp_iterations.isna().all() and wheel.v.notna().all()
    imp = df[df.method == "improved"]
    assert imp.ms.notna().all() and (imp.v.iloc[100:] > 0.5).all()  # cruising at 1 m/s
    info = yaml.safe_load((out / "improved_map.yaml").read_text())
    assert info["image"] == "improved_map.pgm" and info["resolution"] == pytest.approx(0.05)
    assert (out / "improved_map.pgm").read_bytes().startswith(b"P5")
    run = json.loads((out / "run.json").read_text())
    assert run["frames"] == {"improved": "improved/odom", "baseline": "baseline/odom",
                             "wheel_odometry": "wheel_odometry/odom"}


@pytest.mark.slow
def test_processed_mcap_in_rosbags_has_a_tf_tree_per_trajectory_under_map(processed):
    out = processed["corridor_30s"]
    msgs = _rosbags(out / "processed.mcap")
    names = ("improved", "baseline", "wheel_odometry")
    static = msgs["/tf_static"]
    assert len(static) == 1
    links = {(tf.header.frame_id, tf.child_frame_id): tf.transform for tf in static[0][1].transforms}
    assert set(links) == {(f"{m}/base_link", f"{m}/lidar") for m in names} | {("map", f"{m}/odom") for m in names}
    assert links[("improved/base_link", "improved/lidar")].translation.x == pytest.approx(0.35)
    for m in names:  # every estimate starts at map's origin
        tr = links[("map", f"{m}/odom")]
        assert (tr.translation.x, tr.translation.y, tr.rotation.z, tr.rotation.w) == (0.0, 0.0, 0.0, 1.0)
    # every sweep: one /tf message with each trajectory's odom -> base_link, equal to its TUM pose
    tf = msgs["/tf"]
    assert len(tf) == 300 and [t for t, _ in tf] == sorted(t for t, _ in tf)
    for name in names:
        tum = np.loadtxt(out / f"{name}.tum")
        for (t, m), row in zip(tf, tum):
            frames = {(x.header.frame_id, x.child_frame_id): x.transform for x in m.transforms}
            assert set(frames) == {(f"{n}/odom", f"{n}/base_link") for n in names}
            tr = frames[(f"{name}/odom", f"{name}/base_link")]
            assert abs(t * 1e-9 - row[0]) < 1e-6
            assert (tr.translation.x, tr.translation.y) == pytest.approx((row[1], row[2]), abs=2e-6)
    labels = msgs["/improved/moving_labels"]
    assert len(labels) == 300 and {m.header.frame_id for _, m in labels} == {"improved/lidar"}


@pytest.mark.slow
def test_processed_mcap_carries_twist_covariance_paths_maps_and_velocity(processed):
    out = processed["corridor_30s"]
    msgs = _rosbags(out / "processed.mcap")
    odom = [m for _, m in msgs["/improved/odom"]]
    assert all(m.header.frame_id == "improved/odom" and m.child_frame_id == "improved/base_link" for m in odom)
    v = np.array([m.twist.twist.linear.x for m in odom])
    assert np.all(v[100:] > 0.5)  # the Doppler twist: 1 m/s cruise
    cov = np.array([m.pose.covariance for m in odom[20:]]).reshape(-1, 6, 6)
    assert np.all(cov[:, 0, 0] > 0) and np.all(cov[:, 5, 5] > 0)  # x and yaw variances of the registration
    assert np.all(np.abs(cov[:, 0, 1]) <= np.sqrt(cov[:, 0, 0] * cov[:, 1, 1]) + 1e-15)  # a covariance
    tw = np.array([m.twist.covariance for m in odom[5:]]).reshape(-1, 6, 6)
    assert np.all(tw[:, 0, 0] > 0) and np.all(tw[:, 0, 0] < 0.01**2)  # Doppler speed good to under 1 cm/s
    # paths and maps as they grow: every 5 s of log, then the whole at the end
    for name in ("improved", "baseline", "wheel_odometry"):
        paths = msgs[f"/{name}/path"]
        assert len(paths) >= 6 and paths[-1][1].header.frame_id == f"{name}/odom"
        assert len(paths[-1][1].poses) == 300  # the last one is whole
    maps = msgs["/improved/map"]
    assert len(maps) >= 6
    known = [int((m.data >= 0).sum()) for _, m in maps]
    assert known[:-1] == sorted(known[:-1]) and known[-2] > 1.5 * known[0]  # it grows as the robot explores
    # the last map is rebuilt from the back end's optimised nodes: the same floor, drawn again
    assert abs(known[-1] - known[-2]) < 0.05 * known[-2]
    last = maps[-1][1]
    assert last.header.frame_id == "improved/odom" and len(last.data) == last.info.width * last.info.height
    assert set(np.unique(last.data)) <= set(range(-1, 101)) and (last.data == 100).any() | (last.data > 65).any()
    cloud = msgs["/improved/points/static"][50][1]
    assert {f.name for f in cloud.fields} >= {"x", "y", "z", "velocity"} and cloud.header.frame_id == "improved/odom"


@pytest.mark.slow
def test_report_writes_the_ground_truth_and_evo_ape_agrees(processed, tmp_path):
    """The README's command, verbatim: evo_ape tum gt.tum improved.tum -a, on what report wrote."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from fmcwlog.api import report

    out = tmp_path / "out"
    shutil.copytree(processed["corridor_30s"], out)
    ev = report(out)
    gt = np.loadtxt(out / "gt.tum")
    assert gt.shape == (1500, 8)  # 50 Hz over 30 s: the log's /ground_truth/odom
    evo_ape = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    res = subprocess.run([evo_ape, "tum", "gt.tum", "improved.tum", "-a", "--save_results", "ape.zip"],
                         cwd=out, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    rmse = float(next(line.split()[-1] for line in res.stdout.splitlines() if line.strip().startswith("rmse")))
    assert rmse == pytest.approx(ev.result["methods"]["improved"]["ate_rmse_m"], abs=1e-5)


@pytest.mark.slow
def test_a_second_report_does_not_score_its_own_ground_truth(processed, tmp_path):
    import shutil

    from fmcwlog.api import report

    out = tmp_path / "out"
    shutil.copytree(processed["corridor_30s"], out)
    first = report(out).result["methods"]
    second = report(out).result["methods"]  # gt.tum now lies beside the estimates
    assert list(first) == list(second)
    assert set(first) == {"improved", "baseline", "wheel_odometry", "improved_frontend", "baseline_frontend"}


def test_arrow_columns_built_from_buffers_equal_pyarrows_own():
    """The parquet's columns are built from Arrow buffers (to skip pandas' import); pyarrow's own
    ``pa.array`` is the reference, nulls, booleans and non-ASCII text included."""
    import pyarrow as pa

    from fmcwlog.io.outputs import _NUMPY_DTYPE, _arrow_from_numpy, _arrow_strings

    def _arrow_column(values, kind):
        valid = np.array([v is not None for v in values], bool)
        if pa.types.is_string(kind):
            return _arrow_strings(values, valid)
        return _arrow_from_numpy(np.array([0 if v is None else v for v in values], _NUMPY_DTYPE[kind]), valid, kind)

    cases = [([1.5, None, -2.0, float("inf")] * 5, pa.float64()), ([None] * 3, pa.float64()),
             ([3, None, 2**40, -1] * 3, pa.int64()), ([True, None, False, True, True, None, False, True, False], pa.bool_()),
             (["improved", None, "wheel_odometry", "", "fahrtrichtung ä"], pa.string()), ([], pa.int64())]
    for values, kind in cases:
        built = _arrow_column(values, kind)
        built.validate(full=True)
        assert built.equals(pa.array(values, kind)), (kind, built)


def test_maps_are_published_less_often_once_they_outgrow_the_budget(tmp_path):
    """A fixed period repeats the whole map every 5 s: quadratic in a long log. Maps whose size over
    the period exceeds the budget come at size / budget instead; small ones every period still."""
    from types import SimpleNamespace

    from mcap.reader import make_reader

    from fmcwlog.io.outputs import ProcessOutputs

    def map_stamps(cells_side: int) -> np.ndarray:
        grid = SimpleNamespace(width=cells_side, height=cells_side, resolution=0.05, origin=(0.0, 0.0),
                               to_ros_int8=lambda: np.zeros(cells_side * cells_side, np.int8))
        (tmp_path / str(cells_side)).mkdir()
        out = ProcessOutputs(tmp_path / str(cells_side), ("odometry",), np.zeros(3), publish_period=5.0,
                             publish_bytes_per_s=10_000.0)
        for k in range(1200):  # 120 s of sweeps at 10 Hz
            stamp = 10**9 + k * 10**8
            out.add_pose("odometry", stamp, np.array([0.01 * k, 0.0, 0.0]), None)
            out.end_sweep(stamp, {"m": grid})
        out.writer.close()
        with open(tmp_path / str(cells_side) / "processed.mcap", "rb") as fh:
            return np.array([m.log_time for _, c, m in make_reader(fh).iter_messages(topics=["/m/map"])]) * 1e-9

    small = map_stamps(100)  # 10,000 cells: 1 s of budget, under the 5 s period
    assert len(small) == 23 and np.allclose(np.diff(small), 5.0)
    big = map_stamps(300)  # 90,000 cells (+ the path): 9 s of budget or more
    gaps = np.diff(big)
    assert len(big) <= 120 / 9 and np.all(gaps >= 9.0), gaps


def test_tf_carries_the_corrected_poses_and_everything_resolves_to_map(tmp_path):
    """``/tf`` holds each trajectory's poses as they end up: a back end's correction replaces the
    front end's there as in the TUM file; every frame a message names resolves to ``map``."""
    from helpers import replay_frames

    from fmcwlog.io.outputs import ProcessOutputs

    out = ProcessOutputs(tmp_path, ("a", "b"), np.array([0.3, 0.1, 0.2]), publish_period=1.0)
    stamps = [10**9 + k * 10**8 for k in range(30)]
    for k, stamp in enumerate(stamps):
        out.add_pose("a", stamp, np.array([0.1 * k, 0.0, 0.01 * k]), (1.0, 0.1))
        if k >= 5:  # b starts later: its poses join the messages of its stamps
            out.add_pose("b", stamp, np.array([0.0, 0.1 * k, 0.0]), None)
        out.end_sweep(stamp, {})
    corrected = np.column_stack([np.arange(30) * 0.1, np.full(30, 2.0), np.zeros(30)])
    out.correct("a", corrected)
    out.finish({})
    folder = tmp_path / "processed.mcap"
    assert replay_frames.unresolved(folder) == {}
    tree = replay_frames.read_tf(folder)
    for k, stamp in enumerate(stamps):
        assert tree.resolve("a/lidar", stamp) == pytest.approx((0.1 * k + 0.3, 2.0 + 0.1, 0.2))
    assert tree.resolve("b/base_link", stamps[4]).startswith("b/base_link: 'b/odom' -> 'b/base_link' is known from")
    assert tree.resolve("b/base_link", stamps[-1]) == pytest.approx((0.0, 2.9, 0.0))
    tum = np.loadtxt(tmp_path / "a.tum")
    assert np.allclose(tum[:, 1:3], corrected[:, :2])


def test_processed_messages_are_encoded_as_mcap_ros2_encodes_them():
    """``process`` encodes its Odometry, PointCloud2, TFMessage and Path from numbers, skipping the
    message dicts; mcap_ros2's generic encoder of those dicts is the reference, for frame names of every
    length modulo 8, poses in every quadrant, covariances given or not, clouds with and without Doppler."""
    from mcap_ros2._dynamic import serialize_dynamic

    from fmcwlog.io import outputs
    from fmcwlog.io.mcap_log import odometry_cdr, path_cdr, path_cdr_arrays, stamp_pair, tf_cdr, tf_cdr_arrays
    from fmcwlog.io.messages import (
        odometry_message,
        path_message,
        planar_covariance,
        pointcloud_message,
        pose7,
        pose7_array,
        tf_message,
        transform_dict,
    )
    from fmcwlog.io.schemas import message_definition

    def reference(datatype):
        return serialize_dynamic(datatype, message_definition(datatype))[datatype]

    odom, cloud = reference("nav_msgs/msg/Odometry"), reference("sensor_msgs/msg/PointCloud2")
    tf, path = reference("tf2_msgs/msg/TFMessage"), reference("nav_msgs/msg/Path")
    rng = np.random.default_rng(8)
    for n in range(17):
        ns = int(rng.integers(0, 2**31)) * 10**9 + int(rng.integers(0, 10**9))
        frame, child = "ä/odom"[: n % 7] + "o" * (n // 3), "b" * (n % 9)
        pose = np.array([*rng.normal(size=2) * 100, rng.uniform(-np.pi, np.pi)])
        v, w = rng.normal(size=2)
        cov = rng.normal(size=(3, 3)) if n % 2 else None
        tcov = np.diag(rng.uniform(size=3)) if n % 3 else None
        assert odometry_cdr(stamp_pair(ns), frame, child, pose7(pose), planar_covariance(cov),
                            outputs._planar_twist(v, w), planar_covariance(tcov)) == \
            odom(odometry_message(ns, frame, child, pose, np.array([v, 0.0, w]), cov, tcov))
        xy = rng.normal(size=(n * 3, 2)) * 20
        vel = rng.normal(size=n * 3) if n % 2 else None
        cols = {"x": xy[:, 0], "y": xy[:, 1], "z": np.zeros(len(xy)), **({"velocity": vel} if vel is not None else {})}
        assert outputs._cloud(stamp_pair(ns), frame, xy, vel) == cloud(pointcloud_message(ns, frame, cols))
        poses = list(rng.normal(size=(n, 3)) * 10)
        stamps = [ns + k * 10**8 for k in range(n)]
        assert tf_cdr([(stamp_pair(s), frame, child * k, pose7(p)) for k, (s, p) in enumerate(zip(stamps, poses))]) == \
            tf(tf_message([transform_dict(s, frame, child * k, p) for k, (s, p) in enumerate(zip(stamps, poses))]))
        reference_path = path(path_message(ns, frame, stamps, poses))
        assert path_cdr(stamp_pair(ns), frame, [(stamp_pair(s), frame, pose7(p)) for s, p in zip(stamps, poses)]) == \
            reference_path
        # the published paths' poses as process keeps them (numbers): the decimated path's pose7s, and
        # the whole path's (x, y, yaw) made into pose7s at once
        kept = outputs.PathPoses(frame)
        for s, p in zip(stamps, poses):
            kept.append(s, pose7(p))
        assert len(kept) == n
        whole = pose7_array(np.array(poses).reshape(-1, 3))
        assert path_cdr_arrays(stamp_pair(ns), frame, frame, kept.stamps_ns, kept.poses) == \
            path_cdr_arrays(stamp_pair(ns), frame, frame, np.array(stamps, np.int64), whole) == reference_path
        # /tf as process writes it: messages of the same transforms encoded together
        frames = [(frame, child * k) for k in range(n % 4)]
        many = rng.normal(size=(3, len(frames), 3)) * 10
        at = ns + np.arange(3, dtype=np.int64) * 10**8
        assert tf_cdr_arrays(at, frames, pose7_array(many.reshape(-1, 3)).reshape(3, len(frames), 7)) == [
            tf(tf_message([transform_dict(int(s), f[0], f[1], p) for f, p in zip(frames, ps)])) for s, ps in zip(at, many)]


def test_planar_covariance_places_x_y_yaw_in_the_6x6():
    from fmcwlog.io.messages import planar_covariance

    cov3 = np.arange(1.0, 10.0).reshape(3, 3)
    full = np.array(planar_covariance(cov3)).reshape(6, 6)
    assert np.array_equal(full[np.ix_([0, 1, 5], [0, 1, 5])], cov3)
    full[np.ix_([0, 1, 5], [0, 1, 5])] = 0.0
    assert not full.any() and planar_covariance(None) == [0.0] * 36


def test_rows_kept_in_numpy_give_the_columns_pyarrow_builds_from_the_same_values():
    """The parquet's rows are kept column-wise in numpy, not as Python objects; every column (nulls,
    int64 stamps beyond float64's exact range, float64s, booleans) comes out as pyarrow's own
    ``pa.array`` of the values, and a corrected pose replaces only its trajectory's rows."""
    import pyarrow as pa

    from fmcwlog.io.outputs import PARQUET_COLUMNS, TrajectoryRows
    from fmcwlog.kernels.growing import GrowingArray

    rng = np.random.default_rng(4)
    rows, given = TrajectoryRows(), []
    for k in range(3000):  # more than the first capacity: the arrays grow while rows arrive
        method = ("improved", "baseline", "wheel_odometry")[k % 3]
        values = {"method": method, "stamp_ns": 1_700_000_000_123_456_789 + 7 * k, "x": float(rng.normal()),
                  "y": np.float64(rng.normal() * 1e-300), "yaw": -0.0 if k == 5 else rng.normal(), "v": rng.normal()}
        if method != "wheel_odometry":
            values.update(omega=rng.normal(), icp_iterations=int(rng.integers(0, 50)), correspondences=2**40 + k,
                          moving_points=k, keyframe=bool(k % 2), ms=rng.exponential(), x_frontend=values["x"],
                          y_frontend=values["y"], yaw_frontend=values["yaw"])
        rows.add(values)
        given.append(values)
    for name, (kind, _) in PARQUET_COLUMNS.items():
        if name == "t":
            expected = pa.array([v["stamp_ns"] * 1e-9 for v in given], kind)
        else:
            expected = pa.array([v.get(name) for v in given], kind)
        built = rows.arrow(name, kind)
        built.validate(full=True)
        assert built.equals(expected), name
    idx = np.array([i for i, v in enumerate(given) if v["method"] == "baseline"])
    poses = rng.normal(size=(len(idx), 3))
    rows.set_pose(idx, poses)
    x, valid = rows.column("x")
    assert valid.all() and x[idx].tobytes() == poses[:, 0].copy().tobytes()
    assert x[idx[0] - 1] == given[idx[0] - 1]["x"]
    grown = GrowingArray(np.int64)
    for v in given:
        grown.append(v["stamp_ns"])
    assert grown.values.tolist() == [v["stamp_ns"] for v in given]



PARQUET_MEMORY = r"""
import pathlib, sys, tempfile
import numpy as np
from fmcwlog.io.outputs import TrajectoryRows, write_trajectories_parquet
def rss_anon_mb():
    for line in open("/proc/self/status"):
        if line.startswith("RssAnon"):
            return int(line.split()[1]) / 1024
rng = np.random.default_rng(0)
rows = TrajectoryRows()
for k in range(36_000):  # 20 minutes of three trajectories
    rows.add({"method": ("improved", "baseline", "wheel_odometry")[k % 3], "stamp_ns": 10**18 + k * 10**8,
              "x": rng.normal(), "y": rng.normal(), "yaw": rng.normal(), "v": rng.normal(), "omega": rng.normal(),
              "icp_iterations": 5, "correspondences": 1000 + k % 7, "moving_points": k % 11, "keyframe": k % 5 == 0,
              "ms": rng.exponential(), "x_frontend": rng.normal(), "y_frontend": rng.normal(), "yaw_frontend": rng.normal()})
with tempfile.TemporaryDirectory() as d:
    small = TrajectoryRows()
    small.add({"method": "a", "stamp_ns": 1, "x": 0.0})
    write_trajectories_parquet(pathlib.Path(d) / "warm.parquet", small)  # the writer's code paged in
    before = rss_anon_mb()
    write_trajectories_parquet(pathlib.Path(d) / "t.parquet", rows)
    print(before, rss_anon_mb())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc's RssAnon")
def test_writing_the_parquet_leaves_no_arrow_buffers_resident():
    """Arrow's allocator kept ~28 MB of the writer's freed buffers for 36,000 rows (20 minutes of
    three trajectories) until they were given back; the kernel's count (/proc) is the judge."""
    out = subprocess.run([sys.executable, "-c", PARQUET_MEMORY], capture_output=True, text=True, check=True)
    before, after = map(float, out.stdout.split())
    assert after - before < 15, (before, after)


@pytest.mark.slow
def test_the_readmes_evo_traj_command_with_the_map_runs(processed, tmp_path):
    """The README's `evo_traj tum out/improved.tum --ros_map_yaml out/improved_map.yaml -p --plot_mode xy`,
    verbatim (headless): evo reads the map as map_server does. With evo's default 3-D plot mode
    (the command without --plot_mode xy) evo refuses the map and exits 1."""
    import os
    import re
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from helpers import ROOT

    readme = (ROOT / "README.md").read_text()
    command = re.search(r"`(evo_traj tum out/improved\.tum --ros_map_yaml[^`]*)`", readme)[1].split()
    evo_traj = shutil.which("evo_traj") or str(Path(sys.executable).parent / "evo_traj")
    out = tmp_path / "out"
    shutil.copytree(processed["corridor_30s"], out)
    res = subprocess.run([evo_traj, *command[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "MPLBACKEND": "Agg"})
    assert res.returncode == 0 and "[ERROR]" not in res.stdout + res.stderr, res.stdout + res.stderr
