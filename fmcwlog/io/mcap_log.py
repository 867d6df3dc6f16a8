"""Reading and writing MCAP logs: with :mod:`fmcwlog.io.mcap_scan`, the only code that knows the MCAP container.

The log format is a contract (docs/log-format.md): MCAP with the ``ros2`` profile,
CDR-encoded messages whose ``ros2msg`` schemas are the ``.msg`` texts in ``schemas/``
(:mod:`fmcwlog.io.schemas`), ``log_time`` equal to ``header.stamp``, times in nanoseconds
since the epoch.

Writing goes through ``mcap``'s writer with ``mcap_ros2``'s CDR encoders;
reading through :class:`fmcwlog.io.mcap_scan.McapScan` (``mcap``'s record parsers under
framing that steps over damage) and ``mcap_ros2.decoder``. Readers accept compressed or
uncompressed chunks, read a file without a summary (a recording cut off before it
finished) up to its end, and report each damaged place with its byte offset.
"""

from __future__ import annotations

import heapq
import os
import struct
import warnings
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from itertools import chain, islice
from pathlib import Path
from types import SimpleNamespace
from typing import IO, Any, Protocol

import numpy as np
from mcap.records import Channel, Message, Metadata, Schema
from mcap.well_known import SchemaEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2._dynamic import serialize_dynamic  # the CDR encoder mcap_ros2's own Writer uses
from mcap_ros2.decoder import DecoderFactory

from .. import __version__
from ..errors import LogError
from .atomic import partial_path
from .mcap_scan import Damaged, McapScan, Summary
from .messages import FLOAT32
from .schemas import message_definition

# Types whose last field is a large primitive array given as a numpy array: written as raw
# bytes after the rest is CDR-encoded, because mcap_ros2 encodes non-uint8 arrays element by
# element (0.13 s for a 280k-cell occupancy grid, against 0.1 ms this way; identical bytes).
_RAW_TAIL = {"nav_msgs/msg/OccupancyGrid": "data"}
# Message data a time-ordered read may queue before it reads the rest a topic at a time
# (LogReader.raw_messages_by_time): about 2,500 sweeps of 1,081 points.
MERGE_HOLD_BYTES = 64 << 20


_CDR_LE = b"\x00\x01\x00\x00"  # the encapsulation header: CDR, little endian
_U32, _STAMP, _TICKS, _POSE7 = struct.Struct("<I"), struct.Struct("<iI"), struct.Struct("<qq"), struct.Struct("<7d")
_ODOMETRY = struct.Struct("<85d")
_POINT_FIELD = struct.Struct("<IBxxxI")  # offset uint32, datatype uint8, padding, count uint32
_CLOUD_TAIL = struct.Struct("<III")  # point_step, row_step, the data's length
_BOOL = struct.Struct("<?")


def _pad(out: bytearray, size: int) -> None:
    """Align to ``size`` bytes; alignment counts from after the 4-byte encapsulation header."""
    out += bytes(-(len(out) - 4) % size)


def _string(out: bytearray, text: str) -> None:
    raw = text.encode()
    _pad(out, 4)
    out += _U32.pack(len(raw) + 1)
    out += raw
    out += b"\0"


def _octets(out: bytearray, data: bytes) -> None:
    """A ``uint8[]``: its length, then the bytes."""
    _pad(out, 4)
    out += _U32.pack(len(data))
    out += data


# Messages as ``process`` writes them, from numbers rather than dicts: a stamp is ``(sec, nanosec)``,
# a pose the 7 float64 of a Pose (:func:`pose7`). The dict encoders below go through the same code.
Stamp = tuple[int, int]
Pose7 = tuple[float, float, float, float, float, float, float]


def stamp_pair(ns: int) -> Stamp:
    """``(sec, nanosec)`` of integer nanoseconds, as :func:`fmcwlog.io.messages.stamp`."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return sec, nanosec


@lru_cache(maxsize=256)
def _after_stamp(names: tuple[str, ...], align: int) -> bytes:
    """What follows a message's leading stamp: each name a CDR string, then padding to ``align``. At
    a message's start the offsets are fixed, so these bytes are the same for every message."""
    out = bytearray(_CDR_LE + bytes(8))
    for name in names:
        _string(out, name)
    _pad(out, align)
    return bytes(out[12:])


def odometry_cdr(stamp: Stamp, frame_id: str, child_frame_id: str, pose: Pose7, pose_covariance: Sequence[float],
                 twist: Sequence[float], twist_covariance: Sequence[float]) -> bytes:
    """``nav_msgs/Odometry``: the stamp, the two frame names, then 85 float64 (pose, its 36
    covariances, twist (linear, angular: 6), its 36) in one block aligned to 8 bytes."""
    return b"".join((_CDR_LE, _STAMP.pack(*stamp), _after_stamp((frame_id, child_frame_id), 8),
                     _ODOMETRY.pack(*pose, *pose_covariance, *twist, *twist_covariance)))


