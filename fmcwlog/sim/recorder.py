"""Runs a simulation and writes it as a log (the log format, docs/log-format.md).

Messages go out in log-time order, a sweep period at a time: the sweep and
its ground-truth labels at its first beam's stamp, then the encoder counts
and ground-truth odometry falling in that period. Beside the contract's topics, for viewers:
``/tf_static`` holds the mount (``base_link`` -> ``lidar``), ``/ground_truth/tf`` the true pose
(``map`` -> ``base_link``: where Foxglove, or RViz with it remapped to ``/tf``, draws the sweeps)
and ``/tf`` the same true pose as a tree of its own (``map`` -> ``ground_truth/base_link``), which
every viewer shows beside ``processed.mcap``'s trees and no estimator can take for ``base_link``. A Ctrl-C (SIGINT) stops
the loop between two periods, so the log is finished cleanly and is simply
shorter. Randomness comes from two streams derived from the seed (encoders,
LiDAR), so the same seed gives the same bytes.
"""

from __future__ import annotations

import json
import math
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..geometry import yaw_to_quaternion
from ..io.atomic import created_parents, reported_write_errors
from ..io.mcap_log import (
    LogWriter,
    float32_cloud_cdr,
    odometry_cdr_batch,
    point_labels_cdr,
    pointcloud2_cdr,
    stamp_pair,
    tf_cdr_batch,
    wheel_ticks_cdr_batch,
)
from ..io.messages import POINT_FIELDS, tf_message, transform_dict
from ..io.topics import (
    BASE_FRAME,
    CALIBRATION_KEY,
    GT_BASE_FRAME,
    GT_LABELS_TOPIC,
    GT_ODOM_TOPIC,
    GT_TF_TOPIC,
    LIDAR_FRAME,
    MAP_FRAME,
    POINTS_TOPIC,
    SIM_KEY,
    TF_STATIC_TOPIC,
    TF_TOPIC,
    TICKS_TOPIC,
    WORLD_KEY,
)
from .chassis import BodyState, Chassis
from .config import SimConfig
from .lidar import FmcwLidar, Sweep
from .world import World


@dataclass(frozen=True)
class RecordSummary:
    """What :func:`record` wrote: the log's path, its sweeps, the simulated seconds, whether Ctrl-C
    cut it short, and how many points (and of them on movers) it holds."""

    path: Path
    sweeps: int
    seconds: float  # simulated time written
    interrupted: bool
    points: int
    moving_points: int

    @property
    def moving_fraction(self) -> float:
        """The share of the points that hit a mover (0 with no points)."""
        return self.moving_points / self.points if self.points else 0.0


def calibration_metadata(cfg: SimConfig) -> dict[str, str]:
    """The ``fmcwlog.calibration`` record: what the robot *believes* (nominal radii), each value a
    decimal string in SI units (m, rad, Hz, m/s) under the log format's keys (docs/log-format.md)."""
    s, r = cfg.sensor, cfg.robot
    values = {
        "wheel_radius_left": r.wheel_radius,
        "wheel_radius_right": r.wheel_radius,
        "track_width": r.track_width,
        "ticks_per_revolution": r.ticks_per_revolution,
        "lidar_x": s.mount_x,
        "lidar_y": s.mount_y,
        "lidar_yaw": math.radians(s.mount_yaw_deg),
        "fov": math.radians(s.fov_deg),
        "angular_resolution": math.radians(s.resolution_deg),
        "max_range": s.max_range,
        "range_sigma": s.range_sigma,
        "doppler_resolution": s.doppler_resolution,
        "wavelength": s.wavelength,
        "scan_rate": s.scan_rate,
    }
    return {k: repr(v) if isinstance(v, float) else str(v) for k, v in values.items()}


class _StopFlag:
    """Turns SIGINT into a flag checked between sweep periods (main thread only)."""

    def __init__(self) -> None:
        self.set = False
        self._old = None

    def __enter__(self) -> _StopFlag:
        try:
            self._old = signal.signal(signal.SIGINT, self._handle)
        except ValueError:  # not the main thread: leave SIGINT alone
            self._old = None
        return self

    def _handle(self, signum, frame) -> None:
        self.set = True

    def __exit__(self, *exc) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


# Sweeps simulated in one numpy pass: 20 share the per-call overhead that dominates a sweep and
# hold only 20 x 1081 beams at once. CPU time of ``fmcwlog record --scenario crowd --duration 120``:
# 1.13-1.22 s CPU at 20, 1.31-1.34 s at 10, 1.21-1.56 s at 40 (docs/design/speed-experiments.md).
# The log's bytes do not depend on it.
SWEEPS_AT_ONCE = 20


