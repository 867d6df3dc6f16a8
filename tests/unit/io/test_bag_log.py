"""rosbag2 folders and ROS 1 bags, written by rosbags' own writers from an fmcwlog log, read as the log is.

The bags hold the log's messages (tests/bags.py): a bag's reader must give the same topics, counts,
order and decoded values as the MCAP reader gives for the log, with the field names mcap_ros2's
messages have; and a bag that is not one, or is damaged, is one line.
"""

from __future__ import annotations

import shutil
import sqlite3

import numpy as np
import pytest
from bags import calibration_file, write_ros1, write_rosbag2
from helpers import assert_one_line_error, run_cli_here

from fmcwlog.errors import LogError
from fmcwlog.io.bag_log import BagReader
from fmcwlog.io.digest import log_sha256, log_size
from fmcwlog.io.logs import open_log
from fmcwlog.io.mcap_log import LogReader
from fmcwlog.io.sweeps import sweep_from_pointcloud

TOPICS = ("/tf_static", "/fmcw/points", "/wheel/ticks", "/ground_truth/odom", "/ground_truth/point_labels")


@pytest.fixture(scope="module")
def bags(crowd_log, tmp_path_factory):
    """The crowd log's messages on TOPICS as each kind of bag."""
    d = tmp_path_factory.mktemp("bags")
    return {
        "sqlite3": write_rosbag2(crowd_log, d / "crowd_sqlite3", topics=TOPICS),
        "mcap": write_rosbag2(crowd_log, d / "crowd_mcap", storage="mcap", topics=TOPICS),
        "ros1": write_ros1(crowd_log, d / "crowd.bag", topics=TOPICS),
    }


def _same(a, b) -> bool:
    """Whether ``b`` (rosbags) holds every field of ``a`` (mcap_ros2) with equal values: bytes and
    lists against numpy arrays by value; ``b``'s fields ``a`` has not (a ROS 1 header's seq) aside."""
    if hasattr(a, "__slots__") and not isinstance(a, (bytes, str)):
        return all(_same(getattr(a, k), getattr(b, k)) for k in a.__slots__)
    if isinstance(b, np.ndarray):
        return np.array_equal(np.frombuffer(a, np.uint8) if isinstance(a, bytes) else np.asarray(a), b)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "ros1"])
def test_a_bag_reads_as_the_log_it_was_written_from(crowd_log, bags, kind):
    mcap, bag = LogReader(crowd_log), open_log(bags[kind])
    assert isinstance(bag, BagReader) and bag.path == bags[kind] and bag.receive_times and not mcap.receive_times
    assert bag.topics == {t: mcap.topics[t] for t in TOPICS}  # ROS 2 names, a ROS 1 bag's too
    assert {t: bag.message_count(t) for t in TOPICS} == {t: mcap.message_count(t) for t in TOPICS}
    assert bag.metadata == {} and bag.metadata_all("fmcwlog.calibration") == [] and bag.damage_note() == ""
    pairs = list(zip(mcap.messages(TOPICS), bag.messages(TOPICS), strict=True))
    for a, b in pairs:
        assert (a.topic, a.datatype, a.log_time_ns) == (b.topic, b.datatype, b.log_time_ns)
        assert _same(a.msg, b.msg), a.topic
    assert {a.topic for a, _ in pairs} == set(TOPICS)
    a, b = next((a, b) for a, b in pairs if a.topic == "/fmcw/points")
    (sa, _), (sb, _) = sweep_from_pointcloud(mcap.path, a.msg), sweep_from_pointcloud(bag.path, b.msg)
    assert sa.stamp_ns == sb.stamp_ns and np.array_equal(sa.xy, sb.xy) and np.array_equal(sa.velocity, sb.velocity)
    wanted = ["/fmcw/points", "/wheel/ticks"]
    by_time = [(c.topic, r.log_time) for _, c, r in bag.raw_messages_by_time(wanted)]
    assert by_time == [(c.topic, r.log_time) for _, c, r in mcap.raw_messages_by_time(wanted)]
    assert list(bag.log_times("/wheel/ticks")) == list(mcap.log_times("/wheel/ticks"))


