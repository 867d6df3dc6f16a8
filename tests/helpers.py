"""Helpers the tests share: logs read and rewritten with plain ``mcap`` + ``mcap_ros2`` (not fmcwlog's
reader), ground truth read the same way, and a trajectory error written for the tests (2-D Kabsch),
not fmcwlog's metrics.
"""

from __future__ import annotations

import contextlib
import functools
import io
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from fmcwlog.evaluation.ground_truth import read_ground_truth
from fmcwlog.io.logs import open_log
from fmcwlog.kernels import compiled

# The compiled kernels (fmcwlog._core) where they load; the comparisons with numpy skip where they do
# not, unless FMCWLOG_KERNELS=compiled asks for them (CI does): then they fail.
CORE, WHY_NOT = compiled._load()
needs_core = pytest.mark.skipif(
    CORE is None and os.environ.get(compiled.ENV) != "compiled", reason=f"{WHY_NOT} (FMCWLOG_KERNELS=compiled fails instead)")


ROOT = Path(__file__).resolve().parents[1]  # the checkout
SAMPLE_LOGS = ROOT / "sample_logs"
SHARED = ROOT.parent / "shared"  # beside the checkout, not in it: the real robot datasets and another writer's logs

# What each folder of ../shared holds, and the marker a test reading from it carries.
_SHARED_KINDS = {
    "datasets": ("needs_datasets", "the real robot datasets beside the checkout"),
    "conformance": ("needs_conformance", "the other writer's conformance logs beside the checkout"),
}
_current_test = None  # the test being set up or run (conftest sets it): shared_file checks its markers


def shared_file(relpath: str) -> Path:
    """``../shared/RELPATH`` (``datasets/...`` or ``conformance/...``), or the test is skipped naming
    it where it is absent. Data outside the repository is said twice: here by the skip reason, and
    by the test's marker (``needs_datasets``, ``needs_conformance``), which this checks so that
    ``-m "not needs_datasets"`` cannot run a test that reads the datasets."""
    import pytest

    marker, what = _SHARED_KINDS[relpath.split("/", 1)[0]]
    if _current_test is not None and _current_test.get_closest_marker(marker) is None:
        pytest.fail(f"{_current_test.nodeid} reads ../shared/{relpath} but is not marked @pytest.mark.{marker}")
    path = SHARED / relpath
    if not path.exists():
        pytest.skip(f"needs ../shared/{relpath} ({what})")
    return path


def decoded(path: Path, topics=None):
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        yield from reader.iter_decoded_messages(topics=topics)


def copy_log(src: Path, dst: Path, drop_topics=(), drop_metadata=(), edit=None, extra_metadata=None,
             order=None) -> None:
    """Re-encode a log message by message; ``edit(topic, index, msg)`` may change a message or
    return False to drop it; ``extra_metadata`` records are added; ``order(topic, log_time)``, if
    given, is the key messages are written in (a stable sort of the log_time order)."""
    with open(src, "rb") as fh:
        meta = {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}
    counts: dict[str, int] = {}
    with open(dst, "wb") as out:
        w = Writer(out)
        schemas = {}
        for name, values in meta.items():
            if name not in drop_metadata:
                w.add_metadata(name, values)
        for name, values in (extra_metadata or {}).items():
            w.add_metadata(name, values)
        messages = decoded(src)
        if order is not None:
            messages = sorted(messages, key=lambda m: order(m[1].topic, m[2].log_time))
        for schema, channel, message, msg in messages:
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


def metadata(log: Path) -> dict[str, dict[str, str]]:
    """Every metadata record of the log, by name (read with plain mcap)."""
    with open(log, "rb") as fh:
        return {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}


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


def record_scenario(tmp_path_factory, scenario: str, duration: float, seed: int = 0, **overrides) -> Path:
    """A log of the built-in ``scenario`` (``duration`` s, ``seed``, ``--set``-like ``overrides``)."""
    from fmcwlog.sim import scenarios
    from fmcwlog.sim.config import SimConfig, apply_overrides
    from fmcwlog.sim.recorder import record

    cfg = apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": seed}, **overrides})
    out = tmp_path_factory.mktemp(scenario) / f"{scenario}.mcap"
    record(scenarios.SCENARIOS[scenario](), cfg, out)
    return out