def _ns(start_ns: int, k: np.ndarray, rate: float) -> np.ndarray:
    return start_ns + np.round(k * (1e9 / rate)).astype(np.int64)


def _sweeps(chassis: Chassis, lidar: FmcwLidar, n_sweeps: int, scan_rate: float,
            rng: np.random.Generator) -> Iterator[tuple[int, Sweep]]:
    """Sweep ``j`` (from ``j / scan_rate`` s) for every ``j``, simulated ``SWEEPS_AT_ONCE`` at a time."""
    for j0 in range(0, n_sweeps, SWEEPS_AT_ONCE):
        js = np.arange(j0, min(j0 + SWEEPS_AT_ONCE, n_sweeps))
        t_beams = ((js / scan_rate)[:, None] + lidar.beam_time).ravel()  # s, sweep after sweep
        yield from zip(js.tolist(), lidar.sweeps(chassis.state(t_beams), t_beams, rng))


def _ground_truth(ns_ticks: np.ndarray, body: BodyState, left: np.ndarray, right: np.ndarray,
                  ticks: slice) -> list[tuple[int, bytes, bytes, bytes, bytes]]:
    """Per tick of ``ticks``: its stamp (ns), then its wheel ticks, ground-truth odometry, ground-truth
    tf (``map`` -> ``base_link``) and ``/tf`` (``map`` -> ``ground_truth/base_link``) messages,
    CDR-encoded (many at once: ``mcap_log._batch``)."""
    ns = ns_ticks[ticks]
    pose = np.zeros((len(ns), 7))  # pose7: x, y, z, then the quaternion
    pose[:, 0], pose[:, 1], pose[:, 3:] = body.x[ticks], body.y[ticks], yaw_to_quaternion(body.yaw[ticks])
    odom = np.zeros((len(ns), 85))  # pose7, its covariance (unknown: 0), twist (linear, angular), its covariance
    odom[:, :7], odom[:, 43], odom[:, 48] = pose, body.v[ticks], body.omega[ticks]
    return list(zip(ns.tolist(), wheel_ticks_cdr_batch(ns, BASE_FRAME, left[ticks], right[ticks]),
                    odometry_cdr_batch(ns, MAP_FRAME, BASE_FRAME, odom), tf_cdr_batch(ns, MAP_FRAME, BASE_FRAME, pose),
                    tf_cdr_batch(ns, MAP_FRAME, GT_BASE_FRAME, pose)))


# The multi-ring sensor's points: the planar one's float32 fields, then the ring as uint16 (as Ouster's
# and Velodyne's drivers write it), padded to 4 bytes.
_RING_POINT = np.dtype({"names": [*POINT_FIELDS, "ring"], "formats": ["<f4"] * len(POINT_FIELDS) + ["<u2"],
                        "offsets": [4 * i for i in range(len(POINT_FIELDS) + 1)], "itemsize": 4 * len(POINT_FIELDS) + 4})
_RING_FIELDS = tuple((name, _RING_POINT.fields[name][1], 7 if name != "ring" else 4, 1) for name in _RING_POINT.names)


def _cloud(ns: int, sweep: Sweep) -> bytes:
    """The sweep as a PointCloud2 in ``lidar``: x y z (0 for the planar sensor) intensity velocity t, float32,
    point by point; the multi-ring sensor's with its ``ring`` (uint16) after them."""
    columns = dict(zip(POINT_FIELDS, (sweep.x, sweep.y, sweep.z, sweep.intensity, sweep.velocity, sweep.t)))
    if sweep.ring is None:
        return float32_cloud_cdr(stamp_pair(ns), LIDAR_FRAME, len(sweep.x), columns)
    points = np.zeros(len(sweep.x), dtype=_RING_POINT)
    for name, column in (*columns.items(), ("ring", sweep.ring)):
        points[name] = column
    step = _RING_POINT.itemsize
    return pointcloud2_cdr(stamp_pair(ns), LIDAR_FRAME, 1, len(points), _RING_FIELDS, False, step, step * len(points),
                           points.tobytes(), True)