def test_a_rosbag2_without_definitions_decodes_with_the_standard_types_and_fmcwlogs(crowd_log, bags, tmp_path):
    """Bags before ROS 2 Iron hold no message definitions: Humble's and the log format's own decode them."""
    folder = tmp_path / "old"
    shutil.copytree(bags["sqlite3"], folder)
    with sqlite3.connect(folder / "crowd_sqlite3.db3") as db:
        db.execute("DELETE FROM message_definitions")
    bag = open_log(folder)
    for a, b in zip(LogReader(crowd_log).messages(TOPICS), bag.messages(TOPICS), strict=True):
        assert _same(a.msg, b.msg), a.topic


def test_a_db3_is_read_with_its_folder_and_alone(bags, tmp_path):
    folder = bags["sqlite3"]
    assert open_log(folder / "crowd_sqlite3.db3").path == folder
    assert open_log(folder / "metadata.yaml").path == folder
    alone = tmp_path / "alone.db3"  # a recording stopped before rosbag2 wrote its metadata.yaml
    shutil.copyfile(folder / "crowd_sqlite3.db3", alone)
    bag = open_log(alone)
    assert bag.path == alone and bag.message_count("/fmcw/points") == open_log(folder).message_count("/fmcw/points")


def test_a_folder_digest_covers_its_files(bags, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(bags["sqlite3"], folder)
    before = log_sha256(folder)
    assert log_sha256(bags["sqlite3"]) == before and len(before) == 64
    assert log_size(folder) == sum(p.stat().st_size for p in folder.iterdir())
    (folder / "notes.txt").write_text("a note")
    assert log_sha256(folder) != before


@pytest.mark.parametrize("name, content, words", [
    ("junk.txt", b"hello world", ["not an MCAP file", "rosbag2 folders (or their .db3 file) and ROS 1 .bag files"]),
    ("junk.bag", b"hello world", ["not a ROS 1 bag", "fmcwlog reads MCAP logs"]),
    ("junk.db3", b"hello world", ["not a rosbag2 sqlite3 database", "fmcwlog reads MCAP logs"]),
    ("junk.mcap", b"hello world", ["not an MCAP file", "ROS 1 .bag files"]),
])
def test_a_file_that_is_no_log_says_what_is_read(tmp_path, name, content, words):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(LogError) as info:
        open_log(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    for w in words:
        assert w in str(info.value)


def test_a_folder_that_is_no_bag_is_named(tmp_path):
    with pytest.raises(LogError, match="without a metadata.yaml, so not a rosbag2 folder"):
        open_log(tmp_path)


def test_damaged_bags_are_one_line(crowd_log, bags, tmp_path):
    cut = tmp_path / "cut.bag"  # a recording stopped before its index was written
    cut.write_bytes(bags["ros1"].read_bytes()[: bags["ros1"].stat().st_size // 2])
    with pytest.raises(LogError, match="rosbag reindex"):
        open_log(cut)
    hurt = tmp_path / "hurt.bag"  # a chunk overwritten part way through
    raw = bytearray(bags["ros1"].read_bytes())
    raw[len(raw) // 2: len(raw) // 2 + 4000] = b"\xff" * 4000
    hurt.write_bytes(bytes(raw))
    with pytest.raises(LogError, match=r"cannot read this ROS 1 bag after reading \d+ messages"):
        for _ in open_log(hurt).messages(["/fmcw/points"]):
            pass
    folder = tmp_path / "cutdb"
    shutil.copytree(bags["sqlite3"], folder)
    db = folder / "crowd_sqlite3.db3"
    db.write_bytes(db.read_bytes()[: db.stat().st_size // 2])
    with pytest.raises(LogError, match="cannot read this rosbag2 folder"):
        open_log(folder)
    cal = calibration_file(crowd_log, tmp_path / "cal.yaml")
    code, _, err = run_cli_here("-q", "process", str(hurt), "-o", str(tmp_path / "out"), "--calibration", str(cal))
    assert_one_line_error(code, err, str(hurt), "cannot read this ROS 1 bag after reading")
    assert not (tmp_path / "out").exists()
