"""Gaps in the sweeps: found from the stamps, bridged with a covariance that grows with them, and the
motion prior kept from the last sweep across a gap longer than its usual window."""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.frontend.gaps import GapFinder, GapParams, bridge_covariance, gap_window, within_bridge
from fmcwlog.frontend.motion_prior import PoseTrack
from fmcwlog.frontend.twist_fusion import WheelNoise
from fmcwlog.kernels.correlative import CorrelativeParams


@pytest.mark.parametrize("scan_rate", [10.0, None])
def test_gaps_are_intervals_longer_than_a_few_periods(scan_rate):
    finder = GapFinder(3.0, scan_rate)
    stamps = [0.1 * i for i in range(10)] + [0.9 + 0.3, 0.9 + 0.3 + 2.0]  # 0.3 s: 3 periods, not a gap
    found = [finder.observe(t) for t in stamps]
    assert found[:-1] == [0.0] * 11
    assert found[-1] == pytest.approx(1.9)
    assert len(finder.gaps) == 1 and finder.gaps[0].start == pytest.approx(1.3)
    assert "1 gap in the sweeps on /scan" in (finder.warning("/scan") or "")
    assert GapFinder(3.0).warning("/scan") is None


def test_an_unevenly_subsampled_log_is_not_all_gaps():
    """A log that kept a scan every few seconds, now and then two within 0.3 s (as the Intel subset
    does): without a scan rate the period is the intervals' median, so only a pause of many periods
    is a gap (with the shortest interval as the period, nearly every interval was one)."""
    rng = np.random.default_rng(0)
    intervals = rng.uniform(2.5, 4.5, 300)
    intervals[::17] = 0.3
    intervals[200] = 40.0  # a real pause
    stamps = np.concatenate([[0.0], np.cumsum(intervals)])
    finder = GapFinder(3.0)
    found = [finder.observe(float(t)) for t in stamps]
    assert len(finder.gaps) == 1 and finder.gaps[0].start == pytest.approx(stamps[200] + finder.period, abs=1.0)
    assert sum(g > 0 for g in found) == 1


def test_the_bridge_widens_with_the_gap():
    noise = WheelNoise()
    short = bridge_covariance(np.array([2.0, 0.0, 0.0]), 2.0, noise)
    long = bridge_covariance(np.array([6.0, 0.0, 0.0]), 6.0, noise)
    held = bridge_covariance(None, 6.0, noise)
    assert np.all(np.diag(long) > np.diag(short)) and np.all(np.diag(held) > np.diag(long))
    base, p = CorrelativeParams(), GapParams()
    narrow, wide = gap_window(short, base, p), gap_window(held, base, p)
    assert narrow.linear_window >= base.linear_window and wide.linear_window == p.max_linear_window
    assert wide.angular_window_deg == p.max_angular_window_deg
    assert within_bridge(np.array([0.1, 0.0, 0.0]), np.zeros(3), short, 4.0)
    assert not within_bridge(np.array([0.0, 2.0, 0.0]), np.zeros(3), short, 4.0)


def test_the_track_is_kept_from_the_last_sweep_across_a_long_gap():
    track = PoseTrack(keep_seconds=1.0)
    track.hold_from = 0.0
    for i in range(2000):  # 20 s at 100 Hz, straight at 1 m/s: the buffer shifts many times
        track.add_pose(0.01 * i, np.array([0.01 * i, 0.0, 0.0]))
    assert track.delta(0.0, 19.99)[0] == pytest.approx(19.99)
    unheld = PoseTrack(keep_seconds=1.0)
    for i in range(2000):
        unheld.add_pose(0.01 * i, np.array([0.01 * i, 0.0, 0.0]))
    assert unheld.delta(0.0, 19.99)[0] < 19.0  # clamped to the first pose kept
