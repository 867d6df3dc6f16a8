"""`fmcwlog compare` on fleets: five simulated crowd logs processed as a batch with the defaults and
with the moving-point segmentation off (an ablation that lets walkers into the scan matching), the
logs paired by their sha256, each log's values against its own report, the verdicts, and the refusals."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
from helpers import copy_log

from fmcwlog.api import report

SEEDS = (1, 2, 3, 4, 5)


def _cli(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def fleets(tmp_path_factory):
    """default/: crowd1-5, nogt1 (crowd1 without its ground truth) and corridor1 (only here); noseg/:
    crowd1-5 and nogt1 with --set frontend.segment=false."""
    root = tmp_path_factory.mktemp("fleets")
    logs, extra = root / "logs", root / "extra"
    logs.mkdir()
    extra.mkdir()
    for s in SEEDS:
        assert _cli("record", "--scenario", "crowd", "--duration", "10", "--seed", str(s),
                    "-o", str(logs / f"crowd{s}.mcap")).returncode == 0
    copy_log(logs / "crowd1.mcap", logs / "nogt1.mcap", drop_topics=("/ground_truth/odom", "/ground_truth/point_labels"),
             drop_metadata=("fmcwlog.world", "fmcwlog.sim"))
    assert _cli("record", "--duration", "10", "--seed", "1", "-o", str(extra / "corridor1.mcap")).returncode == 0
    proc = _cli("process", str(logs), str(extra), "-o", str(root / "default"), "--jobs", "2")
    assert proc.returncode == 0, proc.stderr
    proc = _cli("process", str(logs), "-o", str(root / "noseg"), "--jobs", "2", "--set", "frontend.segment=false")
    assert proc.returncode == 0, proc.stderr
    return root


def _evo_rmse(folder):
    """RMSE (m) of the baseline positions after evo's alignment without scale onto the improved ones
    (planar trajectories: a rotation about z and a shift), at their common sweeps."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(folder / "improved.tum"))
    est = file_interface.read_tum_trajectory_file(str(folder / "baseline.tum"))
    ref, est = sync.associate_trajectories(ref, est, max_diff=1e-6)
    est.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return ape.get_statistic(metrics.StatisticsType.rmse)


def _rows(doc):
    return {(r["method"], r["metric"]): r for r in doc["metrics"]}


@pytest.mark.slow
def test_fleets_pair_by_log_and_each_value_is_the_logs_own_report(fleets, tmp_path):
    proc = _cli("compare", str(fleets / "default"), str(fleets / "noseg"), "-o", str(tmp_path / "cmp"))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert doc["schema"] == "fmcwlog.compare_fleets/1"
    assert [f["name"] for f in doc["fleets"]] == ["default", "noseg"]
    assert [lg["name"] for lg in doc["logs"]] == [*(f"crowd{s}" for s in SEEDS), "nogt1"]
    assert doc["unpaired"] == [{"id": doc["unpaired"][0]["id"], "name": "corridor1", "in": ["default"]}]
    assert "corridor1: only in default" in proc.stderr
    assert [d["key"] for d in doc["differences"]] == ["params.segment"]
    assert doc["differences"][0]["values"] == [True, False] and not doc["differences"][0]["varies"]
    # each log's values: what 'fmcwlog report' of that log's run gives (on a copy: report writes into it)
    rows = _rows(doc)
    checked = 0
    for j, fleet in enumerate(("default", "noseg")):
        for i, lg in enumerate(doc["logs"]):
            copy = tmp_path / fleet / lg["name"]
            shutil.copytree(fleets / fleet / lg["folders"][j], copy)
            report(copy)
            rep = json.loads((copy / "report.json").read_text())
            for m in ("improved", "baseline"):
                for key in ("ate_rmse_m", "ms_per_sweep_median"):
                    ours, theirs = rows[(m, key)]["values"][i][j], rep["methods"][m][key]
                    assert (ours is None and theirs is None) or ours == pytest.approx(theirs, rel=1e-12)
                    checked += theirs is not None
    assert checked == 44  # 6 logs, 2 fleets, 2 methods, 2 metrics; no ATE on nogt1
    # without ground truth: how far baseline and improved part, as evo_ape of one against the other
    free = rows[("improved vs baseline", "methods_disagreement_m")]
    assert [vs[0] is not None for vs in free["values"]] == [False] * 5 + [True]
    for j, fleet in enumerate(("default", "noseg")):
        assert free["values"][5][j] == pytest.approx(_evo_rmse(fleets / fleet / "nogt1"), rel=1e-6)
    assert free["comparisons"][0]["logs"] == 1 and "too few to judge" in free["comparisons"][0]["why_not"]
    # best per log and medians follow from the values
    for row in doc["metrics"]:
        for vs, best in zip(row["values"], row["best"]):
            have = [v for v in vs if v is not None]
            assert best == [n for n, v in zip(("default", "noseg"), vs) if have and v == min(have)]
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "params.segment" in page and "corridor1" in page and "★" in page and "t(0.975, n − 1)" in page
    assert page.count("<img") == len(doc["metrics"]) and "http://" not in page and "<script" not in page