def _odometry_cdr(m: dict) -> bytes:
    pose, twist = m["pose"], m["twist"]
    p, q = pose["pose"]["position"], pose["pose"]["orientation"]
    lin, ang = twist["twist"]["linear"], twist["twist"]["angular"]
    h = m["header"]
    return odometry_cdr((h["stamp"]["sec"], h["stamp"]["nanosec"]), h["frame_id"], m["child_frame_id"],
                        (p["x"], p["y"], p["z"], q["x"], q["y"], q["z"], q["w"]), pose["covariance"],
                        (lin["x"], lin["y"], lin["z"], ang["x"], ang["y"], ang["z"]), twist["covariance"])


def tf_cdr(transforms: Sequence[tuple[Stamp, str, str, Pose7]]) -> bytes:
    """``tf2_msgs/TFMessage`` of ``(stamp, parent, child, pose)``: the count, then per transform its
    header, child frame and 7 float64."""
    out = bytearray(_CDR_LE)
    out += _U32.pack(len(transforms))
    for stamp, parent, child, pose in transforms:
        _transform(out, stamp, parent, child, pose)
    return bytes(out)


def _transform(out: bytearray, stamp: Stamp, parent: str, child: str, pose: Pose7) -> tuple[int, int]:
    """One TransformStamped of a TFMessage; returns where in ``out`` its stamp and its pose begin."""
    _pad(out, 4)
    stamp_at = len(out)
    out += _STAMP.pack(*stamp)
    _string(out, parent)
    _string(out, child)
    _pad(out, 8)
    pose_at = len(out)
    out += _POSE7.pack(*pose)
    return stamp_at, pose_at


def tf_cdr_arrays(stamps_ns: np.ndarray, frames: Sequence[tuple[str, str]], poses: np.ndarray) -> list[bytes]:
    """:func:`tf_cdr` of M messages of the same K transforms (``frames``: parent and child of each),
    all of a message's at its stamp: ``stamps_ns`` (M,) int64 ns, ``poses`` (M, K, 7) float64 pose7s.
    One template (a message of these frames) repeated, with the stamps and poses written in by numpy:
    1,200 messages of 3 transforms in 1 ms, against 10 ms one by one."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    poses = np.asarray(poses, dtype=np.float64).reshape(len(stamps_ns), len(frames), 7)
    if len(stamps_ns) == 0:
        return []
    out = bytearray(_CDR_LE)
    out += _U32.pack(len(frames))
    at = [_transform(out, (0, 0), parent, child, (0.0,) * 7) for parent, child in frames]
    sec, nanosec = _stamp_columns(stamps_ns)
    names, formats, offsets = [], [], []
    for k, (stamp_at, pose_at) in enumerate(at):
        names += [f"sec{k}", f"nanosec{k}", f"pose{k}"]
        formats += ["<i4", "<u4", ("<f8", (7,))]
        offsets += [stamp_at, stamp_at + 4, pose_at]
    size = len(out)
    raw = bytearray(bytes(out) * len(stamps_ns))
    records = np.frombuffer(raw, np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size}))
    for k in range(len(frames)):
        records[f"sec{k}"], records[f"nanosec{k}"], records[f"pose{k}"] = sec, nanosec, poses[:, k]
    data = bytes(raw)
    return [data[i:i + size] for i in range(0, len(data), size)]


def _dict_pose7(position: dict, orientation: dict) -> Pose7:
    return (position["x"], position["y"], position["z"], orientation["x"], orientation["y"], orientation["z"],
            orientation["w"])


def _dict_stamp(header: dict) -> Stamp:
    return header["stamp"]["sec"], header["stamp"]["nanosec"]


def _tf_cdr(m: dict) -> bytes:
    return tf_cdr([(_dict_stamp(tr["header"]), tr["header"]["frame_id"], tr["child_frame_id"],
                    _dict_pose7(tr["transform"]["translation"], tr["transform"]["rotation"])) for tr in m["transforms"]])


class PathEntries(Protocol):
    """What :func:`path_cdr` reads: a count, then (stamp, frame, pose7) per pose (a list, or entries
    made as they are read)."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[tuple[Stamp, str, Pose7]]: ...


def path_cdr(stamp: Stamp, frame_id: str, poses: PathEntries) -> bytes:
    """``nav_msgs/Path``: its header, the count, then per pose its header and 7 float64. ``process``
    publishes each method's whole path every few seconds of log; through mcap_ros2's generic encoder
    that is 2.8 s of a 42 s ``process --method improved`` of the 200 s ring (cProfile). A 2,000-pose
    path: 26.3 ms there, 4.2 ms from dicts, 1.5 ms from numbers here."""
    out = bytearray(_CDR_LE)
    out += _STAMP.pack(*stamp)
    _string(out, frame_id)
    _pad(out, 4)
    out += _U32.pack(len(poses))
    names: dict[str, bytes] = {}
    for pose_stamp, frame, pose in poses:
        name = names.get(frame)
        if name is None:
            raw = frame.encode()
            name = names[frame] = _U32.pack(len(raw) + 1) + raw + b"\0"
        _path_pose(out, pose_stamp, name, pose)
    return bytes(out)


