"""Reading and writing fmcwlog logs: the one module that knows MCAP and CDR.

The log format is the contract in ``LOG_FORMAT.md`` (kept beside the project
in ``shared/``): MCAP with the ``ros2`` profile, CDR-encoded messages whose
``ros2msg`` schemas are the ``.msg`` texts in ``schemas/``, concatenated with
their dependencies the way ROS 2's MCAP storage plugin writes them.

Writing goes through ``mcap_ros2.writer``; reading through ``mcap`` and
``mcap_ros2.decoder``. Readers locate point fields by name and offset, accept
compressed or uncompressed chunks, and fall back to a sequential scan when a
file has no summary (a recording cut off before it finished).
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from .geometry import quaternion_to_yaw, yaw_to_quaternion

SCHEMA_DIR = Path(__file__).parent / "schemas"

POINTS_TOPIC = "/fmcw/points"
TICKS_TOPIC = "/wheel/ticks"
GT_ODOM_TOPIC = "/ground_truth/odom"
GT_LABELS_TOPIC = "/ground_truth/point_labels"
CALIBRATION_KEY = "fmcwlog.calibration"
WORLD_KEY = "fmcwlog.world"

_SEPARATOR = "=" * 80
_FIELD_TYPE = re.compile(r"^\s*([A-Za-z_][\w/]*)(\[\d*\])?\s+\w+")
_PRIMITIVES = {
    "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32",
    "int64", "uint64", "float32", "float64", "string", "wstring",
}

# PointField datatype codes (sensor_msgs/PointField) -> numpy dtypes, little-endian.
_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}
FLOAT32 = 7


class LogError(Exception):
    """A log cannot be read or written; the message names the file and the problem."""


# --------------------------------------------------------------------------- schemas


def _msg_path(datatype: str) -> Path:
    pkg, _, name = datatype.split("/")
    return SCHEMA_DIR / pkg / "msg" / f"{name}.msg"


def _dependencies(datatype: str, text: str) -> list[str]:
    """Full names of the non-primitive types a .msg text refers to."""
    pkg = datatype.split("/")[0]
    deps = []
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        if "=" in line:  # a constant
            continue
        m = _FIELD_TYPE.match(line)
        if not m:
            continue
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        if t == "Header":
            t = "std_msgs/Header"
        parts = t.split("/")
        full = f"{pkg}/msg/{t}" if len(parts) == 1 else f"{parts[0]}/msg/{parts[-1]}"
        deps.append(full)
    return deps


def message_definition(datatype: str) -> str:
    """The ``ros2msg`` schema text of ``datatype`` (e.g. ``sensor_msgs/msg/PointCloud2``).

    The type's own .msg text followed by each dependency, depth first, after a
    line of 80 ``=`` and ``MSG: pkg/msg/Type``, as ``rosbag2`` writes them.
    """
    own = _msg_path(datatype).read_text()
    seen: list[str] = []

    def visit(t: str, text: str) -> None:
        for dep in _dependencies(t, text):
            if dep not in seen:
                seen.append(dep)
                visit(dep, _msg_path(dep).read_text())

    visit(datatype, own)
    parts = [own.rstrip("\n")]
    for dep in seen:
        parts.append(f"{_SEPARATOR}\nMSG: {dep}\n{_msg_path(dep).read_text().rstrip(chr(10))}")
    return "\n".join(parts) + "\n"


# --------------------------------------------------------------------------- messages


def stamp(ns: int) -> dict[str, int]:
    """``builtin_interfaces/Time`` from integer nanoseconds since the epoch."""
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def stamp_ns(t: Any) -> int:
    """Integer nanoseconds from a decoded ``builtin_interfaces/Time``."""
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


POINT_FIELDS = ("x", "y", "z", "intensity", "velocity", "t")


def pointcloud_message(stamp_ns_: int, frame_id: str, columns: dict[str, np.ndarray]) -> dict:
    """A ``sensor_msgs/PointCloud2`` dict with one FLOAT32 field per column, packed in order."""
    names = list(columns)
    n = len(next(iter(columns.values()))) if names else 0
    packed = np.empty((n, len(names)), dtype="<f4")
    for i, name in enumerate(names):
        packed[:, i] = columns[name]
    step = 4 * len(names)
    return {
        "header": {"stamp": stamp(stamp_ns_), "frame_id": frame_id},
        "height": 1,
        "width": n,
        "fields": [
            {"name": name, "offset": 4 * i, "datatype": FLOAT32, "count": 1}
            for i, name in enumerate(names)
        ],
        "is_bigendian": False,
        "point_step": step,
        "row_step": step * n,
        "data": packed.tobytes(),
        "is_dense": True,
    }


def pointcloud_columns(msg: Any, names: Iterable[str] = POINT_FIELDS) -> dict[str, np.ndarray]:
    """Columns of a decoded PointCloud2 as float64 arrays, located by field name and offset.

    Extra fields are ignored; a missing requested field raises ``KeyError``.
    """
    if msg.is_bigendian:
        raise ValueError("big-endian PointCloud2 is not supported")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = bytes(msg.data)
    if len(data) < n * step:
        raise ValueError(f"PointCloud2 data holds {len(data)} bytes, expected {n * step}")
    by_name = {f.name: f for f in msg.fields}
    out = {}
    for name in names:
        f = by_name[name]
        if f.datatype not in _POINTFIELD_DTYPES:
            raise ValueError(f"field {name!r} has unknown datatype {f.datatype}")
        dt = np.dtype(_POINTFIELD_DTYPES[f.datatype])
        if n == 0:
            out[name] = np.zeros(0)
            continue
        col = np.ndarray((n,), dtype=dt, buffer=data, offset=int(f.offset), strides=(step,))
        out[name] = col.astype(np.float64)
    return out


def odometry_message(
    stamp_ns_: int, frame_id: str, child_frame_id: str, pose: np.ndarray, twist: np.ndarray
) -> dict:
    """``nav_msgs/Odometry``: ``pose`` (x, y, yaw) in ``frame_id``, ``twist`` (vx, vy, wz) in ``child_frame_id``."""
    q = yaw_to_quaternion(pose[2])
    zeros = [0.0] * 36
    return {
        "header": {"stamp": stamp(stamp_ns_), "frame_id": frame_id},
        "child_frame_id": child_frame_id,
        "pose": {
            "pose": {
                "position": {"x": float(pose[0]), "y": float(pose[1]), "z": 0.0},
                "orientation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])},
            },
            "covariance": zeros,
        },
        "twist": {
            "twist": {
                "linear": {"x": float(twist[0]), "y": float(twist[1]), "z": 0.0},
                "angular": {"x": 0.0, "y": 0.0, "z": float(twist[2])},
            },
            "covariance": zeros,
        },
    }


def odometry_pose_twist(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y, yaw)`` and ``(vx, vy, wz)`` of a decoded ``nav_msgs/Odometry``."""
    p = msg.pose.pose.position
    q = msg.pose.pose.orientation
    tw = msg.twist.twist
    pose = np.array([p.x, p.y, float(quaternion_to_yaw(q.x, q.y, q.z, q.w))])
    return pose, np.array([tw.linear.x, tw.linear.y, tw.angular.z])


