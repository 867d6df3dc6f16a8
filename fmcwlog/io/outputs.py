"""What ``fmcwlog process`` leaves in its output folder, in the field's usual formats.

Frames (REP-105, one tree per trajectory so that methods never fight over a frame): each
method ``M`` (and the motion prior, ``wheel_odometry``) has its own fixed frame ``M/odom``,
with its estimate of the robot as ``M/base_link`` and the sensor as ``M/lidar``. Estimates
start at the origin of ``M/odom``: the robot's pose at the first sweep. ``processed.mcap`` hangs
every ``M/odom`` from ``map`` at the identity: estimation cannot know where in the input's
``map`` the robot started (that is ground truth), so ``map`` here is the frame the robot started
in, shared by every trajectory, and an estimate overlays the input's ``map`` exactly where the
input has the robot start at its origin (an imported CARMEN log does).

- ``<M>.tum``: ``t x y z qx qy qz qw`` per sweep, ``M/base_link`` in ``M/odom`` (evo);
- ``trajectories.parquet``: a row per sweep and trajectory (pandas, pyarrow); units,
  frames and the angle convention are in the schema's metadata (:data:`PARQUET_COLUMNS`);
- ``<M>_map.pgm`` + ``.yaml`` (ROS map_server) and ``<M>_map.png``, in ``M/odom``;
- ``processed.mcap`` (Foxglove, RViz, rosbags): ``/tf_static`` (each ``map -> M/odom``, the
  identity, and ``M/base_link -> M/lidar``, the input's mount), ``/tf`` (each
  ``M/odom -> M/base_link`` at every sweep: the poses of ``<M>.tum``, so the back end's
  optimised ones where it ran), ``/M/odom`` (Odometry with the twist and the registration's
  covariance: the front end's, as it ran), ``/M/path`` and ``/M/map`` (every
  ``publish_period`` seconds of log, less often once they outgrow :data:`PUBLISH_BYTES_PER_S`,
  and at the end), ``/M/points/static|moving`` (in ``M/odom``, with their ``velocity``),
  ``/M/moving_labels`` (in ``M/lidar``, index for index with the input sweep). Every frame a
  message names resolves to ``map`` through the file's own tf at the message's stamp;
- ``<M>_frontend.tum`` (with a back end): the front end's own trajectory, before the back end
  corrected it; ``<M>.tum``, the parquet's ``x, y, yaw``, ``processed.mcap``'s ``/tf`` and its
  final path and map are then the optimised ones (:meth:`ProcessOutputs.correct`), the parquet
  keeping the front end's beside them (``x_frontend, y_frontend, yaw_frontend``);
- ``<M>_backend.json`` (with a back end): its nodes and loop closures;
- ``run.json`` (:class:`fmcwlog.pipeline.run_record.RunRecord`): parameters, version, inputs, counts.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..allocator import release_freed_memory
from ..errors import ReportError
from ..geometry import quaternion_to_yaw, yaw_to_quaternion
from ..kernels.growing import GrowingArray
from ..kernels.occupancy import OccupancyGrid
from ..types import SweepResult
from .mcap_log import (
    LogWriter,
    Pose7,
    Stamp,
    float32_cloud_cdr,
    odometry_cdr,
    path_cdr_arrays,
    point_labels_cdr,
    stamp_pair,
    tf_cdr_arrays,
)
from .messages import (
    occupancy_grid_message,
    planar_covariance,
    pose7,
    pose7_array,
    tf_message,
    transform_dict,
)
from .topics import MAP_FRAME, TF_STATIC_TOPIC, TF_TOPIC


def odom_frame(name: str) -> str:
    """Trajectory ``name``'s fixed frame, where it starts at the origin: ``<name>/odom``."""
    return f"{name}/odom"


def base_frame(name: str) -> str:
    """Trajectory ``name``'s robot frame (the rear-axle midpoint): ``<name>/base_link``."""
    return f"{name}/base_link"


def lidar_frame(name: str) -> str:
    """Trajectory ``name``'s sensor frame: ``<name>/lidar``."""
    return f"{name}/lidar"


