"""The fleet page's outlier rule: a flag needs a sample that can show an outlier and a value that
matters in absolute terms.

A ratio rule (flag the worst tenth of the logs when at least twice their median) calls the 0.9 cm
log of three at 0.2, 0.21 and 0.9 cm ATE "4.3 times the median". It is stated here (``_ratio_rule``)
so the ablation shows that fault, and :func:`outliers` not making it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmcwlog.evaluation.fleet import (
    ABSOLUTE_FLOOR,
    MIN_LOGS_TO_FLAG,
    FleetRow,
    flag_logs,
    outliers,
    render_fleet_html,
    rule_sentences,
)


def _ratio_rule(values: list[float], fraction: float = 0.10, ratio: float = 2.0) -> list[int]:
    """A ratio rule: the worst ``fraction`` (at least one) when also ``ratio`` times the median."""
    k = max(1, math.ceil(fraction * len(values)))
    median = float(np.median(values))
    worst = sorted(range(len(values)), key=lambda i: -values[i])[:k]
    return [i for i in worst if values[i] >= ratio * median]


def _row(name: str, ate: float | None = None, feature: float | None = None, disagree: float | None = None) -> FleetRow:
    return FleetRow(name, None, "done", ground_truth=ate is not None, ate_rmse_m={"improved": ate},
                    feature_avg_rel_error_pct={"improved": feature}, methods_disagreement_m=disagree, sweeps=300)


THREE_SMALL = [0.009, 0.002, 0.0021]  # m: 0.9 cm is "4.3 times the median", and fine


def test_three_small_logs_the_ratio_rule_flags_and_the_new_one_does_not():
    assert _ratio_rule(THREE_SMALL) == [0]  # the fault, with a ratio rule
    test = outliers(THREE_SMALL, ABSOLUTE_FLOOR["ate_rmse_m"])
    assert test.flagged == () and test.too_few and test.threshold is None
    # even a large error among three logs is not an outlier the sample can show
    assert outliers([0.01, 0.012, 0.9], ABSOLUTE_FLOOR["ate_rmse_m"]).flagged == ()


def test_a_real_outlier_among_ten_logs_is_flagged_and_only_it():
    rng = np.random.default_rng(0)
    values = list(0.02 + 0.01 * rng.random(9)) + [0.40]  # nine logs at 2-3 cm, one at 40 cm
    test = outliers(values, ABSOLUTE_FLOOR["ate_rmse_m"])
    assert test.flagged == (9,) and not test.too_few
    assert 0.02 < test.median < 0.03 and test.median < test.threshold < 0.40


def test_a_small_value_is_never_flagged_however_far_from_the_others():
    values = [0.001] * 9 + [0.03]  # 30 times the others' median, MAD 0: an outlier by the spread alone
    assert outliers(values, 0.0).flagged == (9,)  # ablation: without the floor it is flagged
    assert outliers(values, ABSOLUTE_FLOOR["ate_rmse_m"]).flagged == ()
    assert outliers([2.0] * 9 + [4.9], ABSOLUTE_FLOOR["feature_avg_rel_error_pct"]).flagged == ()  # %, under 5
    assert outliers([2.0] * 9 + [9.0], ABSOLUTE_FLOOR["feature_avg_rel_error_pct"]).flagged == (9,)


def test_the_threshold_is_the_median_plus_3_5_robust_sigma():
    values = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 30.0]  # median 5, MAD 2 (|v - 5|: 4 3 2 1 0 1 2 3 25)
    test = outliers(values, 0.0)
    assert test.median == 5.0 and test.threshold == pytest.approx(5.0 + 3.5 * 1.4826 * 2.0)
    assert test.flagged == (8,)


def test_the_sample_size_boundary():
    below = [0.02] * (MIN_LOGS_TO_FLAG - 2) + [0.5]
    assert outliers(below, ABSOLUTE_FLOOR["ate_rmse_m"]).too_few
    assert outliers(below + [0.02], ABSOLUTE_FLOOR["ate_rmse_m"]).flagged == (MIN_LOGS_TO_FLAG - 2,)


def test_the_fleet_page_says_too_few_logs_and_flags_nothing_for_three():
    rows = [_row(f"log{i}", ate=v, feature=f) for i, (v, f) in enumerate(zip(THREE_SMALL, (2.9, 0.7, 0.6)))]
    ranked = flag_logs(rows)
    assert not any(r.flags for r in rows)
    assert all(m["too_few"] and m["logs"] == 3 for m in ranked)
    result = {"logs": [r.to_json() for r in rows], "outlier_rule": {"min_logs": MIN_LOGS_TO_FLAG, "z": 3.5,
                                                                     "metrics": ranked}}
    said = rule_sentences(result)
    assert "Too few logs with ground truth to flag outliers by ATE RMSE: 3 (at least 8 needed)." in said
    totals = {"logs": 3, "done": 3, "failed": 0, "with_ground_truth": 3, "sweeps": 900, "duration_s": 90.0,
              "distance_m": 90.0, "processing_s": 3.0, "batch_wall_s": None, "methods": {}}
    page = render_fleet_html({**result, "out_dir": "/x/fleet", "totals": totals, "flagged": []})
    assert "Too few logs with ground truth to flag outliers by feature error: 3" in page
    assert "Nothing flagged." in page


def test_flag_logs_flags_the_outlier_of_ten_with_its_median_and_threshold():
    rows = [_row(f"gt{i}", ate=0.02 + 0.001 * i) for i in range(9)] + [_row("gt-bad", ate=0.5)]
    rows += [_row(f"free{i}", disagree=0.03 + 0.002 * i) for i in range(9)] + [_row("free-bad", disagree=0.6)]
    ranked = flag_logs(rows)
    assert {r.name for r in rows if r.flags} == {"gt-bad", "free-bad"}
    assert rows[9].flags[0].startswith("ATE RMSE 50.0 cm (improved): an outlier among the 10 logs with ground truth")
    assert [(m["metric"], m["logs"], m["too_few"]) for m in ranked] == [
        ("ate_rmse_m", 10, False), ("feature_avg_rel_error_pct", 0, True), ("methods_disagreement_m", 10, False)]