def small_ring():
    """A 3 m ring corridor around an 8 m x 4 m block, recesses in the walls, one walker: 14 s of it
    is a straight, a corner of radius 1.2 m, and a bit of the next straight."""
    from fmcwlog.sim.world import world_from_dict

    outer = [[0, 0, 4, 0], [4, 0, 4, -0.4], [4, -0.4, 5, -0.4], [5, -0.4, 5, 0], [5, 0, 9, 0], [9, 0, 9, -0.3],
             [9, -0.3, 10.5, -0.3], [10.5, -0.3, 10.5, 0], [10.5, 0, 14, 0], [14, 0, 14, 10], [14, 10, 0, 10],
             [0, 10, 0, 0]]
    block = [[3, 3, 11, 3], [11, 3, 11, 7], [11, 7, 3, 7], [3, 7, 3, 3], [6, 3, 6, 2.6], [6, 2.6, 6.5, 2.6],
             [6.5, 2.6, 6.5, 3]]
    return world_from_dict({
        "name": "small-ring",
        "walls": outer + block,
        "route": {"waypoints": [[1.5, 1.5], [12.5, 1.5], [12.5, 8.5], [1.5, 8.5]], "loop": True, "corner_radius": 1.2},
        "movers": [{"kind": "person", "path": [[2, 2.4], [12, 2.4]], "speed": 1.1, "phase": 3.0}],
    })


def record_small_ring(path: Path, duration: float = 14.0, **sensor) -> Path:
    """Record :func:`small_ring` (seed 0) with ``sensor`` parameters set (``mount_x=0.0``, ...)."""
    from fmcwlog.sim.config import SimConfig, apply_overrides
    from fmcwlog.sim.recorder import record

    record(small_ring(), apply_overrides(SimConfig(), {"run": {"duration": duration}, "sensor": sensor}), path)
    return path


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=600)


def run_python(source: str) -> tuple[int, str, str]:
    """``source`` run by a fresh interpreter (exit status, stdout, stderr): for what a process does
    from its start (its imports, its signal handlers), which this test process has long passed."""
    ran = subprocess.run([sys.executable, "-c", source], capture_output=True, text=True, timeout=120)
    return ran.returncode, ran.stdout, ran.stderr


def run_cli_here(*args: str) -> tuple[int, str, str]:
    """``fmcwlog ARGS`` in this process (exit status, stdout, stderr): the real ``cli.main``, with its
    error handling, but without a new interpreter, so that tests can patch what it calls (a full
    disk) and fuzz it quickly. An exception that escapes ``main`` escapes this too: a traceback."""

    from fmcwlog import cli

    out, err = io.StringIO(), io.StringIO()
    argv, sys.argv = sys.argv, ["fmcwlog", *args]
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            cli.main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.argv = argv
    return code, out.getvalue(), err.getvalue()


def assert_one_line_error(code: int, stderr: str, *words: str) -> str:
    """Exit status 2 and a single ``fmcwlog: error: ...`` line holding ``words``; returns the line."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("fmcwlog: error: "), (code, stderr)
    assert "Traceback" not in stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def param_leaves(cls: type, prefix: str = ""):
    """(dotted name as --set takes it, field, type) of every scalar parameter of ``cls``, nested ones included."""
    import dataclasses
    import typing

    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            yield from param_leaves(hints[f.name], f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", f, hints[f.name]


@functools.cache
def numpy_trig_is_libm() -> bool:
    """Whether numpy's float64 sin and cos give the C library's (``math``'s) bits on this machine:
    true without AVX-512; with it numpy uses SVML, 1 ulp apart. The scalar fast paths of
    :mod:`fmcwlog.geometry` and :mod:`fmcwlog.frontend.deskew` are bit-identical to their array
    formulas exactly when it holds."""
    rng = np.random.default_rng(20261122)
    a = np.concatenate([rng.uniform(-4.0, 4.0, 200_000), rng.uniform(-1e-3, 1e-3, 50_000),
                        rng.normal(0.0, 1e-9, 20_000), rng.uniform(-1e4, 1e4, 50_000),
                        [0.0, -0.0, math.pi, -math.pi, math.pi / 2, 2 * math.pi, 1e-300, 5e-324, 1e300]])
    listed = a.tolist()
    return bool(np.array_equal(np.sin(a), [math.sin(x) for x in listed])
                and np.array_equal(np.cos(a), [math.cos(x) for x in listed]))


def same_bits(fast, slow) -> bool:
    """``fast`` is ``slow`` bit for bit (signed zeros and all) where :func:`numpy_trig_is_libm`,
    else within 2 ulp (the fast paths' trig is the C library's, numpy's SVML's is not)."""
    fast, slow = np.asarray(fast, dtype=float), np.asarray(slow, dtype=float)
    if fast.shape != slow.shape:
        return False
    if numpy_trig_is_libm():
        return np.ascontiguousarray(fast).tobytes() == np.ascontiguousarray(slow).tobytes()
    close = np.abs(fast - slow) <= 2 * np.spacing(np.abs(slow))
    return bool(np.all(close | (np.isnan(fast) & np.isnan(slow))))


def _quaternion_dict(roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> dict[str, float]:
    """geometry_msgs/Quaternion of the rotation Rz(yaw) Ry(pitch) Rx(roll), as ROS's tf2 writes it."""
    cr, sr, cp, sp = math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return {"x": sr * cp * cy - cr * sp * sy, "y": cr * sp * cy + sr * cp * sy,
            "z": cr * cp * sy - sr * sp * cy, "w": cr * cp * cy + sr * sp * sy}


def tf_entry(parent: str, child: str, xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0), stamp_ns: int = 0) -> dict:
    """One geometry_msgs/TransformStamped as a dict: ``child`` at ``xyz`` (m), turned by roll, pitch, yaw (rad), in ``parent``."""
    return {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": parent},
            "child_frame_id": child,
            "transform": {"translation": dict(zip("xyz", map(float, xyz))), "rotation": _quaternion_dict(*rpy)}}