# column -> (arrow type, unit and meaning); stored in the parquet schema's metadata
PARQUET_COLUMNS: dict[str, tuple[pa.DataType, str]] = {
    "method": (pa.string(), "trajectory: a method (improved, baseline) or wheel_odometry (the motion prior)"),
    "stamp_ns": (pa.int64(), "ns since the epoch: the sweep's stamp (its first beam)"),
    "t": (pa.float64(), "s since the epoch (stamp_ns as seconds)"),
    "x": (pa.float64(), "m: base_link in the trajectory's own frame <method>/odom"),
    "y": (pa.float64(), "m: base_link in <method>/odom"),
    "yaw": (pa.float64(), "rad in [-pi, pi): heading of base_link in <method>/odom, counter-clockwise from x"),
    "v": (pa.float64(), "m/s: forward speed of base_link over the sweep (the twist used to deskew it)"),
    "omega": (pa.float64(), "rad/s: yaw rate over the sweep, counter-clockwise positive"),
    "icp_iterations": (pa.int64(), "ICP iterations (null for wheel_odometry)"),
    "correspondences": (pa.int64(), "point pairs kept by the last ICP iteration (null for wheel_odometry)"),
    "moving_points": (pa.int64(), "points judged moving and left out (null for wheel_odometry)"),
    "keyframe": (pa.bool_(), "the sweep's points entered the method's map (null for wheel_odometry)"),
    "ms": (pa.float64(), "ms of processing time for this sweep (null for wheel_odometry)"),
    "x_frontend": (pa.float64(), "m: the front end's own estimate of x, before the back end corrected it "
                                 "(equal to x without a back end; null for wheel_odometry)"),
    "y_frontend": (pa.float64(), "m: the front end's own y (null for wheel_odometry)"),
    "yaw_frontend": (pa.float64(), "rad: the front end's own yaw (null for wheel_odometry)"),
}
def write_tum(path: Path, stamps_ns: np.ndarray, poses: np.ndarray) -> None:
    """TUM trajectory file: seconds (9 decimals), position (m), quaternion (x, y, z, w)."""
    q = yaw_to_quaternion(poses[:, 2]).tolist()  # Python floats: the same digits, without numpy scalars per value
    t = np.asarray(stamps_ns, dtype=np.int64)
    xy = np.asarray(poses, dtype=np.float64)[:, :2].tolist()
    lines = [
        f"{s // 1_000_000_000}.{s % 1_000_000_000:09d} {p[0]:.6f} {p[1]:.6f} 0.0 "
        f"{qq[0]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f}"
        for s, p, qq in zip(t.tolist(), xy, q)
    ]
    path.write_text("\n".join(lines) + ("\n" if lines else ""))


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (s) and poses (N, 3) of a planar TUM file.

    A file that is not one (a line without 8 numbers, a NaN, stamps that go backwards or
    repeat, a quaternion of zero length) raises :class:`ReportError` naming it and the line.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: numpy warns, we return no poses
            a = np.loadtxt(path, ndmin=2, comments="#")
    except OSError as exc:
        raise ReportError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: not a TUM trajectory ({str(exc).splitlines()[0] if str(exc) else 'unreadable'}); "
                          "each line is t x y z qx qy qz qw") from None
    if a.size == 0:
        return np.zeros(0), np.zeros((0, 3))
    if a.shape[1] != 8:
        raise ReportError(f"{path}: lines have {a.shape[1]} values, a TUM pose has 8 (t x y z qx qy qz qw)")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise ReportError(f"{path}: pose {int(np.argmax(bad)) + 1} holds a value that is not finite")
    back = np.diff(a[:, 0]) <= 0
    if back.any():
        raise ReportError(f"{path}: stamps do not increase at pose {int(np.argmax(back)) + 2}")
    norm = np.linalg.norm(a[:, 4:8], axis=1)
    if (norm < 1e-6).any():
        raise ReportError(f"{path}: pose {int(np.argmax(norm < 1e-6)) + 1} has a zero quaternion")
    return a[:, 0], np.column_stack([a[:, 1], a[:, 2], quaternion_to_yaw(a[:, 4], a[:, 5], a[:, 6], a[:, 7])])


