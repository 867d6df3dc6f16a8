"""``processed.mcap`` as fmcwlog writes it (its own CDR encoders, paths and ``/tf`` encoded in bulk),
read back with mcap's reader and mcap_ros2's decoder: every field is the number it was written from,
for point clouds of 0, 1 and many points, paths of 0, 1 and many poses, and ``/tf`` messages of one
and of several trajectories."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from fmcwlog.io.outputs import ProcessOutputs
from fmcwlog.types import SweepResult

T0 = 1_700_000_000_123_456_789  # ns


def _result(rng, method: str, i: int, static: int, moving: int, doppler: bool) -> SweepResult:
    pose = np.array([0.3 * i + rng.normal(), rng.normal(), rng.uniform(-math.pi, math.pi)])
    vel = (lambda n: rng.normal(size=n)) if doppler else (lambda n: None)
    return SweepResult(
        method=method, stamp_ns=T0 + i * 100_000_000 + (7 if method == "b" and i == 8 else 0), pose=pose,
        twist=(float(rng.normal()), float(rng.normal())),
        twist_covariance=np.diag(rng.uniform(size=2)) if doppler else None,
        pose_covariance=np.diag(rng.uniform(size=3)) if i else None,
        iterations=i, correspondences=static, moving_points=moving, ms=0.5,
        static_map_xy=rng.normal(size=(static, 2)) * 30, static_velocity=vel(static),
        moving_map_xy=rng.normal(size=(moving, 2)) * 30, moving_velocity=vel(moving),
        moving_mask=rng.random(static + moving) < 0.2, segmented=doppler, keyframe=i % 3 == 0)


def _decoded(path):
    """topic -> [(log_time, decoded message)], by mcap's reader and mcap_ros2's decoder."""
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        for _, channel, message, decoded in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, decoded))
    return out


def _cloud_columns(msg) -> dict[str, np.ndarray]:
    assert not msg.is_bigendian and msg.height == 1 and msg.row_step == msg.width * msg.point_step
    data = bytes(msg.data)
    assert len(data) == msg.width * msg.point_step
    assert all(f.datatype == 7 and f.count == 1 for f in msg.fields)  # FLOAT32
    if msg.width == 0:
        return {f.name: np.zeros(0, "<f4") for f in msg.fields}
    return {f.name: np.ndarray((msg.width,), "<f4", data, f.offset, (msg.point_step,)) for f in msg.fields}


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _planar(pose) -> tuple[float, float, float]:
    p, q = pose.position, pose.orientation
    assert p.z == 0.0 and q.x == 0.0 and q.y == 0.0
    return p.x, p.y, math.remainder(2 * math.atan2(q.z, q.w), 2 * math.pi)


def _wrapped(poses: np.ndarray) -> np.ndarray:
    """(x, y, yaw) with yaw in [-pi, pi], as _planar reads it."""
    poses = np.array(poses, float)
    poses[..., 2] = np.remainder(poses[..., 2] + math.pi, 2 * math.pi) - math.pi
    return poses


@pytest.mark.parametrize("sizes", [(0, 0), (1, 1), (1, 0), (1500, 40)])
def test_processed_log_decodes_to_the_numbers_written(tmp_path, sizes):
    rng = np.random.default_rng(sum(sizes))
    outputs = ProcessOutputs(tmp_path, ("a", "b", "wheel_odometry"), np.array([0.4, -0.1, 0.2]), publish_period=0.25)
    results: list[SweepResult] = []
    wheel: list[tuple[int, np.ndarray]] = []
    for i in range(12):
        for method, doppler in (("a", True), ("b", False)):
            if method == "b" and i == 5:  # a sweep b has no result for (and at 8 its own stamp): /tf messages of 1-3 poses
                continue
            r = _result(rng, method, i, *sizes, doppler=doppler)
            results.append(r)
            outputs.add(r)
        wheel.append((T0 + i * 100_000_000, rng.normal(size=3)))
        outputs.add_pose("wheel_odometry", wheel[-1][0], wheel[-1][1], (0.5, 0.1))
        outputs.end_sweep(T0 + i * 100_000_000, {})
    corrected = np.array([r.pose for r in results if r.method == "a"]) + [1.0, -2.0, 0.1]
    outputs.correct("a", corrected)
    outputs.finish({})
    got = _decoded(tmp_path / "processed.mcap")

    for r in results:
        (at, odom), = [(t, m) for t, m in got[f"/{r.method}/odom"] if t == r.stamp_ns]
        assert _ns(odom.header.stamp) == at and odom.header.frame_id == f"{r.method}/odom"
        assert odom.child_frame_id == f"{r.method}/base_link"
        assert _planar(odom.pose.pose) == pytest.approx(tuple(r.pose), abs=1e-12)
        assert odom.twist.twist.linear.x == r.twist[0] and odom.twist.twist.angular.z == r.twist[1]
        for kind, xy, vel in (("static", r.static_map_xy, r.static_velocity),
                              ("moving", r.moving_map_xy, r.moving_velocity)):
            (_, cloud), = [(t, m) for t, m in got[f"/{r.method}/points/{kind}"] if t == r.stamp_ns]
            cols = _cloud_columns(cloud)
            assert cloud.width == len(xy) and sorted(cols) == sorted(["x", "y", "z"] + (["velocity"] if vel is not None else []))
            assert np.array_equal(cols["x"], xy[:, 0].astype("<f4")) and np.array_equal(cols["y"], xy[:, 1].astype("<f4"))
            assert not cols["z"].any()
            if vel is not None:
                assert np.array_equal(cols["velocity"], vel.astype("<f4"))
        labels = [m for t, m in got.get(f"/{r.method}/moving_labels", []) if t == r.stamp_ns]
        assert len(labels) == r.segmented
        if labels:
            assert np.array_equal(np.frombuffer(bytes(labels[0].moving), np.uint8), r.moving_mask.astype(np.uint8))

    final = {"a": corrected, "b": np.array([r.pose for r in results if r.method == "b"]),
             "wheel_odometry": np.array([p for _, p in wheel])}
    stamps = {"a": [r.stamp_ns for r in results if r.method == "a"], "b": [r.stamp_ns for r in results if r.method == "b"],
              "wheel_odometry": [ns for ns, _ in wheel]}
    for name in final:  # the last path is the whole trajectory, as it ends up
        at, path = got[f"/{name}/path"][-1]
        assert path.header.frame_id == f"{name}/odom" and len(path.poses) == len(final[name])
        assert [_ns(p.header.stamp) for p in path.poses] == stamps[name]
        assert {p.header.frame_id for p in path.poses} == {f"{name}/odom"}
        assert np.allclose(_wrapped([_planar(p.pose) for p in path.poses]), _wrapped(final[name]), atol=1e-12)
        for _, earlier in got[f"/{name}/path"][:-1]:  # the paths published on the way: a part of it, in order
            seen = [_ns(p.header.stamp) for p in earlier.poses]
            assert seen[0] == stamps[name][0] and seen == sorted(seen) and set(seen) <= set(stamps[name])

    tf = got["/tf"]
    assert [t for t, _ in tf] == sorted({ns for v in stamps.values() for ns in v})
    for at, msg in tf:
        names = [name for name in final if at in stamps[name]]
        assert [(tr.header.frame_id, tr.child_frame_id) for tr in msg.transforms] == \
            [(f"{n}/odom", f"{n}/base_link") for n in names]
        for name, tr in zip(names, msg.transforms):
            assert _ns(tr.header.stamp) == at
            t, q = tr.transform.translation, tr.transform.rotation
            x, y, yaw = final[name][stamps[name].index(at)]
            assert (t.x, t.y, t.z) == (x, y, 0.0) and q.x == q.y == 0.0
            assert _wrapped([0, 0, 2 * math.atan2(q.z, q.w)])[2] == pytest.approx(_wrapped([0, 0, yaw])[2], abs=1e-12)