# --------------------------------------------------------------------------- writing


class LogWriter:
    """Writes an MCAP log to ``path`` via a temporary file renamed on :meth:`close`.

    Use as a context manager: on an exception the temporary file is removed and
    nothing is left at ``path``. Schemas are registered on first use.
    """

    def __init__(self, path: str | os.PathLike, compression: str = "zstd", chunk_size: int = 1 << 20):
        self.path = Path(path)
        self._tmp = self.path.with_name(f".{self.path.name}.partial")
        self._file: IO[bytes] = open(self._tmp, "wb")
        self._writer = Ros2Writer(
            self._file, chunk_size=chunk_size, compression=CompressionType[compression.upper() or "NONE"]
        )
        self._schemas: dict[str, Schema] = {}

    def _schema(self, datatype: str) -> Schema:
        if datatype not in self._schemas:
            self._schemas[datatype] = self._writer.register_msgdef(datatype, message_definition(datatype))
        return self._schemas[datatype]

    def write(self, topic: str, datatype: str, message: dict, log_time_ns: int) -> None:
        """Write one message; ``log_time`` is the message's ``header.stamp`` (LOG_FORMAT.md)."""
        self._writer.write_message(
            topic, self._schema(datatype), message, log_time=log_time_ns, publish_time=log_time_ns
        )

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        self._writer.add_metadata(name, values)

    def close(self) -> Path:
        """Finish the MCAP (summary and footer) and move it into place."""
        self._writer.finish()
        self._file.close()
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the partial file."""
        try:
            self._file.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# --------------------------------------------------------------------------- reading


@dataclass
class LogMessage:
    """One decoded message: its topic, schema name, ``log_time`` (ns) and decoded object."""

    topic: str
    datatype: str
    log_time_ns: int
    msg: Any


@dataclass
class LogContents:
    """What a scan of a log found besides its messages."""

    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    counts: dict[str, int] = field(default_factory=dict)  # topic -> messages, when the summary says
    truncated: bool = False


def _check_magic(path: Path, fh: IO[bytes]) -> None:
    head = fh.read(8)
    fh.seek(0)
    if head[:5] != b"\x89MCAP":
        raise LogError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


class LogReader:
    """Streams decoded messages of a log in file order, whoever wrote it.

    An indexed file is read through its summary; a file without one (cut off
    before the footer) is scanned record by record up to where it ends, and
    :attr:`contents.truncated` is set.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if self.path.is_dir():
            raise LogError(f"{self.path}: is a folder, not a log file")
        if not self.path.is_file():
            raise LogError(f"{self.path}: no such file")
        self.contents = LogContents()
        self._decoders: dict[int, Any] = {}
        self._factory = DecoderFactory()
        with open(self.path, "rb") as fh:
            _check_magic(self.path, fh)
            self._indexed = self._read_summary(fh)
        if not self._indexed:
            self._scan_headers()

    def _read_summary(self, fh: IO[bytes]) -> bool:
        try:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None:
                return False
            for ch in summary.channels.values():
                self.contents.topics[ch.topic] = summary.schemas[ch.schema_id].name
            if summary.statistics is not None:
                self.contents.counts = {summary.channels[c].topic: n
                                        for c, n in summary.statistics.channel_message_counts.items()}
            for md in reader.iter_metadata():
                self.contents.metadata[md.name] = dict(md.metadata)
            return True
        except (McapError, ValueError, AssertionError, EOFError, OSError):
            return False

    def _stream_records(self, fh: IO[bytes]) -> Iterator[Any]:
        reader = StreamReader(fh, skip_magic=False, emit_chunks=False)
        try:
            yield from reader.records
        except (McapError, EOFError, ValueError, AssertionError) as exc:
            if not self.contents.truncated:
                self.contents.truncated = True
                warnings.warn(f"{self.path}: log ends early ({type(exc).__name__}); reading up to where it ends")

    def _scan_headers(self) -> None:
        """Collect metadata and topics of an unindexed file with one sequential pass."""
        for _ in self._raw_messages(set()):
            pass

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        return self.contents.metadata

    @property
    def topics(self) -> dict[str, str]:
        return self.contents.topics

    def message_count(self, topic: str) -> int | None:
        """Messages on ``topic`` by the summary's statistics; None for an unindexed file."""
        return self.contents.counts.get(topic)

    def _raw_messages(self, wanted: set[str] | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Undecoded messages on the ``wanted`` topics (all when None), in file order; topics and
        metadata met on the way are noted in :attr:`contents` (an unindexed file has no summary).

        Always a sequential scan, chunk by chunk: memory stays at one chunk. (mcap's
        indexed reader held ~87 MB at its peak over a 5-minute log, growing with length.)
        """
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        with open(self.path, "rb") as fh:
            for rec in self._stream_records(fh):
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                    self.contents.topics.setdefault(rec.topic, schemas[rec.schema_id].name if rec.schema_id in schemas else "")
                elif isinstance(rec, Metadata):
                    self.contents.metadata.setdefault(rec.name, dict(rec.metadata))
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is not None and (wanted is None or ch.topic in wanted):
                        yield schemas.get(ch.schema_id), ch, rec

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """Decoded messages on ``topics`` (all when None), in file order."""
        for schema, channel, rec in self._raw_messages(None if topics is None else set(topics)):
            yield self._decode(schema, channel, rec)

    def log_times(self, topic: str) -> Iterator[int]:
        """``log_time`` (ns) of every message on ``topic``, without decoding them."""
        for _, _, rec in self._raw_messages({topic}):
            yield rec.log_time

    def _decode(self, schema: Schema | None, channel: Channel, message: Message) -> LogMessage:
        if schema is None:
            raise LogError(f"{self.path}: topic {channel.topic} has no schema")
        dec = self._decoders.get(channel.id)
        if dec is None:
            dec = self._factory.decoder_for(channel.message_encoding, schema)
            if dec is None:
                raise LogError(
                    f"{self.path}: topic {channel.topic} is encoded as {channel.message_encoding!r}, expected 'cdr'"
                )
            self._decoders[channel.id] = dec
        try:
            msg = dec(message.data)
        except Exception as exc:  # the CDR decoder raises several unrelated types
            raise LogError(f"{self.path}: cannot decode a message on {channel.topic} ({exc})") from exc
        return LogMessage(channel.topic, schema.name, message.log_time, msg)


# --------------------------------------------------------------------------- estimator inputs
#
# What ``fmcwlog process`` reads, as numpy records. Only the topics it is told
# to use are decoded: estimation never touches /ground_truth/* or fmcwlog.world.


@dataclass
class SweepInput:
    """One sweep in the sensor frame: points where the sensor saw them at their own time."""

    stamp_ns: int  # first beam
    xy: np.ndarray  # (N, 2) m, frame lidar
    t: np.ndarray  # (N,) s after stamp_ns
    velocity: np.ndarray | None  # (N,) m/s radial Doppler, None without Doppler
    intensity: np.ndarray | None


@dataclass
class TicksInput:
    stamp_ns: int
    left: int
    right: int


@dataclass
class OdomInput:
    stamp_ns: int
    pose: np.ndarray  # (3,) x, y, yaw in the odometry frame


def _finite(path: Path, what: str, stamp_ns_: int, *arrays: np.ndarray | None) -> None:
    for a in arrays:
        if a is not None and not np.all(np.isfinite(a)):
            raise LogError(f"{path}: {what} at stamp {stamp_ns_} holds NaN or infinite values")


def sweep_from_pointcloud(path: Path, msg: Any) -> SweepInput:
    """A PointCloud2 of the log format to a :class:`SweepInput` (fields by name and offset)."""
    ns = stamp_ns(msg.header.stamp)
    names = {f.name for f in msg.fields}
    missing = {"x", "y"} - names
    if missing:
        raise LogError(f"{path}: PointCloud2 at stamp {ns} has no field {sorted(missing)[0]!r}")
    wanted = [n for n in ("x", "y", "t", "velocity", "intensity") if n in names]
    try:
        cols = pointcloud_columns(msg, wanted)
    except ValueError as exc:
        raise LogError(f"{path}: PointCloud2 at stamp {ns}: {exc}") from None
    n = len(cols["x"])
    t = cols.get("t", np.zeros(n))
    vel, inten = cols.get("velocity"), cols.get("intensity")
    _finite(path, "PointCloud2", ns, cols["x"], cols["y"], t, vel)
    return SweepInput(ns, np.column_stack([cols["x"], cols["y"]]), t, vel, inten)


def sweep_from_laserscan(path: Path, msg: Any) -> SweepInput:
    """A ``sensor_msgs/LaserScan`` to a :class:`SweepInput` without Doppler.

    Ranges outside ``[range_min, range_max]`` or not finite are no return (REP-117).
    """
    ns = stamp_ns(msg.header.stamp)
    r = np.asarray(msg.ranges, dtype=float)
    i = np.arange(r.size)
    ang = msg.angle_min + i * msg.angle_increment
    ok = np.isfinite(r) & (r >= msg.range_min) & (r <= msg.range_max)
    inten = np.asarray(msg.intensities, dtype=float)[ok] if len(msg.intensities) == r.size else None
    xy = np.column_stack([r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])])
    return SweepInput(ns, xy, (i * float(msg.time_increment))[ok], None, inten)


def iter_inputs(
    reader: LogReader, scan_topic: str, ticks_topic: str | None, odom_topic: str | None
) -> Iterator[SweepInput | TicksInput | OdomInput]:
    """The estimator's inputs in file order: sweeps, and ticks or odometry as the motion prior."""
    topics = [t for t in (scan_topic, ticks_topic, odom_topic) if t]
    for m in reader.messages(topics):
        if m.topic == scan_topic:
            if m.datatype.endswith("PointCloud2"):
                yield sweep_from_pointcloud(reader.path, m.msg)
            else:
                yield sweep_from_laserscan(reader.path, m.msg)
        elif m.topic == ticks_topic:
            yield TicksInput(stamp_ns(m.msg.header.stamp), int(m.msg.left), int(m.msg.right))
        else:
            pose, _ = odometry_pose_twist(m.msg)
            _finite(reader.path, "Odometry", m.log_time_ns, pose)
            yield OdomInput(stamp_ns(m.msg.header.stamp), pose)


def read_ground_truth(reader: LogReader, topic: str = GT_ODOM_TOPIC) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth stamps (ns) and poses (N, 3) of ``base_link`` in ``map`` (evaluation only)."""
    stamps, poses = [], []
    for m in reader.messages([topic]):
        pose, _ = odometry_pose_twist(m.msg)
        stamps.append(stamp_ns(m.msg.header.stamp))
        poses.append(pose)
    return np.asarray(stamps, dtype=np.int64), np.asarray(poses).reshape(-1, 3)


def read_point_labels(reader: LogReader, topic: str = GT_LABELS_TOPIC) -> dict[int, np.ndarray]:
    """Per-sweep moving labels (uint8) keyed by sweep stamp (ns) (evaluation only)."""
    return {stamp_ns(m.msg.header.stamp): np.frombuffer(bytes(m.msg.moving), np.uint8)
            for m in reader.messages([topic])}