_NUMPY_DTYPE = {pa.bool_(): bool, pa.int64(): np.int64, pa.float64(): np.float64}  # the parquet's non-string kinds


def _arrow_strings(values: list, valid: np.ndarray) -> pa.Array:
    """A string column: int32 offsets and the UTF-8 bytes, with a validity bitmap (LSB first)."""
    n = len(values)
    bitmap = None if valid.all() else pa.py_buffer(np.packbits(valid, bitorder="little"))
    encoded = [b"" if v is None else str(v).encode() for v in values]
    offsets = np.zeros(n + 1, np.int32)
    np.cumsum([len(b) for b in encoded], out=offsets[1:])
    return pa.Array.from_buffers(pa.string(), n, [bitmap, pa.py_buffer(offsets), pa.py_buffer(b"".join(encoded))])


def _arrow_from_numpy(data: np.ndarray, valid: np.ndarray, kind: pa.DataType) -> pa.Array:
    """A numeric or boolean Arrow array of ``data`` (0 in the null slots) where ``valid``.

    ``pa.array`` imports pandas on its first call (0.5 s, a quarter of ``process`` on a 20 s
    log); the buffers are Arrow's documented layout: a validity bitmap (LSB first), then the
    values (bit-packed for booleans).
    """
    n = len(data)
    bitmap = None if valid.all() else pa.py_buffer(np.packbits(valid, bitorder="little"))
    data = np.ascontiguousarray(data, _NUMPY_DTYPE[kind])
    if pa.types.is_boolean(kind):
        return pa.Array.from_buffers(kind, n, [bitmap, pa.py_buffer(np.packbits(data, bitorder="little"))])
    return pa.Array.from_buffers(kind, n, [bitmap, pa.py_buffer(data)])


_INT_COLUMNS = ("stamp_ns", "icp_iterations", "correspondences", "moving_points", "keyframe")  # keyframe as 0/1
_FLOAT_COLUMNS = tuple(k for k, (t, _) in PARQUET_COLUMNS.items() if t == pa.float64() and k != "t")


