"""compare's best-marking, spread and verdicts on constructed runs whose answer is known: a run
clearly better than another, and one whose difference is within what the log's segments wander by."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fmcwlog.evaluation import compare as C
from fmcwlog.evaluation.evaluate import Evaluation

RMSE = next(m for m in C.METRICS if m.key == "ate_rmse_m")
F1 = next(m for m in C.METRICS if m.key == "segmentation.f1")


def _judge(metric, values, segs, paired=True):
    names = [f"run{i}" for i in range(len(values))]
    return C.judge(metric, names, values, lambda b, i: C.spread_between(segs[b], segs[i], paired))


def test_the_lower_error_is_best_and_the_higher_f1():
    segs = [None, None, None]
    assert _judge(RMSE, [0.3, 0.1, None], segs)["best"] == ["run1"]
    assert _judge(F1, [0.90, 0.95, 0.95], segs)["best"] == ["run1", "run2"]  # a tie: both marked
    assert _judge(RMSE, [None, None], segs)["best"] == []
    r = _judge(RMSE, [0.3, 0.1], segs)
    assert r["verdict"] is None and r["beyond"] == []  # no segment series: marked best, no verdict


def test_a_run_clearly_better_gets_a_verdict_and_one_within_the_spread_does_not():
    base = np.array([0.10, 0.30, 0.20, 0.50, 0.40])  # the log's hard and easy stretches (m)
    clearly_worse = 1.5 * base  # every stretch worse by half: 15 cm on average
    as_good = base + np.array([0.05, -0.05, 0.05, -0.05, 0.0]) + 0.001  # 1 mm worse, wandering 5 cm a stretch
    values = [float(np.mean(x)) for x in (base, clearly_worse, as_good)]
    r = _judge(RMSE, values, [base, clearly_worse, as_good])
    assert r["best"] == ["run0"] and r["beyond"] == ["run1"], r
    assert r["verdict"].startswith("run0 is lower") and "within the spread of it: run2" in r["verdict"]
    # the spreads: of the segment-by-segment differences, over sqrt(5)
    assert r["judged_against"][1] == pytest.approx(np.std(0.5 * base, ddof=1) / np.sqrt(5))
    assert r["judged_against"][2] == pytest.approx(np.std(as_good - base, ddof=1) / np.sqrt(5))
    assert r["judged_against"][0] is None


def test_ablation_unpaired_spread_hides_a_difference_the_paired_segments_show():
    """Segments of one log pair up: what both runs find hard cancels. Judged as if from different
    logs (each run's spread over its own segments), a uniform 10 % worse run is within the spread."""
    base = np.array([0.05, 0.60, 0.20, 1.00, 0.30])
    a, b = base, 1.1 * base
    values = [float(np.mean(a)), float(np.mean(b))]
    assert _judge(RMSE, values, [a, b], paired=True)["beyond"] == ["run1"]
    assert _judge(RMSE, values, [a, b], paired=False)["beyond"] == []


def test_ablation_without_the_spread_every_difference_is_a_verdict(monkeypatch):
    a = np.array([0.10, 0.30, 0.20, 0.50, 0.40])
    b = a + np.array([0.05, -0.05, 0.05, -0.05, 0.0]) + 0.001  # 1 mm worse on average, 5 cm either way a stretch
    values = [float(np.mean(a)), float(np.mean(b))]
    assert _judge(RMSE, values, [a, b])["verdict"] is None
    monkeypatch.setattr(C, "VERDICT_FACTOR", 0.0)
    assert _judge(RMSE, values, [a, b])["verdict"] is not None


def test_segment_values_and_spread():
    x = np.arange(10.0)  # two values per segment: means 0.5, 2.5, 4.5, 6.5, 8.5
    seg = C.segment_values(x, np.mean)
    assert seg == pytest.approx([0.5, 2.5, 4.5, 6.5, 8.5])
    assert C.spread(seg) == pytest.approx(np.std(seg, ddof=1) / np.sqrt(5))
    assert C.segment_values(np.arange(9.0), np.mean) is None  # fewer than 2 a segment
    assert C.segment_values(None, np.mean) is None and C.segment_values(x, None) is None
    # paired: a constant offset between two runs has no spread at all
    assert C.spread_between(seg, seg + 1.0, paired=True) == pytest.approx(0.0, abs=1e-12)
    assert C.spread_between(seg, seg + 1.0, paired=False) == pytest.approx(np.sqrt(2) * C.spread(seg))


def test_settings_that_differ_are_named():
    runs = [{"log": "a.mcap", "prior": "wheel ticks", "backend": {"kind": "pose-graph"},
             "params": {"frontend": {"source_voxel": 0.1, "icp": {"huber": 0.1}}, "keep": 1}},
            {"log": "a.mcap", "prior": "wheel ticks", "backend": {"kind": "none"},
             "params": {"frontend": {"source_voxel": 0.2, "icp": {"huber": 0.1}}, "keep": 1, "new": True}}]
    diffs = {d["key"]: d["values"] for d in C.differences(runs)}
    assert diffs == {"backend.kind": ["pose-graph", "none"], "params.frontend.source_voxel": [0.1, 0.2],
                     "params.new": [None, True]}


def test_runs_with_the_same_folder_name_are_told_apart():
    assert C.run_names([Path("x/out"), Path("y/out"), Path("z/b")]) == ["x/out", "y/out", "b"]
    assert C.run_names([Path("x/out"), Path("x/out2")]) == ["out", "out2"]


def _evaluation(name: str, errors: np.ndarray, log_sha: str = "aa") -> Evaluation:
    t = np.arange(len(errors)) * 0.1
    ev = Evaluation(Path(name), Path("log.mcap"), {"log_sha256": log_sha, "params": {"v": name}, "sweeps": len(t)})
    ev.gt = np.zeros((2, 3))
    ev.aligned["improved"] = (t, np.zeros((len(t), 3)), errors)
    e = errors
    ev.result = {"sweeps": len(t), "wall_seconds": 1.0, "wall_sweeps_per_second": float(len(t)),
                 "methods": {"improved": {"ate_rmse_m": float(np.sqrt(np.mean(e**2))), "ate_mean_m": float(np.mean(e)),
                                          "ate_median_m": float(np.median(e)), "ate_std_m": float(np.std(e)),
                                          "ate_min_m": float(e.min()), "ate_max_m": float(e.max())}}}
    return ev


def test_comparison_of_constructed_runs():
    s = np.linspace(0.0, 1.0, 100)
    path = 0.02 + 0.05 * np.sin(3 * s) ** 2  # the log's hard stretch in the middle (m)
    good, bad = _evaluation("good", path), _evaluation("bad", 2.0 * path)
    doc = C.comparison([good, bad], ["good", "bad"])
    rmse = next(r for r in doc["metrics"] if r["metric"] == "ate_rmse_m")
    assert rmse["best"] == ["good"] and rmse["beyond"] == ["bad"] and rmse["verdict"].startswith("good is lower")
    assert next(r for r in doc["metrics"] if r["metric"] == "ate_max_m")["verdict"] is None  # an extreme: no series
    assert doc["same_log"] and doc["differences"] == [{"key": "params.v", "values": ["good", "bad"]}]
    other = _evaluation("elsewhere", path, log_sha="bb")
    doc = C.comparison([good, other], ["good", "elsewhere"])
    assert not doc["same_log"] and any("different logs" in n for n in doc["notes"])
    html = C.render_html(doc, [good, other])
    assert "different logs" in html and html.count("★") >= 1 and 'alt="position error along the path, each run"' in html