def _path_pose(out: bytearray, stamp: Stamp, name: bytes, pose: Pose7) -> None:
    """One of a Path's PoseStamped: its header (``name``: the frame as a CDR string), then the 7 float64."""
    _pad(out, 4)
    out += _STAMP.pack(*stamp)
    out += name  # a string at a 4-byte boundary (after the stamp): no padding before it
    _pad(out, 8)
    out += _POSE7.pack(*pose)


def path_cdr_arrays(stamp: Stamp, frame_id: str, pose_frame: str, stamps_ns: np.ndarray, poses: np.ndarray) -> bytes:
    """:func:`path_cdr` of poses that share one frame, given as arrays: ``stamps_ns`` (N,) int64 ns and
    ``poses`` (N, 7) float64, each a pose7; the same bytes. The first pose is encoded as path_cdr does;
    it ends 8-aligned, so every later pose has the layout of one encoded at the start, and those are
    that template repeated with the stamps and poses written in by numpy (:func:`_batch_bytes`): a
    1,200-pose path 0.2 ms, where path_cdr reads it pose by pose in 1.2 ms (3.7 ms making pose7 per pose)."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
    if len(stamps_ns) != len(poses):
        raise ValueError(f"{len(stamps_ns)} stamps for {len(poses)} poses")
    if len(stamps_ns) == 0:
        return path_cdr(stamp, frame_id, [])
    first = (stamp_pair(int(stamps_ns[0])), pose_frame, tuple(poses[0].tolist()))
    head = path_cdr(stamp, frame_id, _Counted([first], len(stamps_ns)))
    template = bytearray(_CDR_LE)  # a pose encoded at an 8-aligned start
    raw = pose_frame.encode()
    _path_pose(template, (0, 0), _U32.pack(len(raw) + 1) + raw + b"\0", (0.0,) * 7)
    return head + _batch_bytes(bytes(template[4:]), 0, stamps_ns[1:], poses[1:])


class _Counted:
    """Path entries that say there are ``count`` of them but give only ``entries`` (the rest follow)."""

    def __init__(self, entries: list, count: int):
        self.entries, self.count = entries, count

    def __len__(self) -> int:
        return self.count

    def __iter__(self) -> Iterator[tuple[Stamp, str, Pose7]]:
        return iter(self.entries)


def _path_cdr(m: dict) -> bytes:
    return path_cdr(_dict_stamp(m["header"]), m["header"]["frame_id"], [
        (_dict_stamp(p["header"]), p["header"]["frame_id"], _dict_pose7(p["pose"]["position"], p["pose"]["orientation"]))
        for p in m["poses"]])


def wheel_ticks_cdr(stamp: Stamp, frame_id: str, left: int, right: int) -> bytes:
    """``fmcwlog_msgs/WheelTicks``: its header, then the two int64 counts aligned to 8 bytes."""
    return b"".join((_CDR_LE, _STAMP.pack(*stamp), _after_stamp((frame_id,), 8), _TICKS.pack(left, right)))


def _wheel_ticks_cdr(m: dict) -> bytes:
    return wheel_ticks_cdr(_dict_stamp(m["header"]), m["header"]["frame_id"], m["left"], m["right"])


def point_labels_cdr(stamp: Stamp, frame_id: str, moving: bytes) -> bytes:
    """``fmcwlog_msgs/PointLabels``: its header, then the ``uint8[]`` of labels."""
    out = bytearray(_CDR_LE)
    out += _STAMP.pack(*stamp)
    _string(out, frame_id)
    _octets(out, moving)
    return bytes(out)


def _point_labels_cdr(m: dict) -> bytes:
    return point_labels_cdr(_dict_stamp(m["header"]), m["header"]["frame_id"], m["moving"])


PointField = tuple[str, int, int, int]  # name, offset, datatype, count


@lru_cache(maxsize=256)
def _fields_block(fields: tuple[PointField, ...]) -> bytes:
    """A PointCloud2's ``fields`` (their count first), from a 4-byte boundary: nothing in them aligns
    to more, so the bytes are the same wherever they start."""
    out = bytearray(_CDR_LE)
    out += _U32.pack(len(fields))
    for name, offset, datatype, count in fields:
        _string(out, name)
        _pad(out, 4)
        out += _POINT_FIELD.pack(offset, datatype, count)
    return bytes(out[4:])


def pointcloud2_cdr(stamp: Stamp, frame_id: str, height: int, width: int, fields: tuple[PointField, ...],
                    is_bigendian: bool, point_step: int, row_step: int, data: bytes, is_dense: bool) -> bytes:
    """``sensor_msgs/PointCloud2``; nothing in it aligns to more than 4 bytes."""
    return b"".join((_CDR_LE, _STAMP.pack(*stamp), _after_stamp((frame_id,), 4), _U32.pack(height),
                     _U32.pack(width), _fields_block(fields), _BOOL.pack(is_bigendian), b"\0\0\0",
                     _CLOUD_TAIL.pack(point_step, row_step, len(data)), data, _BOOL.pack(is_dense)))


@lru_cache(maxsize=64)
def _float32_fields(names: tuple[str, ...]) -> tuple[PointField, ...]:
    return tuple((name, 4 * i, FLOAT32, 1) for i, name in enumerate(names))


def float32_cloud_cdr(stamp: Stamp, frame_id: str, n: int, columns: dict[str, np.ndarray | None]) -> bytes:
    """A ``sensor_msgs/PointCloud2`` of ``n`` points with one float32 field per column, in order,
    packed point by point (as :func:`fmcwlog.io.messages.pointcloud_message`); a None column is 0."""
    packed = np.zeros((n, len(columns)), dtype="<f4")
    for i, column in enumerate(columns.values()):
        if column is not None:
            packed[:, i] = column
    step = 4 * len(columns)
    return pointcloud2_cdr(stamp, frame_id, 1, n, _float32_fields(tuple(columns)), False, step, step * n,
                           packed.tobytes(), True)


def _pointcloud2_cdr(m: dict) -> bytes:
    return pointcloud2_cdr(_dict_stamp(m["header"]), m["header"]["frame_id"], m["height"], m["width"],
                           tuple((f["name"], f["offset"], f["datatype"], f["count"]) for f in m["fields"]),
                           m["is_bigendian"], m["point_step"], m["row_step"], m["data"], m["is_dense"])


# Many messages of one fixed layout at once. ``record`` writes ground truth at 50 Hz (wheel ticks,
# odometry, tf: 18,000 of the 20,400 messages of 120 s); one message at a time through the encoders
# above, from dicts, that would be ~20 % of its time. A message whose strings are the same every time
# has the same length and the same bytes but for its leading stamp and its trailing numbers, so the
# batch is one template (the single-message encoder's output, which the tests hold to mcap_ros2's)
# repeated, with the stamps and numbers written in by numpy.


def _batch(template: bytes, stamp_at: int, stamps_ns: np.ndarray, tail: np.ndarray) -> list[bytes]:
    """Copies of ``template`` with the stamp of ``stamps_ns[i]`` (int64 ns) as ``(int32 sec, uint32
    nanosec)`` at byte ``stamp_at`` and ``tail[i]`` (N, k) as the last bytes, little endian."""
    size, data = len(template), _batch_bytes(template, stamp_at, stamps_ns, tail)
    return [data[i:i + size] for i in range(0, len(data), size)]


def _stamp_columns(stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sec, nanosec)`` of int64 ns, as :func:`stamp_pair` splits one; the seconds must fit an int32."""
    sec, nanosec = np.divmod(stamps_ns, 1_000_000_000)  # floor, as stamp_pair
    if sec.min() < -(2**31) or sec.max() >= 2**31:
        raise ValueError("a stamp's seconds do not fit a builtin_interfaces/Time (int32)")
    return sec, nanosec


