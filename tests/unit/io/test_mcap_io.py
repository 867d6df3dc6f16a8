"""fmcwlog's log reader on logs written by another program (shared/conformance) and on its own."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import shared_file
from mcap.reader import make_reader

from fmcwlog.errors import LogError
from fmcwlog.io.mcap_log import LogReader
from fmcwlog.io.messages import pointcloud_columns


def _counts(reader: LogReader) -> dict[str, int]:
    counts: dict[str, int] = {}
    for m in reader.messages():
        counts[m.topic] = counts.get(m.topic, 0) + 1
    return counts


@pytest.mark.needs_conformance
def test_reads_the_other_writers_lz4_log():
    reader = LogReader(shared_file("conformance/other-writer-lz4.mcap"))
    assert reader.metadata["fmcwlog.calibration"]["lidar_x"] == "0.45"
    assert reader.topics["/fmcw/points"] == "sensor_msgs/msg/PointCloud2"
    assert _counts(reader) == {"/fmcw/points": 200, "/ground_truth/point_labels": 200,
                               "/ground_truth/odom": 1001, "/wheel/ticks": 1001}
    first = next(reader.messages(["/fmcw/points"]))
    cols = pointcloud_columns(first.msg)
    assert len(cols["x"]) == first.msg.width and np.all(np.isfinite(cols["velocity"]))


@pytest.mark.needs_conformance
def test_reads_a_log_cut_off_before_its_summary():
    path = shared_file("conformance/other-writer-cut-off.mcap")
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        reader = LogReader(path)
        counts = _counts(reader)
    assert reader.contents.truncated
    assert "fmcwlog.calibration" in reader.metadata
    assert counts["/fmcw/points"] == 80 and counts["/wheel/ticks"] == 401


def test_own_log_reads_the_same_through_both_paths(corridor_log, tmp_path):
    reader = LogReader(corridor_log)
    assert not reader.contents.truncated
    stamps = [m.log_time_ns for m in reader.messages(["/fmcw/points"])]
    # the same file with its summary and footer cut off is read by the sequential scan
    data = corridor_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        part = LogReader(cut)
        part_stamps = [m.log_time_ns for m in part.messages(["/fmcw/points"])]
    assert part.contents.truncated
    assert 0 < len(part_stamps) < len(stamps) and part_stamps == stamps[: len(part_stamps)]


@pytest.mark.parametrize("content, words", [(b"hello world", "not an MCAP"), (None, "no such file")])
def test_bad_files_are_named(tmp_path, content, words):
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(LogError, match=words) as info:
        LogReader(path)
    assert str(path) in str(info.value)


def test_odometry_is_encoded_as_mcap_ros2_encodes_it():
    """Odometry is written by fmcwlog's own CDR encoder (speed); mcap_ros2's generic encoder is the
    reference: the same bytes for frame names of every length modulo 8 (the float block's padding)."""
    from mcap_ros2._dynamic import serialize_dynamic

    from fmcwlog.io.mcap_log import _odometry_cdr
    from fmcwlog.io.messages import odometry_message
    from fmcwlog.io.schemas import message_definition

    reference = serialize_dynamic("nav_msgs/msg/Odometry", message_definition("nav_msgs/msg/Odometry"))["nav_msgs/msg/Odometry"]
    rng = np.random.default_rng(5)
    for n in range(12):
        frame, child = "o" * n, "bäse/" + "l" * (n // 2)
        cov = rng.normal(size=(3, 3))
        msg = odometry_message(int(rng.integers(0, 2**31)) * 10**9 + int(rng.integers(0, 10**9)), frame, child, rng.normal(size=3) * 100, rng.normal(size=3),
                               cov @ cov.T if n % 2 else None, np.eye(3) * n)
        assert _odometry_cdr(msg) == reference(msg)


def _messages_of_every_alignment(datatype: str, rng: np.random.Generator) -> list[dict]:
    """Messages of ``datatype`` as the recorder builds them, with frame names, field names and
    array lengths of every length modulo 8 (every padding the layout can need)."""
    from fmcwlog.io.messages import path_message, pointcloud_message, stamp, tf_message, transform_dict

    out = []
    for n in range(17):
        ns = int(rng.integers(0, 2**31)) * 10**9 + int(rng.integers(0, 10**9))
        frame = "bäse/"[: n % 6] + "l" * (n // 2)
        header = {"header": {"stamp": stamp(ns), "frame_id": frame}}
        if datatype == "sensor_msgs/msg/PointCloud2":
            cols = {"f" * (1 + (n + k) % 9): rng.normal(size=n) for k in range(1 + n % 6)}
            out.append(pointcloud_message(ns, frame, cols))
        elif datatype == "fmcwlog_msgs/msg/PointLabels":
            out.append({**header, "moving": rng.integers(0, 2, n).astype(np.uint8).tobytes()})
        elif datatype == "nav_msgs/msg/Path":
            stamps = [int(x) * 10**9 + int(y) for x, y in zip(rng.integers(0, 2**31, n % 5), rng.integers(0, 10**9, n % 5))]
            out.append(path_message(ns, frame, stamps, list(rng.normal(size=(n % 5, 3)) * 50)))
        elif datatype == "fmcwlog_msgs/msg/WheelTicks":
            out.append({**header, "left": int(rng.integers(-2**62, 2**62)), "right": -n})
        else:
            out.append(tf_message([transform_dict(ns, frame, "x" * k, rng.normal(size=3)) for k in range(n % 4)]))
    return out


@pytest.mark.parametrize("datatype", ["sensor_msgs/msg/PointCloud2", "fmcwlog_msgs/msg/PointLabels",
                                      "fmcwlog_msgs/msg/WheelTicks", "tf2_msgs/msg/TFMessage", "nav_msgs/msg/Path"])
def test_recorded_types_are_encoded_as_mcap_ros2_encodes_them(datatype):
    """The other types ``record`` writes have their own encoders too (speed); mcap_ros2's is the reference."""
    from mcap_ros2._dynamic import serialize_dynamic

    from fmcwlog.io.mcap_log import _ENCODERS
    from fmcwlog.io.schemas import message_definition

    reference = serialize_dynamic(datatype, message_definition(datatype))[datatype]
    for msg in _messages_of_every_alignment(datatype, np.random.default_rng(6)):
        assert _ENCODERS[datatype](msg) == reference(msg)


def test_fixed_layout_batches_are_encoded_as_mcap_ros2_encodes_them():
    """``record`` encodes its ground truth many messages at once (speed); each of them must be what
    mcap_ros2's generic encoder makes of the same message dict, for frame names of every length
    modulo 8 and stamps up to the last second an int32 holds."""
    from mcap_ros2._dynamic import serialize_dynamic

    from fmcwlog.io.mcap_log import odometry_cdr_batch, tf_cdr_batch, wheel_ticks_cdr_batch
    from fmcwlog.io.messages import odometry_message, planar_covariance, pose7, stamp, tf_message, transform_dict
    from fmcwlog.io.schemas import message_definition

    def reference(datatype):
        return serialize_dynamic(datatype, message_definition(datatype))[datatype]

    odometry, tf, ticks = (reference(t) for t in ("nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage",
                                                  "fmcwlog_msgs/msg/WheelTicks"))
    rng = np.random.default_rng(7)
    for n in range(9):
        frame, child = "bäse/"[: n % 6] + "m" * (n // 2), "c" * n
        stamps = np.concatenate([rng.integers(0, 2**31 * 10**9, 4), [0, 2**31 * 10**9 - 1]])
        poses, twists = rng.normal(size=(6, 3)) * 50, rng.normal(size=(6, 3))
        twists[:, 1] = 0.0
        covs = [(c @ c.T, np.eye(3) * k) for k, c in enumerate(rng.normal(size=(6, 3, 3)))]
        left, right = rng.integers(-2**62, 2**62, 6), rng.integers(-2**62, 2**62, 6)
        values = np.array([(*pose7(p), *planar_covariance(c0), tw[0], tw[1], 0.0, 0.0, 0.0, tw[2], *planar_covariance(c1))
                           for p, tw, (c0, c1) in zip(poses, twists, covs)])
        got = (odometry_cdr_batch(stamps, frame, child, values),
               tf_cdr_batch(stamps, frame, child, np.array([pose7(p) for p in poses])),
               wheel_ticks_cdr_batch(stamps, frame, left, right))
        for i, ns in enumerate(stamps.tolist()):
            assert got[0][i] == odometry(odometry_message(ns, frame, child, poses[i], twists[i], *covs[i]))
            assert got[1][i] == tf(tf_message([transform_dict(ns, frame, child, poses[i])]))
            assert got[2][i] == ticks({"header": {"stamp": stamp(ns), "frame_id": frame},
                                       "left": int(left[i]), "right": int(right[i])})
    assert odometry_cdr_batch(np.zeros(0, np.int64), "map", "base_link", np.zeros((0, 85))) == []
    with pytest.raises(ValueError, match="int32"):
        tf_cdr_batch(np.array([2**31 * 10**9]), "map", "base_link", np.zeros((1, 7)))


@pytest.mark.parametrize("message_encoding, schema_encoding, words", [
    ("json", "ros2msg", "is encoded as 'json', expected 'cdr'"),
    ("cdr", "ros2idl", "has its schema 'fmcwlog_msgs/msg/WheelTicks' as 'ros2idl', expected 'ros2msg'"),
])
def test_a_topic_in_an_encoding_other_than_the_contracts_is_one_error_naming_it(tmp_path, message_encoding,
                                                                                 schema_encoding, words):
    """The log format (docs/log-format.md): CDR messages with ros2msg schemas. A topic otherwise (written here with plain
    mcap) is refused naming the file, the topic and the encoding at fault (the schema's encoding was
    reported as "encoded as 'cdr', expected 'cdr'")."""
    from mcap.writer import Writer

    path = tmp_path / "other.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        schema = w.register_schema("fmcwlog_msgs/msg/WheelTicks", schema_encoding, b"int64 left\nint64 right\n")
        channel = w.register_channel("/wheel/ticks", message_encoding, schema)
        w.add_message(channel, log_time=1, publish_time=1, data=b"\0\1\0\0" + bytes(16))
        w.finish()
    reader = LogReader(path)
    with pytest.raises(LogError) as info:
        for schema, channel, message in reader.raw_messages():
            reader.decode(schema, channel, message)
    assert str(info.value) == f"{path}: topic /wheel/ticks {words}"


def _unindexed_log_with_a_record_spliced_in(path: Path, opcode: int) -> list[tuple[str, int, bytes]]:
    """An unchunked log without summary (plain mcap) with a record of ``opcode`` after its header;
    its messages as mcap's own reader reads them before the splice."""
    from mcap.writer import IndexType, Writer

    plain = path.with_suffix(".plain.mcap")
    with open(plain, "wb") as fh:
        w = Writer(fh, use_chunking=False, index_types=IndexType.NONE, repeat_channels=False, repeat_schemas=False,
                   use_statistics=False, use_summary_offsets=False)
        w.start(profile="ros2", library="test")
        schema = w.register_schema("fmcwlog_msgs/msg/WheelTicks", "ros2msg", b"int64 left\nint64 right\n")
        channel = w.register_channel("/wheel/ticks", "cdr", schema)
        for i in range(5):
            w.add_message(channel, log_time=i + 1, publish_time=i + 1, data=b"\0\1\0\0" + struct.pack("<qq", i, 2 * i))
        w.finish()
    with open(plain, "rb") as fh:
        expected = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    data = plain.read_bytes()
    header_end = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    path.write_bytes(data[:header_end] + bytes([opcode]) + struct.pack("<Q", 6) + b"vendor" + data[header_end:])
    return expected


def test_records_of_extension_opcodes_are_skipped_with_a_note(tmp_path):
    """The MCAP specification: "0x80-0xFF are reserved for application extensions". A writer's record
    of such an opcode is skipped, with one warning naming the file and where (the log was 'nothing
    readable: damaged'); an unknown opcode below 0x80 is still damage."""
    path = tmp_path / "extension.mcap"
    expected = _unindexed_log_with_a_record_spliced_in(path, 0x80)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = LogReader(path)
        got = [(c.topic, m.log_time, m.data) for _, c, m in reader.raw_messages_by_time(["/wheel/ticks"])]
    assert got == expected and not reader.contents.damage
    assert [str(w.message) for w in caught] == [
        f"{path}: skipped 1 record of extension opcodes (0x80-0xFF, which the MCAP specification leaves to "
        f"applications; the first: 0x80 at byte {8 + 9 + struct.unpack_from('<Q', path.read_bytes(), 9)[0]})"]
    reserved = tmp_path / "reserved.mcap"
    _unindexed_log_with_a_record_spliced_in(reserved, 0x7F)
    with warnings.catch_warnings(record=True), pytest.raises(LogError, match="unknown opcode 0x7f"):
        warnings.simplefilter("always")
        LogReader(reserved)