@pytest.mark.slow
def test_an_ablated_fleet_is_judged_worse_and_a_copy_is_judged_the_same(fleets, tmp_path):
    """Segmentation off lets walkers into ICP: the improved method's ATE RMSE is several times the
    default's on every crowd log (measured: 0.53 cm vs 2.68 cm median, 5.2 x); the baseline has no
    segmentation stage, its values are the same on every log, and it gets no verdict."""
    assert _cli("compare", str(fleets / "default"), str(fleets / "noseg"), "-o", str(tmp_path / "cmp")).returncode == 0
    rows = _rows(json.loads((tmp_path / "cmp" / "compare.json").read_text()))
    ate = rows[("improved", "ate_rmse_m")]["comparisons"][0]
    assert ate["clear"] and ate["logs"] == 5 and ate["higher_in_b"] == 5 and ate["ratio"] > 2.5
    assert ate["verdict"].startswith("default is better: noseg's ATE RMSE is")
    base = rows[("baseline", "ate_rmse_m")]["comparisons"][0]
    assert not base["clear"] and base["verdict"] is None and base["why_not"] == "the same on every log"
    # a fleet against a copy of itself: every value the same, not one verdict
    shutil.copytree(fleets / "default", tmp_path / "again")
    proc = _cli("compare", str(fleets / "default"), str(tmp_path / "again"), "-o", str(tmp_path / "same"))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "same" / "compare.json").read_text())
    assert len(doc["logs"]) == 7 and not doc["unpaired"] and not doc["differences"]
    assert all(c["verdict"] is None for r in doc["metrics"] for c in r["comparisons"])
    assert "no clear difference between the fleets" in proc.stdout


@pytest.mark.slow
def test_too_few_paired_logs_are_said_to_be(fleets, tmp_path):
    for fleet in ("default", "noseg"):
        for s in SEEDS[:3]:
            shutil.copytree(fleets / fleet / f"crowd{s}", tmp_path / fleet / f"crowd{s}")
    proc = _cli("compare", str(tmp_path / "default"), str(tmp_path / "noseg"), "-o", str(tmp_path / "cmp"))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    ate = _rows(doc)[("improved", "ate_rmse_m")]["comparisons"][0]
    assert ate["logs"] == 3 and not ate["clear"] and "too few to judge" in ate["why_not"]
    assert "too few to judge" in proc.stderr and "no clear difference" not in proc.stdout
    assert "Too few paired logs to judge" in (tmp_path / "cmp" / "compare.html").read_text()


@pytest.mark.slow
def test_a_run_among_fleets_is_one_line(fleets, tmp_path):
    fleet, run = str(fleets / "default"), str(fleets / "noseg" / "crowd1")
    for args, words in (((fleet, run), "a single run among batch folders"),
                        ((run, fleet), "a batch folder (many logs) among single runs"),
                        ((fleet,), "needs two fleets or more"),
                        ((fleet, fleet), "given twice")):
        proc = _cli("compare", *args, "-o", str(tmp_path / "out"))
        lines = [x for x in proc.stderr.splitlines() if x.strip()]
        assert proc.returncode == 2 and len(lines) == 1 and words in lines[0], (args, proc.stderr)
        assert not (tmp_path / "out").exists()
