"""The same recording as an MCAP log, a rosbag2 folder (sqlite3 and MCAP storage) and a ROS 1 bag:
the same outputs from process, the same estimates from calibrate, the same scores from report, and
a fleet of all three kinds.

The bags are written by rosbags' own writers from the crowd log's messages (tests/bags.py). A bag
holds no fmcwlog metadata, so every log here is processed with the log's calibration record as a
file (``--calibration``); what must differ between the outputs is the log itself (run.json's
``log``, ``log_size_bytes``, ``log_sha256``) and the timings.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from bags import calibration_file, write_ros1, write_rosbag2

from fmcwlog.api import ProcessOptions, calibrate, evaluate, process, process_many, report
from fmcwlog.io.digest import log_sha256, log_size

pytestmark = pytest.mark.slow

TIMINGS = re.compile(r"^(wall_seconds|seconds|ms_per_sweep\w*|sweeps_per_second)$")
THE_LOG = {"log", "log_size_bytes", "log_sha256"}
# receive times: sweeps reach the recorder 30 ms after their stamp, ticks 2 ms, the ground truth 1 ms
LATE = {"/fmcw/points": 30_000_000, "/wheel/ticks": 2_000_000, "/ground_truth/odom": 1_000_000}


@pytest.fixture(scope="module")
def logs(crowd_log, tmp_path_factory) -> tuple[Path, dict[str, Path]]:
    d = tmp_path_factory.mktemp("bag_logs")
    mcap = d / "crowd.mcap"
    shutil.copyfile(crowd_log, mcap)
    return calibration_file(crowd_log, d / "calibration.yaml"), {
        "mcap": mcap,
        "rosbag2-sqlite3": write_rosbag2(crowd_log, d / "crowd_sqlite3"),
        "rosbag2-mcap": write_rosbag2(crowd_log, d / "crowd_mcap_storage", storage="mcap"),
        "ros1": write_ros1(crowd_log, d / "crowd.bag"),
        "ros1-receive-times": write_ros1(crowd_log, d / "crowd_late.bag", delay=LATE),
    }


@pytest.fixture(scope="module")
def outputs(logs, tmp_path_factory) -> dict[str, Path]:
    cal, paths = logs
    out = tmp_path_factory.mktemp("bag_outputs")
    return {kind: process(path, out / kind, ProcessOptions(calibration=cal)).out_dir for kind, path in paths.items()}


def _without(doc, keys=frozenset()):
    if isinstance(doc, dict):
        return {k: _without(v) for k, v in doc.items() if not TIMINGS.match(k) and k not in keys}
    if isinstance(doc, list):
        return [_without(v) for v in doc]
    return doc


def _differences(a: Path, b: Path) -> list[str]:
    """The files of output folder ``b`` that differ from ``a``'s, timings and the log's identity aside."""
    names = sorted({p.name for p in a.iterdir()} | {p.name for p in b.iterdir()})
    out = []
    for name in names:
        fa, fb = a / name, b / name
        if not (fa.is_file() and fb.is_file()):
            out.append(f"{name}: only in one")
        elif fa.read_bytes() == fb.read_bytes():
            continue
        elif name.endswith(".json"):
            keys = THE_LOG if name == "run.json" else frozenset()
            if _without(json.loads(fa.read_text()), keys) != _without(json.loads(fb.read_text()), keys):
                out.append(name)
        elif name == "trajectories.parquet":
            ta, tb = pq.read_table(fa), pq.read_table(fb)
            keep = [c for c in ta.column_names if c != "ms"]
            if ta.column_names != tb.column_names or not ta.select(keep).equals(tb.select(keep)):
                out.append(name)
        else:
            out.append(name)
    return out


@pytest.mark.parametrize("kind", ["rosbag2-sqlite3", "rosbag2-mcap", "ros1", "ros1-receive-times"])
def test_the_same_recording_gives_the_same_outputs_from_each_kind_of_log(logs, outputs, kind):
    """Trajectories, maps and processed.mcap byte for byte; run.json but for the log it names and the
    timings. A bag's receive times change nothing: the sweeps wait for the prior to cover them."""
    assert _differences(outputs["mcap"], outputs[kind]) == []
    for name in ("improved.tum", "baseline.tum", "wheel_odometry.tum", "improved_map.pgm", "processed.mcap"):
        assert (outputs["mcap"] / name).read_bytes() == (outputs[kind] / name).read_bytes()
    run = json.loads((outputs[kind] / "run.json").read_text())
    path = logs[1][kind]
    assert run["log"] == str(path.resolve()) and run["log_sha256"] == log_sha256(path)
    assert run["log_size_bytes"] == log_size(path) and run["warnings"] == []


@pytest.mark.parametrize("kind", ["rosbag2-sqlite3", "ros1-receive-times"])
def test_report_scores_a_bag_against_its_ground_truth(outputs, kind):
    ours, theirs = report(outputs[kind]).result, evaluate(outputs["mcap"]).result
    for method, scores in theirs["methods"].items():
        for key in ("ate_rmse_m", "ate_max_m", "rpe_1m_pct", "heading_rmse_deg", "segmentation"):
            assert ours["methods"][method][key] == scores[key], (method, key)
    assert ours["methods"]["improved"]["ate_rmse_m"] is not None and ours["methods"]["improved"]["segmentation"]
    assert ours["header"]["scenario"] is None  # the simulator's record is MCAP metadata: no bag has it
    assert (outputs[kind] / "report.html").is_file()


def test_calibrate_estimates_the_same_from_a_bag(logs, tmp_path):
    cal, paths = logs
    texts = [calibrate(paths[kind], tmp_path / f"{kind}.yaml", ProcessOptions(methods=("improved",), calibration=cal))
             .output.read_text().splitlines() for kind in ("mcap", "ros1")]
    assert texts[0][1:] == texts[1][1:]  # the first line names the log


def test_a_fleet_processes_an_mcap_a_bag_and_a_rosbag2_folder(logs, outputs, tmp_path):
    cal, paths = logs
    fleet = tmp_path / "logs"
    fleet.mkdir()
    shutil.copyfile(paths["mcap"], fleet / "a.mcap")
    shutil.copyfile(paths["ros1"], fleet / "b.bag")
    shutil.copytree(paths["rosbag2-sqlite3"], fleet / "c_rosbag2")
    summary = process_many([fleet], tmp_path / "out", ProcessOptions(calibration=cal))
    assert sorted((o.name, o.status) for o in summary.outcomes) == [("a", "done"), ("b", "done"), ("c_rosbag2", "done")]
    for name in ("a", "b", "c_rosbag2"):
        assert _differences(outputs["mcap"], tmp_path / "out" / name) == [], name
    again = process_many([fleet], tmp_path / "out", ProcessOptions(calibration=cal))
    assert [o.status for o in again.outcomes] == ["skipped"] * 3  # each log's digest unchanged
