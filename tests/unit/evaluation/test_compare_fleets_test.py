"""The fleet-level verdict of ``compare`` on fleets (a paired t-test on per-log log-ratios) on
constructed per-log values whose answer is known."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from fmcwlog.evaluation.compare_fleets import paired_test

# five logs of very different difficulty: a corridor's millimetres beside a crowd's decimetres (m)
LOGS = np.array([0.004, 0.006, 0.05, 0.20, 0.012])


def test_a_fleet_worse_on_every_log_by_a_steady_factor_is_clear():
    b = LOGS * np.array([1.48, 1.52, 1.50, 1.47, 1.53])
    r = paired_test(list(LOGS), list(b))
    assert r["clear"] and r["logs"] == 5 and r["higher_in_b"] == 5 and r["lower_in_b"] == 0
    assert r["ratio"] == pytest.approx(1.5, rel=0.01)
    d = np.log(b / LOGS)
    assert r["standard_error"] == pytest.approx(np.std(d, ddof=1) / math.sqrt(5))
    assert r["critical"] == pytest.approx(2.776, abs=1e-3)  # t(0.975, 4)


def test_the_verdict_is_scipys_paired_t_test_at_five_percent():
    rng = np.random.default_rng(3)
    for _ in range(200):
        n = int(rng.integers(5, 12))
        a = rng.uniform(0.005, 0.3, n)
        b = a * np.exp(rng.normal(rng.normal(0, 0.1), 0.15, n))
        p = stats.ttest_rel(np.log(b), np.log(a)).pvalue
        if abs(p - 0.05) > 1e-6:
            assert paired_test(list(a), list(b))["clear"] == (p < 0.05)


def test_noise_either_way_too_few_logs_and_the_same_values_give_no_verdict():
    wobble = LOGS * np.array([1.10, 0.92, 1.05, 0.95, 1.01])
    r = paired_test(list(LOGS), list(wobble))
    assert not r["clear"] and r["why_not"].startswith("within the noise")
    r = paired_test(list(LOGS[:4]), list(LOGS[:4] * 3.0))  # 3 x worse, but on 4 logs
    assert not r["clear"] and "4 paired logs: too few to judge" in r["why_not"]
    r = paired_test(list(LOGS), list(LOGS))
    assert not r["clear"] and r["why_not"] == "the same on every log"
    r = paired_test([0.1, None, 0.2, 0.3, 0.0, 0.1], [0.2, 0.5, None, 0.6, 0.1, 0.2])  # gaps and a zero: left out
    assert r["logs"] == 3 and not r["clear"]


def test_ablation_without_the_ratio_the_hard_log_hides_a_steady_loss():
    """Every log 30 % worse in B, one log 50 times harder than the rest: on the per-log ratios the
    difference is clear; on the plain differences (the same t-test on b − a) the hard log's
    difference swamps the others' and there would be no verdict."""
    a = np.array([0.010, 0.012, 0.011, 0.009, 0.50])
    b = a * 1.3 * np.array([1.02, 0.99, 1.01, 0.98, 1.0])
    r = paired_test(list(a), list(b))
    assert r["clear"] and r["higher_in_b"] == 5 and r["ratio"] == pytest.approx(1.3, rel=0.02)
    assert stats.ttest_rel(b, a).pvalue > 0.05  # the ablation: plain differences see no difference
