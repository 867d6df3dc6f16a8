"""fmcwlog's log reader on logs written by another program (shared/conformance) and on its own."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fmcwlog.errors import LogError
from fmcwlog.io.mcap_log import LogReader
from fmcwlog.io.messages import pointcloud_columns


def _counts(reader: LogReader) -> dict[str, int]:
    counts: dict[str, int] = {}
    for m in reader.messages():
        counts[m.topic] = counts.get(m.topic, 0) + 1
    return counts


def test_reads_the_other_writers_lz4_log(shared_dir):
    reader = LogReader(shared_dir / "conformance" / "other-writer-lz4.mcap")
    assert reader.metadata["fmcwlog.calibration"]["lidar_x"] == "0.45"
    assert reader.topics["/fmcw/points"] == "sensor_msgs/msg/PointCloud2"
    assert _counts(reader) == {"/fmcw/points": 200, "/ground_truth/point_labels": 200,
                               "/ground_truth/odom": 1001, "/wheel/ticks": 1001}
    first = next(reader.messages(["/fmcw/points"]))
    cols = pointcloud_columns(first.msg)
    assert len(cols["x"]) == first.msg.width and np.all(np.isfinite(cols["velocity"]))


def test_reads_a_log_cut_off_before_its_summary(shared_dir):
    path = shared_dir / "conformance" / "other-writer-cut-off.mcap"
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