def wheel_odometry(path: Path) -> list[tuple[int, np.ndarray]]:
    """The robot's own odometry, as its driver would publish it: the log's ticks integrated with the
    calibrated radii (exact arcs, composed in a loop; not fmcwlog's integration)."""
    cal = {k: float(v) for k, v in metadata(path)["fmcwlog.calibration"].items()}
    k = 2 * math.pi / cal["ticks_per_revolution"]
    out, pose, last = [], np.zeros(3), None
    for _, _, message, m in decoded(path, ["/wheel/ticks"]):
        if last is not None:
            sl = (m.left - last[0]) * k * cal["wheel_radius_left"]
            sr = (m.right - last[1]) * k * cal["wheel_radius_right"]
            s, dth = (sl + sr) / 2, (sr - sl) / cal["track_width"]
            chord = s if abs(dth) < 1e-12 else 2 * s / dth * math.sin(dth / 2)
            pose = pose + [chord * math.cos(pose[2] + dth / 2), chord * math.sin(pose[2] + dth / 2), dth]
        last = (m.left, m.right)
        out.append((message.log_time, pose.copy()))
    return out


_HEADER_DEFS = ("=" * 80 + "\nMSG: std_msgs/msg/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
                + "=" * 80 + "\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n")


def ros_laser_log(src: Path, dst: Path, tf_static=(), tf=(), calibration=None, odom: bool = True,
                  ticks: bool = False, ground_truth: bool = True, until_s: float | None = None) -> Path:
    """``src`` (a recorded fmcwlog log) as a ROS 2 driver stack would log it, written by mcap_ros2's
    ``Writer``: ``/scan`` a LaserScan in frame ``laser`` (the cloud's points on 1081 beams of 0.25°),
    ``/odom`` the wheels' odometry (:func:`wheel_odometry`) with ``odom``, ``/wheel/ticks`` copied
    with ``ticks``, ``/ground_truth/odom`` copied with ``ground_truth`` (for report), one
    ``/tf_static`` message holding the ``tf_static`` entries (:func:`tf_entry`) at the start, the
    ``tf`` entries on ``/tf`` with every scan, and the ``fmcwlog.calibration`` record only where
    ``calibration`` gives it. ``until_s``: the first so many seconds."""
    schemas = ROOT / "schemas"
    with open(src, "rb") as fh:
        summary = make_reader(fh).get_summary()
    texts = {sc.name: sc.data.decode() for sc in summary.schemas.values()}
    rows = list(decoded(src, ["/fmcw/points", "/wheel/ticks", "/ground_truth/odom"]))
    start = rows[0][2].log_time
    end = start + int(until_s * 1e9) if until_s is not None else None
    odometry = iter(wheel_odometry(src) if odom else [])
    with open(dst, "wb") as out:
        w = Writer(out)
        if calibration is not None:
            w.add_metadata("fmcwlog.calibration", calibration)
        scan_schema = w.register_msgdef("sensor_msgs/msg/LaserScan",
                                        (schemas / "sensor_msgs" / "msg" / "LaserScan.msg").read_text() + _HEADER_DEFS)
        odom_schema = w.register_msgdef("nav_msgs/msg/Odometry", texts["nav_msgs/msg/Odometry"])
        tf_schema = w.register_msgdef("tf2_msgs/msg/TFMessage", texts["tf2_msgs/msg/TFMessage"])
        ticks_schema = w.register_msgdef("fmcwlog_msgs/msg/WheelTicks", texts["fmcwlog_msgs/msg/WheelTicks"])
        if tf_static:
            w.write_message("/tf_static", tf_schema, {"transforms": list(tf_static)}, log_time=start, publish_time=start)
        n, res = 1081, math.radians(0.25)
        pending = next(odometry, None)
        for _, channel, message, msg in rows:
            ns = message.log_time
            if end is not None and ns > end:
                break
            while pending is not None and pending[0] <= ns:
                t, pose = pending
                w.write_message("/odom", odom_schema, {
                    "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "odom"},
                    "child_frame_id": "base_link",
                    "pose": {"pose": {"position": {"x": pose[0], "y": pose[1], "z": 0.0},
                                      "orientation": _quaternion_dict(yaw=pose[2])}, "covariance": [0.0] * 36},
                    "twist": {"twist": {"linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                                        "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}, "covariance": [0.0] * 36},
                }, log_time=t, publish_time=t)
                pending = next(odometry, None)
            if channel.topic == "/wheel/ticks":
                if ticks:
                    w.write_message("/wheel/ticks", ticks_schema, msg, log_time=ns, publish_time=ns)
                continue
            if channel.topic == "/ground_truth/odom":
                if ground_truth:
                    w.write_message("/ground_truth/odom", odom_schema, msg, log_time=ns, publish_time=ns)
                continue
            if tf:
                stamped = [dict(e, header=dict(e["header"], stamp={"sec": ns // 10**9, "nanosec": ns % 10**9}))
                           for e in tf]
                w.write_message("/tf", tf_schema, {"transforms": stamped}, log_time=ns, publish_time=ns)
            pts = np.frombuffer(bytes(msg.data), np.float32).reshape(-1, msg.point_step // 4)
            beam = np.rint((np.arctan2(pts[:, 1], pts[:, 0]) + math.radians(135)) / res).astype(int)
            ranges = np.full(n, np.inf, np.float32)
            ranges[beam] = np.hypot(pts[:, 0], pts[:, 1])
            w.write_message("/scan", scan_schema, {
                "header": {"stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec},
                           "frame_id": "laser"},
                "angle_min": -math.radians(135), "angle_max": math.radians(135), "angle_increment": res,
                "time_increment": 0.075 / 1080, "scan_time": 0.1, "range_min": 0.1, "range_max": 30.0,
                "ranges": ranges.tolist(), "intensities": []}, log_time=ns, publish_time=ns)
        w.finish()
    return dst


def _bench_module(name: str):
    """``bench/NAME.py`` imported as a module (the bench scripts are not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


# bench/replay_frames.py: whether a viewer places every message of an MCAP file (each frame a message
# names resolves to map through the file's own tf at its stamp), read with plain mcap + mcap_ros2
replay_frames = _bench_module("replay_frames")


def wall_scene(seed: int, n_walls: int, n_points: int, n_source: int, offset, n_clutter: int,
               extent: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """Random walls within ±``extent`` m as ``n_points`` points (the target, map frame) and a view of
    ``n_source`` of them with 1 cm noise plus ``n_clutter`` random points within ±(``extent`` + 1) m
    that the map lacks (movers), seen from ``offset`` (x, y, θ): the source in its own frame, C-ordered."""
    rng = np.random.default_rng(seed)
    ends = rng.uniform(-extent, extent, (n_walls, 4))
    t = rng.random(n_points)
    seg = rng.integers(0, n_walls, n_points)
    target = ends[seg, :2] + t[:, None] * (ends[seg, 2:] - ends[seg, :2])
    pick = rng.choice(n_points, min(n_source, n_points), replace=False)
    seen = target[pick] + rng.normal(0, 0.01, (len(pick), 2))
    seen = np.concatenate([seen, rng.uniform(-extent - 1, extent + 1, (n_clutter, 2))])
    x, y, th = offset
    c, s = np.cos(-th), np.sin(-th)
    return np.ascontiguousarray((seen - (x, y)) @ np.array([[c, s], [-s, c]])), target


def truth_twist(log: Path, t0: np.ndarray, span: np.ndarray) -> np.ndarray:
    """(N, 2) true ``(v, ω)`` of base_link from ``t0`` (ns) over ``span`` (s): the ground truth's motion
    over that interval, its forward component and its yaw change, each over ``span``."""
    stamps, poses = read_ground_truth(open_log(log))
    stamps = stamps.astype(float)
    yaw = np.unwrap(poses[:, 2])

    def at(t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, stamps, poses[:, 0]), np.interp(t, stamps, poses[:, 1]),
                         np.interp(t, stamps, yaw)], -1)

    a, b = at(t0), at(t0 + span * 1e9)
    d = b[:, :2] - a[:, :2]
    forward = np.cos(a[:, 2]) * d[:, 0] + np.sin(a[:, 2]) * d[:, 1]
    return np.stack([forward / span, (b[:, 2] - a[:, 2]) / span], -1)