class TrajectoryRows:
    """The parquet's rows, kept column-wise in numpy (int64 and float64 blocks with a validity mask)
    rather than as a Python object per value: 8 bytes a value instead of ~40 on a long log. The
    values are stored as given (an int64 stays exact, a float64 the same float64)."""

    INTS = _INT_COLUMNS
    FLOATS = _FLOAT_COLUMNS

    def __init__(self) -> None:
        self.method: list[str] = []  # a reference per row to one of a few shared strings
        self._ints = GrowingArray(np.int64, (len(self.INTS),))
        self._floats = GrowingArray(np.float64, (len(self.FLOATS),))
        self._valid = GrowingArray(bool, (len(self.INTS) + len(self.FLOATS),))

    def __len__(self) -> int:
        return len(self.method)

    def add(self, values: dict) -> None:
        """One row: ``values`` by column name (units in the schema's metadata); a column left out is null."""
        ints = [values.get(k) for k in self.INTS]
        floats = [values.get(k) for k in self.FLOATS]
        self.method.append(values["method"])
        # tuples: GrowingArray stores them a batch at a time, where a list is converted on its own
        self._ints.append(tuple(0 if v is None else v for v in ints))
        self._floats.append(tuple(0 if v is None else v for v in floats))
        self._valid.append(tuple(v is not None for v in ints + floats))

    def column(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Column ``name``'s values (0 where null, a view for the float columns) and validity."""
        if name in self.INTS:
            i = self.INTS.index(name)
            return self._ints.values[:, i], self._valid.values[:, i]
        i = self.FLOATS.index(name)
        return self._floats.values[:, i], self._valid.values[:, len(self.INTS) + i]

    def set_pose(self, rows: np.ndarray, poses: np.ndarray) -> None:
        """Replace ``x, y, yaw`` of ``rows`` by ``poses`` (len(rows), 3)."""
        cols = [self.FLOATS.index(k) for k in ("x", "y", "yaw")]
        self._floats.values[np.asarray(rows, np.int64)[:, None], cols] = poses

    def arrow(self, name: str, kind: pa.DataType, rows: slice = slice(None)) -> pa.Array:
        """Column ``name`` as an Arrow array of type ``kind``, nulls where no value was given; of the
        rows ``rows`` only (a slice), where given."""
        if name == "method":
            method = self.method[rows]
            return _arrow_strings(method, np.ones(len(method), bool))
        if name == "t":
            stamps, valid = self.column("stamp_ns")
            return _arrow_from_numpy(stamps[rows] * 1e-9, valid[rows], kind)
        values, valid = self.column(name)
        return _arrow_from_numpy(values[rows], valid[rows], kind)


PARQUET_ROW_GROUP = 4096  # rows: the parquet is written a row group at a time, so the writer's buffers stay small


def write_trajectories_parquet(path: Path, rows: TrajectoryRows) -> None:
    """A row per sweep and trajectory; the schema's metadata says each column's unit and frame.
    Written in row groups of :data:`PARQUET_ROW_GROUP` rows, each made from the rows as it is
    written: the writer buffers a whole row group (~600 bytes a row), so one group of a 20-minute
    log's 36,000 rows added ~23 MB at the run's end."""
    meta = {f"fmcwlog.column.{k}": doc for k, (_, doc) in PARQUET_COLUMNS.items()}
    meta.update({"fmcwlog.frames": "each trajectory in its own frame <method>/odom, starting at its origin; "
                                   "base_link is the rear-axle midpoint (REP-105)",
                 "fmcwlog.angles": "radians, counter-clockwise positive, z up (REP-103)"})
    schema = pa.schema([(k, t) for k, (t, _) in PARQUET_COLUMNS.items()]).with_metadata(meta)
    # the file opened here: Arrow takes a path as UTF-8, which a name need not be
    with open(path, "wb") as fh, pq.ParquetWriter(fh, schema) as writer:
        for start in range(0, max(len(rows), 1), PARQUET_ROW_GROUP):  # an empty table: one empty group
            part = slice(start, start + PARQUET_ROW_GROUP)
            writer.write_table(pa.table({k: rows.arrow(k, t, part) for k, (t, _) in PARQUET_COLUMNS.items()},
                                        schema=schema))
    # Arrow's allocator (mimalloc) keeps the writer's freed buffers resident (26 MB for 36,000 rows):
    # give them back, so that what runs after the write does not stand on them
    pa.default_memory_pool().release_unused()


def write_grid(folder: Path, name: str, grid: OccupancyGrid) -> None:
    """``name.pgm`` + ``name.yaml`` (map_server) and ``name.png`` (a picture of the same, 8-bit grey).

    Pillow writes the PNG: matplotlib's ``imsave`` takes 0.5 s a run to import and 0.2 s a map.
    """
    from PIL import Image

    pgm = grid.to_pgm_bytes()
    (folder / f"{name}.pgm").write_bytes(pgm)
    (folder / f"{name}.yaml").write_text(grid.map_server_yaml(f"{name}.pgm"))
    Image.fromarray(pgm_pixels(pgm), mode="L").save(folder / f"{name}.png", format="PNG")


def pgm_pixels(data: bytes) -> np.ndarray:
    """Pixels of a binary (P5) PGM with 8-bit samples."""
    parts: list[bytes] = []
    pos = 0
    while len(parts) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        parts.append(data[pos:end])
        pos = end
    w, h = int(parts[1]), int(parts[2])
    return np.frombuffer(data, np.uint8, count=w * h, offset=pos + 1).reshape(h, w)


def _cloud(stamp: Stamp, frame: str, xy: np.ndarray, velocity: np.ndarray | None) -> bytes:
    """A PointCloud2 of float32 ``x, y, z`` (0) and ``velocity`` if given, packed point by point."""
    columns: dict[str, np.ndarray | None] = {"x": xy[:, 0], "y": xy[:, 1], "z": None}
    if velocity is not None:
        columns["velocity"] = velocity
    return float32_cloud_cdr(stamp, frame, len(xy), columns)


def _planar_twist(v: float, omega: float) -> tuple[float, ...]:
    """A Twist's linear and angular parts (vx, vy, vz, wx, wy, wz) of a forward speed and a yaw rate."""
    return float(v), 0.0, 0.0, 0.0, 0.0, float(omega)


_TEN_DEGREES = np.radians(10)  # rad: a published path keeps a pose at least this far turned from the last


class PathPoses:
    """A published path's poses in ``frame``, as numbers: the stamp (ns) and the 7 float64 of the
    pose (:func:`~fmcwlog.io.messages.pose7`) each, 64 bytes a pose where a tuple of Python objects
    per pose held ~420; encoded by :func:`~fmcwlog.io.mcap_log.path_cdr_arrays`."""

    def __init__(self, frame: str):
        self.frame = frame
        self._stamps = GrowingArray(np.int64)
        self._poses = GrowingArray(np.float64, (7,))

    def append(self, stamp_ns: int, pose: Pose7) -> None:
        """One pose (the 7 numbers of a ``geometry_msgs/Pose``, m) at ``stamp_ns`` (ns since the epoch)."""
        self._stamps.append(stamp_ns)
        self._poses.append(pose)

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def stamps_ns(self) -> np.ndarray:
        """(N,) int64 ns: each pose's stamp."""
        return self._stamps.values

    @property
    def poses(self) -> np.ndarray:
        """(N, 7) float64: each pose's pose7."""
        return self._poses.values


ODOMETRY, POINTCLOUD2 = "nav_msgs/msg/Odometry", "sensor_msgs/msg/PointCloud2"
POINT_LABELS = "fmcwlog_msgs/msg/PointLabels"
PUBLISH_BYTES_PER_S = 1e6  # paths and maps put into processed.mcap, at most, per second of log (before compression)


SweepMessages = list[tuple[str, str, bytes]]  # (topic, type, CDR bytes) of processed.mcap


def sweep_messages(r: SweepResult, pose: Pose7 | None = None) -> SweepMessages:
    """What ``processed.mcap`` holds of one method's result for one sweep, in its order: ``/M/odom``
    (Odometry with the twist and the registration's covariance), ``/M/points/static`` and
    ``/M/points/moving`` (in ``M/odom``, with their ``velocity``), and where the method segmented
    the sweep ``/M/moving_labels`` (in ``M/lidar``, index for index with the input sweep, 1 = moving).
    ``pose``: :func:`~fmcwlog.io.messages.pose7` of ``r.pose``, where the caller has it."""
    at, frame = stamp_pair(r.stamp_ns), odom_frame(r.method)
    pose = pose7(r.pose) if pose is None else pose
    twist_cov = None
    if r.twist_covariance is not None:  # (v, ω) -> (vx, vy, wz); vy is 0 by the rear axle's constraint
        twist_cov = np.zeros((3, 3))
        twist_cov[np.ix_([0, 2], [0, 2])] = r.twist_covariance
    out = [(f"/{r.method}/odom", ODOMETRY, odometry_cdr(
               at, frame, base_frame(r.method), pose, planar_covariance(r.pose_covariance),
               _planar_twist(r.twist[0], r.twist[1]), planar_covariance(twist_cov))),
           (f"/{r.method}/points/static", POINTCLOUD2, _cloud(at, frame, r.static_map_xy, r.static_velocity)),
           (f"/{r.method}/points/moving", POINTCLOUD2, _cloud(at, frame, r.moving_map_xy, r.moving_velocity))]
    if r.segmented:
        out.append((f"/{r.method}/moving_labels", POINT_LABELS, point_labels_cdr(
            at, lidar_frame(r.method), np.asarray(r.moving_mask, np.uint8).tobytes())))
    return out


class ProcessOutputs:
    """Everything ``fmcwlog process`` writes into its (temporary) output folder, fed sweep by sweep.

    ``processed.mcap`` is streamed; trajectories and the parquet rows are kept (a few numbers
    per sweep) and written by :meth:`finish`, with the maps and ``/tf`` (the trajectories as
    they end up, a back end's correction included). ``mount`` (x, y, yaw of the lidar in
    base_link; ``upside_down``: rolled by π about its x axis too, as the input's sensor frame is)
    goes to ``/tf_static`` with each ``map -> M/odom``; paths and maps are published
    every ``publish_period`` seconds of log.
    """

    def __init__(self, folder: Path, trajectories: tuple[str, ...], mount: np.ndarray,
                 publish_period: float = 5.0, publish_bytes_per_s: float = PUBLISH_BYTES_PER_S,
                 upside_down: bool = False):
        self.folder = folder
        self.writer = LogWriter(folder / "processed.mcap")
        self.rows = TrajectoryRows()
        # per trajectory: stamps (ns) and poses (x, y, yaw), in numpy (a few bytes a sweep on a long log)
        self.trajectories: dict[str, tuple[GrowingArray, GrowingArray]] = {
            name: (GrowingArray(np.int64), GrowingArray(np.float64, (3,))) for name in trajectories}
        self._decimated = {name: PathPoses(odom_frame(name)) for name in trajectories}  # the published paths
        self._kept: dict[str, np.ndarray] = {}  # per trajectory, the last pose its decimated path kept
        self.mount = np.asarray(mount, dtype=float)
        self.upside_down = upside_down
        self.publish_period_ns = int(publish_period * 1e9)
        self.publish_bytes_per_s = float(publish_bytes_per_s)
        self._next_publish: int | None = None
        self.publishes = 0  # times end_sweep published the paths and maps
        self._static_written = False  # /tf_static, once, at the first pose
        self.frontend: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # the front end's trajectories a back end corrected

    @property
    def next_publish_ns(self) -> int | None:
        """Log time (ns) from which :meth:`end_sweep` publishes the paths and maps next; None before
        the first sweep. It moves only when they are published."""
        return self._next_publish

    def _row(self, **values) -> None:
        self.rows.add(values)

    def _track(self, name: str, stamp_ns: int, pose: np.ndarray) -> tuple[Stamp, Pose7]:
        """Keep the pose; the published paths keep one pose per 0.25 m or 10 deg of motion. Returns
        the stamp and the pose as messages carry them."""
        at, p7 = stamp_pair(stamp_ns), pose7(pose)
        self.trajectories[name][0].append(stamp_ns)
        self.trajectories[name][1].append(pose)
        kept = self._kept.get(name)
        if kept is None or np.hypot(pose[0] - kept[0], pose[1] - kept[1]) >= 0.25 or \
                abs((pose[2] - kept[2] + np.pi) % (2 * np.pi) - np.pi) >= _TEN_DEGREES:
            self._kept[name] = pose
            self._decimated[name].append(stamp_ns, p7)
        return at, p7

    def _static(self, stamp_ns: int) -> None:
        """``/tf_static``, once: each trajectory's ``map -> M/odom`` (the identity: every estimate
        starts at its origin) and ``M/base_link -> M/lidar`` (the input's mount, its roll included: the
        frame of the input's points, which ``/M/moving_labels`` index)."""
        if self._static_written:
            return
        self._static_written = True
        origin = np.zeros(3)
        self.writer.write(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", tf_message(
            [t for n in self.trajectories for t in (transform_dict(stamp_ns, MAP_FRAME, odom_frame(n), origin),
                                                    transform_dict(stamp_ns, base_frame(n), lidar_frame(n),
                                                                   self.mount, self.upside_down))]), stamp_ns)

    def add(self, r: SweepResult, messages: SweepMessages | None = None) -> None:
        """One method's result for one sweep; ``messages``: its :func:`sweep_messages` where they were
        encoded already (by the process that ran the method), else they are encoded here."""
        self._static(r.stamp_ns)
        if self._next_publish is None:  # the first sweep
            self._next_publish = r.stamp_ns + self.publish_period_ns
        self._row(method=r.method, stamp_ns=r.stamp_ns, x=r.pose[0], y=r.pose[1], yaw=r.pose[2], v=r.twist[0],
                  omega=r.twist[1], icp_iterations=r.iterations, correspondences=r.correspondences,
                  moving_points=r.moving_points, keyframe=r.keyframe, ms=r.ms, x_frontend=r.pose[0],
                  y_frontend=r.pose[1], yaw_frontend=r.pose[2])
        _, pose = self._track(r.method, r.stamp_ns, r.pose)
        for topic, datatype, data in sweep_messages(r, pose) if messages is None else messages:
            self.writer.write_cdr(topic, datatype, data, r.stamp_ns)

    def add_pose(self, name: str, stamp_ns: int, pose: np.ndarray, twist: tuple[float, float] | None) -> None:
        """A pose of a trajectory that is not a method's (the motion prior's), and its twist if known."""
        v, omega = twist if twist is not None else (None, None)
        self._static(stamp_ns)
        self._row(method=name, stamp_ns=stamp_ns, x=pose[0], y=pose[1], yaw=pose[2], v=v, omega=omega)
        at, p = self._track(name, stamp_ns, pose)
        zeros = planar_covariance(None)
        self.writer.write_cdr(f"/{name}/odom", ODOMETRY, odometry_cdr(
            at, odom_frame(name), base_frame(name), p, zeros, _planar_twist(v or 0.0, omega or 0.0), zeros), stamp_ns)

    def end_sweep(self, stamp_ns: int, grids: dict[str, OccupancyGrid]) -> None:
        """The end of a sweep: the paths and maps when they are due."""
        if self._next_publish is None:  # no method's result yet (only the motion prior's poses)
            self._next_publish = stamp_ns + self.publish_period_ns
        if stamp_ns >= self._next_publish:
            size = self._publish(stamp_ns, grids)
            self.publishes += 1
            # every publish_period, unless the maps and paths have grown so large that this would write
            # more than publish_bytes_per_s per second of log: each publish repeats them whole, so a
            # fixed period is quadratic in a long log's length (MIT Killian, 2.1 h: 1,535 maps of 25
            # million cells each, a 1.08 GB processed.mcap and 33 of its 35 minutes of processing)
            wait_ns = max(self.publish_period_ns, int(size / self.publish_bytes_per_s * 1e9))
            self._next_publish = stamp_ns + wait_ns

    def _publish(self, stamp_ns: int, grids: dict[str, OccupancyGrid], final: bool = False) -> int:
        """Each path so far (decimated; whole when ``final``) and each map; returns their size (bytes,
        before compression: 56 a pose, 1 a cell)."""
        size = 0
        for name, (stamps, poses) in self.trajectories.items():
            # the whole path (final) from the kept numpy rows, or the decimated one
            if final:
                path_stamps, path_poses = stamps.values, pose7_array(poses.values)
            else:
                path_stamps, path_poses = self._decimated[name].stamps_ns, self._decimated[name].poses
            if len(path_stamps):
                self.writer.write_cdr(f"/{name}/path", "nav_msgs/msg/Path", path_cdr_arrays(
                    stamp_pair(stamp_ns), odom_frame(name), odom_frame(name), path_stamps, path_poses), stamp_ns)
                size += 56 * len(path_stamps)
        for name, grid in grids.items():
            if grid.width:
                size += grid.width * grid.height
                self.writer.write(f"/{name}/map", "nav_msgs/msg/OccupancyGrid", occupancy_grid_message(
                    stamp_ns, odom_frame(name), grid.resolution, grid.width, grid.height, grid.origin,
                    grid.to_ros_int8()), stamp_ns)
        return size

    def correct(self, name: str, poses: np.ndarray) -> None:
        """Replace trajectory ``name``'s poses (S, 3), sweep for sweep, by a back end's; the front
        end's stay in ``self.frontend`` (written as ``<name>_frontend.tum``) and in the parquet's
        ``*_frontend`` columns."""
        stamps, before = self.trajectories[name]
        poses = np.asarray(poses, float)
        if len(poses) != len(before):
            raise ValueError(f"{name}: {len(poses)} corrected poses for {len(before)} sweeps")
        self.frontend[name] = (stamps.values.copy(), before.values.copy())
        before.values[:] = poses
        rows = [i for i, m in enumerate(self.rows.method) if m == name]
        self.rows.set_pose(np.array(rows, np.int64), poses[: len(rows)])

    def _write_tf(self) -> None:
        """Every trajectory's poses as they end up (a back end's where it corrected them: those of
        ``<M>.tum``) as ``M/odom -> M/base_link`` on ``/tf``: one message a sweep, holding each
        trajectory's pose at its stamp. Written last, in stamp order: readers go by log time."""
        kept = [(n, stamps.values, poses.values) for n, (stamps, poses) in self.trajectories.items() if len(stamps)]
        if not kept:
            return
        stamps = np.concatenate([s for _, s, _ in kept])
        which = np.concatenate([np.full(len(s), i) for i, (_, s, _) in enumerate(kept)])
        row = np.concatenate([np.arange(len(s)) for _, s, _ in kept])
        order = np.lexsort((which, stamps))  # by stamp, then in the trajectories' order
        stamps, which, row = stamps[order], which[order], row[order]
        starts = np.flatnonzero(np.r_[True, stamps[1:] != stamps[:-1]])
        ends = np.r_[starts[1:], len(stamps)]
        frames = [(odom_frame(n), base_frame(n)) for n, _, _ in kept]
        poses7 = [pose7_array(poses) for _, _, poses in kept]
        # the messages of one set of trajectories share a layout: encoded together (tf_cdr_arrays)
        groups: dict[tuple[int, ...], list[int]] = {}
        for m, (a, b) in enumerate(zip(starts.tolist(), ends.tolist())):
            groups.setdefault(tuple(which[a:b].tolist()), []).append(m)
        data: list[bytes] = [b""] * len(starts)
        for members, messages in groups.items():
            first = starts[messages]
            poses = np.stack([poses7[i][row[first + k]] for k, i in enumerate(members)], axis=1)
            for m, encoded in zip(messages, tf_cdr_arrays(stamps[first], [frames[i] for i in members], poses)):
                data[m] = encoded
        for ns, encoded in zip(stamps[starts].tolist(), data):
            self.writer.write_cdr(TF_TOPIC, "tf2_msgs/msg/TFMessage", encoded, ns)

    def ms_median(self) -> dict[str, float]:
        """Per trajectory, the median processing time of its sweeps (ms); those never timed are left out."""
        method = np.asarray(self.rows.method)
        values, valid = self.rows.column("ms")
        ms = np.where(valid, values, np.nan)
        return {m: float(np.median(ms[method == m])) for m in dict.fromkeys(self.rows.method)
                if np.isfinite(ms[method == m]).any()}

    def finish(self, grids: dict[str, OccupancyGrid]) -> None:
        """The last paths and maps, ``processed.mcap`` closed; the trajectories, the map files, the parquet."""
        last_ns = int(self.rows.column("stamp_ns")[0][-1])
        self._publish(last_ns, grids, final=True)
        self._write_tf()
        self.writer.close()
        for method, grid in grids.items():
            write_grid(self.folder, f"{method}_map", grid)
        for name, (stamps, poses) in self.trajectories.items():
            if len(stamps):
                write_tum(self.folder / f"{name}.tum", stamps.values, poses.values)
        for name, (before_stamps, before) in self.frontend.items():
            if len(before_stamps):
                write_tum(self.folder / f"{name}_frontend.tum", before_stamps, before)
        release_freed_memory()  # the parquet writer's buffers come from Arrow's allocator, not this heap
        write_trajectories_parquet(self.folder / "trajectories.parquet", self.rows)

    def abort(self) -> None:
        """Drop ``processed.mcap``'s partial file (after a failure)."""
        self.writer.abort()
