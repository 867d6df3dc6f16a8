"""`fmcwlog compare` on real outputs: the sample corridor processed twice with different parameters
(and the crowd log once), its statistics against evo's own, the page, and its one-line refusals."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from helpers import SAMPLE_LOGS

from fmcwlog.api import ProcessOptions, ProcessParams
from fmcwlog.api import process as process_log
from fmcwlog.evaluation.ground_truth import read_ground_truth
from fmcwlog.io.mcap_log import LogReader
from fmcwlog.io.outputs import write_tum

LOG = SAMPLE_LOGS / "corridor_30s.mcap"


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """corridor_30s processed with the defaults and with a coarser source voxel; crowd_30s once."""
    import dataclasses

    root = tmp_path_factory.mktemp("compare")
    coarse = dataclasses.replace(ProcessParams(), source_voxel=0.2)  # as --set frontend.source_voxel=0.2
    process_log(LOG, root / "default", ProcessOptions())
    process_log(LOG, root / "voxel02", ProcessOptions(params=coarse))
    process_log(SAMPLE_LOGS / "crowd_30s.mcap", root / "crowd", ProcessOptions())
    return root


@pytest.mark.slow
def test_compare_statistics_are_evos_on_real_outputs(runs, tmp_path):
    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.tools import file_interface

    proc = _cli("compare", str(runs / "default"), str(runs / "voxel02"), "-o", str(tmp_path / "cmp"))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert [r["name"] for r in doc["runs"]] == ["default", "voxel02"] and doc["same_log"]
    voxel = next(d for d in doc["differences"] if d["key"].endswith("source_voxel"))
    assert voxel["values"] == [0.1, 0.2]
    gt_ns, gt = read_ground_truth(LogReader(LOG))
    write_tum(tmp_path / "gt.tum", gt_ns, gt)
    ref = file_interface.read_tum_trajectory_file(str(tmp_path / "gt.tum"))
    rows = {(r["method"], r["metric"]): r for r in doc["metrics"]}
    checked = 0
    for j, run in enumerate(("default", "voxel02")):
        for m in ("improved", "baseline", "wheel_odometry"):
            est = file_interface.read_tum_trajectory_file(str(runs / run / f"{m}.tum"))
            r, e = sync.associate_trajectories(ref, est, max_diff=0.001)
            e.align(r, correct_scale=False)
            ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
            ape.process_data((r, e))
            for stat in ("rmse", "mean", "median", "std", "min", "max"):
                ours = rows[(m, f"ate_{stat}_m")]["values"][j]
                assert ours == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType(stat)), abs=1e-6), (run, m, stat)
                checked += 1
    assert checked == 36
    # the best of each row is the lowest (F1: the highest) of its values, and a verdict names it
    for row in doc["metrics"]:
        vals = [v for v in row["values"] if v is not None]
        top = min(vals) if row["better"] == "lower" else max(vals)
        assert [n for n, v in zip(("default", "voxel02"), row["values"]) if v == top] == row["best"]
        if row["verdict"]:
            assert row["verdict"].startswith(row["best"][0]) and row["beyond"]
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "★" in page and "source_voxel" in page and 'alt="position error along the path, each run"' in page
    assert "http://" not in page and "https://" not in page and "<script" not in page
    assert "wrote" in proc.stdout and "source_voxel" in proc.stdout


@pytest.mark.slow
def test_runs_of_different_logs_are_compared_and_said_to_be(runs, tmp_path):
    proc = _cli("compare", str(runs / "default"), str(runs / "crowd"), "-o", str(tmp_path / "cmp"))
    assert proc.returncode == 0, proc.stderr
    assert "different logs" in proc.stderr
    doc = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert not doc["same_log"] and len(doc["logs"]) == 2 and any("different logs" in n for n in doc["notes"])
    assert any(d["key"] == "log" for d in doc["differences"])


@pytest.mark.slow
def test_bad_inputs_are_one_line(runs, tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "batch").mkdir()
    (tmp_path / "batch" / "batch.json").write_text("{}")
    a = str(runs / "default")
    for args, words in (((a,), "needs two runs or more"),
                        ((a, str(tmp_path / "empty")), "not a 'fmcwlog process' output"),
                        ((a, str(tmp_path / "missing")), "no such folder"),
                        ((a, a), "given twice"),
                        ((a, str(tmp_path / "batch")), "a batch folder")):
        proc = _cli("compare", *args, "-o", str(tmp_path / "out"))
        lines = [x for x in proc.stderr.splitlines() if x.strip()]
        assert proc.returncode == 2 and len(lines) == 1 and words in lines[0], (args, proc.stderr)
        assert not (tmp_path / "out").exists()
    proc = _cli("compare", a, str(runs / "voxel02"))
    assert proc.returncode == 2 and "-o" in proc.stderr


@pytest.mark.slow
def test_report_of_several_runs_writes_compares_page(runs, tmp_path):
    """``report A B`` gives each run its report and writes what ``compare A B`` writes (one
    implementation: the same compare.json), beside the reports' table."""
    import shutil

    for name in ("default", "voxel02"):  # report writes into the runs' folders: copies, the fixture's stay as made
        shutil.copytree(runs / name, tmp_path / name)
    a, b = str(tmp_path / "default"), str(tmp_path / "voxel02")
    proc = _cli("report", a, b, "-o", str(tmp_path / "rep"))
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "default" / "report.html").is_file() and (tmp_path / "voxel02" / "report.html").is_file()
    assert sorted(p.name for p in (tmp_path / "rep").iterdir()) == ["compare.html", "compare.json", "comparison.json",
                                                                     "comparison.md"]
    assert _cli("compare", a, b, "-o", str(tmp_path / "cmp")).returncode == 0
    assert (tmp_path / "rep" / "compare.json").read_text() == (tmp_path / "cmp" / "compare.json").read_text()
    doc = json.loads((tmp_path / "rep" / "compare.json").read_text())
    verdicts = [r["verdict"] for r in doc["metrics"] if r["verdict"]]
    assert verdicts and all(v in proc.stdout for v in verdicts)  # printed as compare prints them
    page = (tmp_path / "rep" / "compare.html").read_text()
    assert "★" in page and "source_voxel" in page
    proc = _cli("report", a, a, "-o", str(tmp_path / "twice"))  # refused before any report is written
    assert proc.returncode == 2 and "given twice" in proc.stderr and not (tmp_path / "twice").exists()