def _batch_bytes(template: bytes, stamp_at: int, stamps_ns: np.ndarray, tail: np.ndarray) -> bytes:
    """:func:`_batch`'s copies, one after the other in one ``bytes``."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    if len(stamps_ns) == 0:
        return b""
    sec, nanosec = _stamp_columns(stamps_ns)
    size, n = len(template), len(stamps_ns)
    tail = np.asarray(tail)
    layout = np.dtype({"names": ["sec", "nanosec", "tail"],
                       "formats": ["<i4", "<u4", (tail.dtype.newbyteorder("<"), tail.shape[1:])],
                       "offsets": [stamp_at, stamp_at + 4, size - tail[0].nbytes],
                       "itemsize": size})
    raw = bytearray(template * n)
    records = np.frombuffer(raw, layout)
    records["sec"], records["nanosec"], records["tail"] = sec, nanosec, tail
    return bytes(raw)


_NO_COVARIANCE = (0.0,) * 36


def odometry_cdr_batch(stamps_ns: np.ndarray, frame_id: str, child_frame_id: str, values: np.ndarray) -> list[bytes]:
    """:func:`odometry_cdr` of N messages: ``values`` (N, 85) float64 as it takes them (pose7, its
    covariance, twist, its covariance)."""
    template = odometry_cdr((0, 0), frame_id, child_frame_id, (0.0,) * 7, _NO_COVARIANCE, (0.0,) * 6, _NO_COVARIANCE)
    return _batch(template, 4, stamps_ns, np.asarray(values, dtype=np.float64))


def tf_cdr_batch(stamps_ns: np.ndarray, parent: str, child: str, poses: np.ndarray) -> list[bytes]:
    """:func:`tf_cdr` of N messages of one transform each: ``poses`` (N, 7) float64, each a pose7."""
    template = tf_cdr([((0, 0), parent, child, (0.0,) * 7)])
    return _batch(template, 8, stamps_ns, np.asarray(poses, dtype=np.float64))  # after the count


def wheel_ticks_cdr_batch(stamps_ns: np.ndarray, frame_id: str, left: np.ndarray, right: np.ndarray) -> list[bytes]:
    """:func:`wheel_ticks_cdr` of N messages: the counts (N,) int64."""
    return _batch(wheel_ticks_cdr((0, 0), frame_id, 0, 0), 4, stamps_ns,
                  np.stack([np.asarray(left, np.int64), np.asarray(right, np.int64)], -1))


# Types encoded here in full (the layout is fixed by the .msg; the bytes are mcap_ros2's, which
# ``tests/unit/io/test_mcap_io.py`` checks): mcap_ros2 writes each field through its generic encoder,
# 17-72 us a message, 20 % of ``record`` (ground truth at 50 Hz); these take 3-8 us.
_ENCODERS: dict[str, Callable[[dict], bytes]] = {
    "nav_msgs/msg/Odometry": _odometry_cdr,
    "tf2_msgs/msg/TFMessage": _tf_cdr,
    "nav_msgs/msg/Path": _path_cdr,
    "fmcwlog_msgs/msg/WheelTicks": _wheel_ticks_cdr,
    "fmcwlog_msgs/msg/PointLabels": _point_labels_cdr,
    "sensor_msgs/msg/PointCloud2": _pointcloud2_cdr,
}


# --------------------------------------------------------------------------- the inputs' fast decoders

# The two types ``process`` reads in bulk, decoded straight from their CDR bytes when a channel's
# schema is the log format's own text (docs/log-format.md): mcap_ros2's generic decoder reads field
# by field through Python calls, ~15 us a message, most of it for the 50 Hz wheel ticks. Each
# gives the same values as that decoder, as attributes of plain objects, or None where the bytes
# are anything but the plain case (another encapsulation, too short, a string that is not UTF-8),
# which is then left to that decoder, with its errors.
_HEAD = struct.Struct("<iII")  # header.stamp (sec, nanosec), then frame_id's length
_U32X2 = struct.Struct("<II")
_FIELD_TAIL = struct.Struct("<IBxxxI")  # PointField: offset, datatype, (padding to 4), count


def _cdr_string(data: bytes, at: int) -> tuple[str, int]:
    """A CDR string at 4-aligned ``at`` (its length counting the NUL), as mcap_ros2 reads it; the offset after."""
    (n,) = _U32.unpack_from(data, at)
    at += 4
    if n <= 1:
        return "", at + n
    if at + n > len(data):
        raise ValueError("short")
    return data[at:at + n - 1].decode("utf-8"), at + n


def _align(at: int, size: int) -> int:
    return at + (-(at - 4) % size)


def _header(data: bytes) -> tuple[SimpleNamespace, int]:
    if data[:4] != _CDR_LE:
        raise ValueError("not little-endian CDR")
    sec, nanosec, _ = _HEAD.unpack_from(data, 4)
    frame_id, at = _cdr_string(data, 12)
    return SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec), frame_id=frame_id), at


def _fast_wheel_ticks(data: bytes) -> SimpleNamespace:
    header, at = _header(data)
    left, right = _TICKS.unpack_from(data, _align(at, 8))
    return SimpleNamespace(header=header, left=left, right=right)


# the fields of the last PointCloud2 read, and their bytes (its count first): a log's clouds share their
# fields, so a cloud that holds the same bytes there holds the same fields (their layout does not depend
# on where they start, a 4-byte boundary), read once rather than field by field each sweep
_last_fields: tuple[bytes, tuple[SimpleNamespace, ...]] = (b"", ())


def _fast_pointcloud2(data: bytes) -> SimpleNamespace:
    global _last_fields
    header, at = _header(data)
    at = _align(at, 4)
    height, width = _U32X2.unpack_from(data, at)
    at += 8
    block, known = _last_fields
    if block and data.startswith(block, at):
        at += len(block)
        fields = list(known)
    else:
        start = at
        (count,) = _U32.unpack_from(data, at)
        at += 4
        fields = []
        for _ in range(count):
            name, at = _cdr_string(data, _align(at, 4))
            offset, datatype, n = _FIELD_TAIL.unpack_from(data, _align(at, 4))
            at = _align(at, 4) + 12
            fields.append(SimpleNamespace(name=name, offset=offset, datatype=datatype, count=n))
        _last_fields = (data[start:at], tuple(fields))
    is_bigendian = data[at] != 0
    at = _align(at + 1, 4)
    point_step, row_step, size = _CLOUD_TAIL.unpack_from(data, at)
    at += 12
    if at + size + 1 > len(data):
        raise ValueError("short")
    return SimpleNamespace(header=header, height=height, width=width, fields=fields, is_bigendian=is_bigendian,
                           point_step=point_step, row_step=row_step, data=data[at:at + size],
                           is_dense=data[at + size] != 0)


_FAST_DECODERS: dict[str, Callable[[bytes], SimpleNamespace]] = {
    "fmcwlog_msgs/msg/WheelTicks": _fast_wheel_ticks,
    "sensor_msgs/msg/PointCloud2": _fast_pointcloud2,
}


@lru_cache(maxsize=16)
def _own_schema(name: str, text: bytes) -> bool:
    """Whether ``text`` is the log format's own ``ros2msg`` schema of ``name``."""
    return text == message_definition(name).encode()


