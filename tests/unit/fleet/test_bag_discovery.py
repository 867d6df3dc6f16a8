"""What a fleet finds besides MCAP logs: ROS 1 .bag files and rosbag2 folders, each one log."""

from __future__ import annotations

import pytest

from fmcwlog.errors import LogError
from fmcwlog.fleet.inputs import CARMEN_PATTERNS, find_logs, unique_names


def test_a_search_finds_bags_and_takes_a_rosbag2_folder_as_one_log(tmp_path):
    for rel in ("a.mcap", "b.bag", "C.BAG", "day1/run/metadata.yaml", "day1/run/run_0.mcap", "day1/run/run_0.db3",
                "day2/run.v2/metadata.yaml", "day2/run.v2/run.v2_0.db3", "notes/metadata.txt"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    logs = find_logs([tmp_path])
    assert [p.relative_to(tmp_path).as_posix() for p in logs] == ["C.BAG", "a.mcap", "b.bag", "day1/run", "day2/run.v2"]
    assert unique_names(logs) == ["C", "a", "b", "run", "run.v2"]  # a folder by its whole name
    bag = tmp_path / "day1" / "run"
    assert find_logs([bag]) == [bag]  # given alone: one log, its storage files not searched
    assert find_logs([bag / "run_0.db3"]) == [bag]  # a rosbag2 .db3 stands for its folder
    assert find_logs([bag / "run_0.db3", tmp_path]) == [bag] + [p for p in logs if p != bag]  # each log once
    with pytest.raises(LogError, match=r"looked for \*\.mcap, \*\.bag and rosbag2 folders"):
        find_logs([tmp_path / "notes"])


def test_carmen_imports_search_as_before(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text("")
    (tmp_path / "bag" / "run.clf").write_text("")
    assert find_logs([tmp_path], CARMEN_PATTERNS, rosbag2=False) == [tmp_path / "bag" / "run.clf"]