def record(world: World, cfg: SimConfig, out: str | Path,
           on_progress: Callable[[int], None] | None = None) -> RecordSummary:
    """Simulate ``cfg.run.duration`` seconds of ``world`` and write the log to ``out`` (and the
    folders it needs: removed again if the recording fails).

    ``on_progress`` is called with the number of sweeps done after each one. ``cfg`` is validated
    first (:class:`~fmcwlog.errors.ConfigError` naming the parameter at fault); the log is written
    under a temporary name and moved to ``out`` only when complete, so a failure leaves nothing at ``out``
    (a full disk or an unwritable folder: one :class:`~fmcwlog.errors.OutputError` naming ``out``).
    """
    with reported_write_errors(out), created_parents(out):
        return _record(world, cfg, out, on_progress)


def _record(world: World, cfg: SimConfig, out: str | Path, on_progress: Callable[[int], None] | None) -> RecordSummary:
    cfg.validate()
    s_cfg, r_cfg, run = cfg.sensor, cfg.robot, cfg.run
    chassis = Chassis(world.route.build(), r_cfg)
    lidar = FmcwLidar(s_cfg, world.walls, world.movers)
    rng_encoders = np.random.default_rng([run.seed, 1])
    rng_lidar = np.random.default_rng([run.seed, 2])

    n_ticks = int(math.floor(run.duration * r_cfg.encoder_rate + 1e-9))
    k = np.arange(n_ticks)
    t_ticks = k / r_cfg.encoder_rate
    ns_ticks = _ns(run.start_time_ns, k, r_cfg.encoder_rate)
    body = chassis.state(t_ticks)
    left, right = chassis.encoder_counts(body, rng_encoders)

    n_sweeps = int(math.floor(run.duration * s_cfg.scan_rate + 1e-9))
    ns_sweeps = _ns(run.start_time_ns, np.arange(n_sweeps + 1), s_cfg.scan_rate)
    tick_bounds = np.searchsorted(ns_ticks, ns_sweeps)

    sim_meta = {
        "generator": f"fmcwlog {__version__}",
        "scenario": world.name,
        "seed": str(run.seed),
        "config": json.dumps(cfg.recorded(), sort_keys=True),
        "true_wheel_radius_left": repr(r_cfg.wheel_radius * (1 + r_cfg.wheel_radius_error_left)),
        "true_wheel_radius_right": repr(r_cfg.wheel_radius * (1 + r_cfg.wheel_radius_error_right)),
    }
    done = points = moving = 0
    with LogWriter(out, compression=run.compression) as writer, _StopFlag() as stop:
        writer.add_metadata(CALIBRATION_KEY, calibration_metadata(cfg))
        writer.add_metadata(WORLD_KEY, world.metadata())
        writer.add_metadata(SIM_KEY, sim_meta)
        # the mount, once at the start (a latched topic in ROS 2): Foxglove places lidar in base_link
        writer.write(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage",
                     tf_message([transform_dict(run.start_time_ns, BASE_FRAME, LIDAR_FRAME, np.array(s_cfg.mount))]),
                     run.start_time_ns)
        write, first, gt = writer.write_cdr, 0, []
        for j, sweep in _sweeps(chassis, lidar, n_sweeps, s_cfg.scan_rate, rng_lidar):
            if stop.set:
                break
            if j % SWEEPS_AT_ONCE == 0:  # the ground truth of the next SWEEPS_AT_ONCE periods
                first = int(tick_bounds[j])
                gt = _ground_truth(ns_ticks, body, left, right,
                                   slice(first, int(tick_bounds[min(j + SWEEPS_AT_ONCE, n_sweeps)])))
            ns = int(ns_sweeps[j])
            write(POINTS_TOPIC, "sensor_msgs/msg/PointCloud2", _cloud(ns, sweep), ns)
            write(GT_LABELS_TOPIC, "fmcwlog_msgs/msg/PointLabels",
                  point_labels_cdr(stamp_pair(ns), LIDAR_FRAME, sweep.moving.tobytes()), ns)
            for tns, ticks, odom, gt_tf, tf in gt[tick_bounds[j] - first:tick_bounds[j + 1] - first]:
                write(TICKS_TOPIC, "fmcwlog_msgs/msg/WheelTicks", ticks, tns)
                write(GT_ODOM_TOPIC, "nav_msgs/msg/Odometry", odom, tns)
                write(GT_TF_TOPIC, "tf2_msgs/msg/TFMessage", gt_tf, tns)
                write(TF_TOPIC, "tf2_msgs/msg/TFMessage", tf, tns)
            done += 1
            points += len(sweep.x)
            moving += int(sweep.moving.sum())
            if on_progress:
                on_progress(done)
    return RecordSummary(Path(out), done, done / s_cfg.scan_rate, done < n_sweeps, points, moving)