class LogWriter:
    """Writes an MCAP log (``ros2`` profile, CDR) to ``path`` via a temporary file renamed on :meth:`close`.

    Use as a context manager: on an exception the temporary file is removed and
    nothing is left at ``path``. Schemas and channels are registered on first use.
    """

    def __init__(self, path: str | os.PathLike, compression: str = "zstd", chunk_size: int = 1 << 20):
        self.path = Path(path)
        self._tmp = partial_path(self.path)
        self._file: IO[bytes] = open(self._tmp, "wb")
        try:
            self._writer = McapWriter(self._file, chunk_size=chunk_size,
                                      compression=CompressionType[compression.upper() or "NONE"])
            self._writer.start(profile="ros2", library=f"fmcwlog {__version__}")
        except BaseException:  # the header could not be written (a full disk): leave nothing behind
            self.abort()
            raise
        self._schemas: dict[str, int] = {}
        self._generic: dict[str, Callable[[Any], bytes]] = {}
        self._channels: dict[str, int] = {}

    def _schema(self, datatype: str) -> int:
        if datatype not in self._schemas:
            text = message_definition(datatype)
            self._schemas[datatype] = self._writer.register_schema(datatype, SchemaEncoding.ROS2, text.encode())
        return self._schemas[datatype]

    def encode(self, datatype: str, message: dict) -> bytes:
        """CDR bytes of ``message`` (a dict of the type's fields). Registers the type's schema."""
        self._schema(datatype)
        if datatype in _ENCODERS:
            return _ENCODERS[datatype](message)
        encoder = self._generic.get(datatype)
        if encoder is None:  # built on first use only: parsing the schema takes 2 ms a type, 9 of record's 22 ms
            encoder = self._generic[datatype] = serialize_dynamic(datatype, message_definition(datatype))[datatype]
        tail = _RAW_TAIL.get(datatype)
        if tail is not None and isinstance(message.get(tail), np.ndarray):
            raw = np.ascontiguousarray(message[tail]).tobytes()
            head = encoder({**message, tail: []})  # ends with the empty array's uint32 length
            return head[:-4] + struct.pack("<I", message[tail].size) + raw
        return encoder(message)

    def write(self, topic: str, datatype: str, message: dict, log_time_ns: int) -> None:
        """Write one message; ``log_time_ns`` (ns since the epoch) must be the message's
        ``header.stamp``, as the log format requires."""
        self.write_cdr(topic, datatype, self.encode(datatype, message), log_time_ns)

    def write_cdr(self, topic: str, datatype: str, data: bytes, log_time_ns: int) -> None:
        """Write one message already CDR-encoded (by :func:`odometry_cdr` and its like)."""
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._writer.register_channel(topic, "cdr", self._schema(datatype))
            self._channels[topic] = channel
        self._writer.add_message(channel, log_time=log_time_ns, data=data, publish_time=log_time_ns)

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """One MCAP metadata record ``name`` (e.g. ``fmcwlog.calibration``) of string keys and values."""
        self._writer.add_metadata(name, values)

    def close(self) -> Path:
        """Finish the MCAP (summary and footer) and move it into place; on failure nothing is left."""
        try:
            self._writer.finish()
            self._file.close()
            os.replace(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Drop the partial file."""
        try:
            self._file.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> LogWriter:
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
    """What a scan of a log found besides its messages.

    metadata: the first record of each name; ``metadata_records`` keeps every record, in
    file order (MCAP allows several of one name).
    truncated: reading stopped before the end of the data section (a cut or damage that no
    index let it step over). damage: one sentence per damaged place, each naming its byte offset.
    """

    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    metadata_records: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    topics: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    counts: dict[str, int] = field(default_factory=dict)  # topic -> messages, when the summary says
    truncated: bool = False
    damage: list[str] = field(default_factory=list)


class UndecodableMessage(LogError):
    """One message's bytes do not decode with its schema (damage local to that message)."""


class ContentsReader:
    """What every log reader answers from its :class:`LogContents` (an MCAP log, a bag)."""

    contents: LogContents

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        """The first metadata record of each name (:attr:`LogContents.metadata`; a bag has none)."""
        return self.contents.metadata

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> its type's ROS 2 name, of every channel found so far."""
        return self.contents.topics

    def metadata_all(self, name: str) -> list[dict[str, str]]:
        """Every metadata record called ``name``, in file order."""
        return [values for n, values in self.contents.metadata_records if n == name]

    def message_count(self, topic: str) -> int | None:
        """Messages on ``topic`` by the file's index (an MCAP summary, a bag's index); None without one."""
        return self.contents.counts.get(topic)


class LogReader(ContentsReader):
    """Streams decoded messages of a log in file order, whoever wrote it, damaged or not.

    The container is read by :class:`fmcwlog.io.mcap_scan.McapScan`: an indexed file
    through its summary, a file without one (cut off before the footer, or with a
    damaged summary) record by record. Each damaged place is a warning naming its byte
    offset, once per reader (:attr:`contents.damage`); a file that holds nothing readable
    before its damage is a :class:`LogError`.
    """

    receive_times = False  # log_time is header.stamp, as the log format has it

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if self.path.is_dir():
            raise LogError(f"{self.path}: is a folder, not a log file")
        if not self.path.is_file():
            what = "no such file" if not self.path.exists() else "not a regular file (a pipe or a device): a log must be seekable"
            raise LogError(f"{self.path}: {what}")
        self.contents = LogContents()
        self._decoders: dict[int, Any] = {}
        self._factory = DecoderFactory()
        self._reported: set[int] = set()
        self._causes: list[str] = []
        self._extensions_said = False
        try:
            self._scan = McapScan(self.path, self._report)
        except Damaged as exc:
            raise LogError(f"{self.path}: {exc}") from None
        summary = self._scan.summary
        if summary is not None:
            for ch in summary.channels.values():
                schema = summary.schemas.get(ch.schema_id)
                self.contents.topics[ch.topic] = schema.name if schema is not None else ""
            if summary.message_counts is not None:
                self.contents.counts = {summary.channels[c].topic: n
                                        for c, n in summary.message_counts.items() if c in summary.channels}
            for md in self._scan.metadata():
                self._note_metadata(md)
        else:
            self._scan_headers()

    def _report(self, offset: int, cause: str, effect: str) -> None:
        """One warning per damaged place and reader, however many passes meet it."""
        if offset not in self._reported:
            self._reported.add(offset)
            self._causes.append(cause)
            text = f"{self.path}: {cause}: {effect}"
            self.contents.damage.append(text)
            warnings.warn(text, stacklevel=2)

    def damage_note(self) -> str:
        """What went wrong first, for an error that follows from it ('' for an intact log)."""
        return f" (the log is damaged: {self._causes[0]})" if self._causes else ""

    def _note_metadata(self, md: Metadata) -> None:
        self.contents.metadata_records.append((md.name, dict(md.metadata)))
        self.contents.metadata.setdefault(md.name, dict(md.metadata))

    def _scan_headers(self) -> None:
        """Collect metadata and topics of a file without a usable summary with one sequential pass."""
        for _ in self._records(None, metadata=True):
            pass
        problem = self._scan.summary_problem
        if self._scan.complete and problem is not None:
            self._report(self._scan.size, problem, "read every message, without the summary's index")
        if not self.contents.topics:
            why = self._causes[0] if self._causes else "it holds no channels"
            raise LogError(f"{self.path}: nothing readable: {why}")

    def _records(self, wanted: set[str] | None, metadata: bool = False,
                 indexed: bool = False) -> Generator[tuple[Schema | None, Channel, Message], None, None]:
        """The messages on ``wanted`` topics (all when None); ``indexed``: the chunks the summary's index
        lists without one of their channels are not read (:meth:`_without_wanted`)."""
        summary = self._scan.summary
        schemas: dict[int, Schema] = dict(summary.schemas) if summary is not None else {}
        channels: dict[int, Channel] = dict(summary.channels) if summary is not None else {}
        skip = self._without_wanted(summary, wanted) if indexed and summary is not None and wanted is not None else None
        # channels known to be on other topics: their messages are not made into records (a channel
        # defined inside a chunk counts from the next chunk on; until then it is filtered below)
        unwanted = {i for i, ch in channels.items() if ch.topic not in wanted} if wanted is not None else set()
        for rec in self._scan.records(skip, unwanted):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
                if wanted is not None and rec.topic not in wanted:
                    unwanted.add(rec.id)
                else:
                    unwanted.discard(rec.id)
                self.contents.topics.setdefault(rec.topic, schemas[rec.schema_id].name if rec.schema_id in schemas else "")
            elif isinstance(rec, Metadata):
                if metadata:
                    self._note_metadata(rec)
            else:
                ch = channels.get(rec.channel_id)
                if ch is not None and (wanted is None or ch.topic in wanted):
                    yield schemas.get(ch.schema_id), ch, rec
        if not self._scan.complete:
            self.contents.truncated = True
        if self._scan.extensions and not self._extensions_said:
            self._extensions_said = True
            first = min(self._scan.extensions)
            n = len(self._scan.extensions)
            warnings.warn(f"{self.path}: skipped {n} record{'s' if n > 1 else ''} of extension opcodes "
                          f"(0x80-0xFF, which the MCAP specification leaves to applications; the first: 0x"
                          f"{self._scan.extensions[first]:02x} at byte {first})", stacklevel=2)

    @staticmethod
    def _without_wanted(summary: Summary, wanted: set[str]) -> Callable[[frozenset[int]], bool]:
        """Whether a chunk holding these channels (ids, by the summary's index) holds none on ``wanted``:
        each is a channel of the summary's, on another topic. A channel the summary does not name
        could be on one: that chunk is read."""
        known = summary.channels
        return lambda ids: all(i in known and known[i].topic not in wanted for i in ids)

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Undecoded messages on ``topics`` (all when None), in file order; :meth:`decode` decodes one.

        Always a sequential scan, chunk by chunk: memory stays at one chunk. (mcap's
        indexed reader holds ~87 MB at its peak over a 5-minute log, growing with length.) For
        named topics the chunks that the summary's index lists without them are stepped over,
        unread: reading a log's one ``/tf_static`` message decompresses one chunk, not the log.
        The damage of a chunk stepped over is left to the passes that read it (``process``
        reads every chunk that holds its scan or its motion prior: :meth:`raw_messages_by_time`).
        """
        return self._records(None if topics is None else set(topics), indexed=topics is not None)

    def raw_messages_by_time(self, topics: Sequence[str],
                             hold_bytes: int = MERGE_HOLD_BYTES) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Undecoded messages on ``topics`` in ``log_time`` order across them, each topic in its own file order.

        The log format leaves free how a writer interleaves topics (MCAP orders nothing), and one
        that writes a topic at a time (every wheel tick, then every sweep) is as valid as one that
        writes in time order; a reader that takes file order for time order would give the sweeps
        a motion prior from the wrong time. So the topics' messages are merged by ``log_time``
        (ties in the order of ``topics``), as :func:`heapq.merge` of one pass per topic would.

        One pass serves while it can: each topic's messages wait in a queue until every topic has
        one, and the earliest head goes next, so a log written in time order holds a few messages.
        Once the queues hold more than ``hold_bytes`` of message data (a writer that grouped its
        topics, or a topic that stops), the rest comes from a pass per topic, each resuming after
        the messages already taken, merged with what the queues hold: the same order, memory back
        to one chunk a pass, the file decompressed once more per topic. (Passes per topic from the
        start cost the 120 s corridor's sweeps and ticks 1.15-1.29 s to read, against 0.38-0.76 s
        in one pass.) Within one topic file order is kept: a message earlier than the one before it
        is the caller's to judge.
        """
        order = {topic: i for i, topic in enumerate(topics)}
        queues: list[deque[tuple[Schema | None, Channel, Message]]] = [deque() for _ in topics]
        taken = [0] * len(topics)  # each topic's messages read from the single pass, queued or given
        held = 0
        empty = len(topics)  # queues without a message
        single = self._records(set(topics))
        for record in single:
            i = order[record[1].topic]
            queue = queues[i]
            if not queue:
                empty -= 1
            queue.append(record)
            taken[i] += 1
            held += len(record[2].data)
            while not empty:  # every topic has a head: the earliest (the first topic's on a tie) is next
                first, first_time = 0, queues[0][0][2].log_time
                for j in range(1, len(queues)):
                    if queues[j][0][2].log_time < first_time:
                        first, first_time = j, queues[j][0][2].log_time
                out = queues[first].popleft()
                if not queues[first]:
                    empty += 1
                held -= len(out[2].data)
                yield out
            if held > hold_bytes:
                break
        else:  # the whole file in one pass
            yield from heapq.merge(*queues, key=lambda record: record[2].log_time)
            return
        single.close()
        passes = [chain(queues[i], islice(self._records({topic}), taken[i], None)) for i, topic in enumerate(topics)]
        yield from heapq.merge(*passes, key=lambda record: record[2].log_time)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """Decoded messages on ``topics`` (all when None), in file order."""
        for schema, channel, rec in self.raw_messages(topics):
            yield self.decode(schema, channel, rec)

    def log_times(self, topic: str) -> Iterator[int]:
        """``log_time`` (ns) of every message on ``topic``, without decoding them."""
        for _, _, rec in self.raw_messages([topic]):
            yield rec.log_time

    def decode_input(self, schema: Schema | None, channel: Channel, message: Message) -> LogMessage:
        """:meth:`decode` for the estimator's inputs (:class:`fmcwlog.io.inputs.LogInputs`): the same
        values, a wheel-tick or PointCloud2 message of the log format's schema read straight from its
        bytes (:data:`_FAST_DECODERS`), as plain objects rather than mcap_ros2's message classes."""
        fast = _FAST_DECODERS.get(schema.name) if schema is not None else None
        if fast is not None and channel.message_encoding == "cdr" and schema is not None \
                and schema.encoding == "ros2msg" and _own_schema(schema.name, bytes(schema.data)):
            try:
                return LogMessage(channel.topic, schema.name, message.log_time, fast(message.data))
            except Exception:  # noqa: BLE001 (anything but the plain case: mcap_ros2's decoder says what)
                pass
        return self.decode(schema, channel, message)

    def decode(self, schema: Schema | None, channel: Channel, message: Message) -> LogMessage:
        """One message decoded; :class:`LogError` where its topic cannot be decoded at all,
        :class:`UndecodableMessage` where only this message's bytes are at fault."""
        if schema is None:
            raise LogError(f"{self.path}: topic {channel.topic} has no schema")
        dec = self._decoders.get(channel.id)
        if dec is None:
            try:
                dec = self._factory.decoder_for(channel.message_encoding, schema)
            except Exception as exc:  # mcap_ros2 raises several types for a schema it cannot parse
                raise LogError(f"{self.path}: topic {channel.topic}: its schema {schema.name!r} "
                               f"cannot be parsed ({exc})") from None
            if dec is None:  # mcap_ros2 decodes CDR messages with ros2msg schemas only, which the log format requires
                what = (f"is encoded as {channel.message_encoding!r}, expected 'cdr'"
                        if channel.message_encoding != "cdr" else
                        f"has its schema {schema.name!r} as {schema.encoding!r}, expected 'ros2msg'")
                raise LogError(f"{self.path}: topic {channel.topic} {what}")
            self._decoders[channel.id] = dec
        try:
            msg = dec(message.data)
        except Exception as exc:  # the CDR decoder raises several unrelated types
            raise UndecodableMessage(f"{self.path}: cannot decode a message on {channel.topic} ({exc})") from exc
        return LogMessage(channel.topic, schema.name, message.log_time, msg)
