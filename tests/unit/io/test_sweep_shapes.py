"""Scanners of every shape decoded into sweeps: any field of view up to a full turn, any beam count,
any rate; times stored as float32, whose last beam may lie a fraction of an ulp past the period.

Messages are built here as a decoder gives them (float32 fields as the floats they hold).
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.io.messages import pointcloud_message
from fmcwlog.io.sweeps import TIME_SLACK_ULPS, InputLimits, Rejected, sweep_from_laserscan, sweep_from_pointcloud, time_slack

LOG = Path("shapes.mcap")


def f32(x: float) -> float:
    """``x`` as a float32 field holds it."""
    return float(np.float32(x))


def _ns(d):
    if isinstance(d, dict):
        return SimpleNamespace(**{k: _ns(v) for k, v in d.items()})
    if isinstance(d, list):
        return [_ns(v) for v in d]
    return d


def laserscan(n: int, angle_min: float, increment: float, time_increment: float, ranges=None, scan_time: float = 0.0):
    r = np.full(n, 5.0, np.float32) if ranges is None else np.asarray(ranges, np.float32)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=100, nanosec=0), frame_id="laser"),
        angle_min=f32(angle_min), angle_max=f32(angle_min + (n - 1) * increment), angle_increment=f32(increment),
        time_increment=f32(time_increment), scan_time=f32(scan_time), range_min=f32(0.1), range_max=f32(30.0),
        ranges=r, intensities=[])


def cloud(t: np.ndarray):
    n = len(t)
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return _ns(pointcloud_message(100_000_000_000, "lidar", {"x": 5 * np.cos(a), "y": 5 * np.sin(a), "t": t}))


def limits(rate: float) -> InputLimits:
    return InputLimits(1.0 / rate, 60.0)


def test_the_slack_is_a_few_float32_ulps_of_the_period():
    assert time_slack(0.1) == TIME_SLACK_ULPS * 2.0**-27  # 0.1 s lies in [1/16, 1/8): float32 ulp 2^-27
    assert time_slack(0.1) < 3e-8 and time_slack(1.0) < 5e-7  # far below any damage (seconds)


def test_a_full_turn_of_721_beams_whose_first_and_last_coincide():
    """0.5° from -π to +π at 10 Hz, time_increment 0.1/720 as float32: the last beam's time is
    0.1000000024 s, past the period. The sweep is used; its last beam, the first one's direction a
    period later (the next sweep's first measurement), is left out: the same sweep as 720 beams."""
    inc = 2 * math.pi / 720
    assert 720 * f32(0.1 / 720) > 0.1  # the case: beyond the period by a fraction of an ulp
    s721 = sweep_from_laserscan(LOG, laserscan(721, -math.pi, inc, 0.1 / 720), limits(10.0))
    s720 = sweep_from_laserscan(LOG, laserscan(720, -math.pi, inc, 0.1 / 720), limits(10.0))
    assert len(s721.xy) == 720
    np.testing.assert_array_equal(s721.xy, s720.xy)
    np.testing.assert_array_equal(s721.t, s720.t)


def test_the_last_beam_on_the_period_itself_in_float32_is_within_the_sweep():
    """A driver that spreads the period over n - 1 steps (the last beam at the period), and times
    stored as float32: float32(0.1) is 0.10000000149 s."""
    s = sweep_from_laserscan(LOG, laserscan(720, -math.pi, 2 * math.pi / 720, 0.1 / 719), limits(10.0))
    assert len(s.xy) == 720
    t = np.linspace(0.0, 0.1, 721).astype(np.float32)
    assert float(t[-1]) > 0.1
    assert len(sweep_from_pointcloud(LOG, cloud(t), limits(10.0))[0].t) == 721


@pytest.mark.parametrize("excess", [1e-6, 1e-3, 1.0])
def test_times_past_the_period_by_more_than_their_precision_are_still_refused(excess):
    t = np.linspace(0.0, 0.1, 721)
    t[-1] = 0.1 + excess
    with pytest.raises(Rejected) as err:
        sweep_from_pointcloud(LOG, cloud(t), limits(10.0))
    assert err.value.kind == "times" and f"{f32(0.1 + excess):.10g}" in str(err.value)  # the time as stored


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(fov_deg=st.floats(0.5, 360.0), beams=st.integers(2, 4000), rate=st.floats(1.0, 100.0),
       whole_period=st.booleans(), both_ends=st.booleans())
def test_any_field_of_view_beam_count_and_rate_is_read_whole(fov_deg, beams, rate, whole_period, both_ends):
    """Any scanner up to a full turn: its beams spread over its share of the period, or over the whole
    period (the last beam on the period), float32 time_increment: every beam is read, but the one
    that closes a full turn on the first."""
    fov = math.radians(fov_deg)
    inc = fov / (beams - 1) if both_ends else fov / beams
    span = 1.0 / rate if whole_period else (fov / (2 * math.pi)) / rate
    s = sweep_from_laserscan(LOG, laserscan(beams, -fov / 2, inc, span / (beams - 1)), limits(rate))
    closes_turn = (beams - 1) * f32(inc) >= 2 * math.pi - 0.5 * f32(inc)
    assert len(s.xy) == beams - int(closes_turn)
    assert s.t.max() <= 1.0 / rate + time_slack(1.0 / rate)
    np.testing.assert_allclose(np.hypot(s.xy[:, 0], s.xy[:, 1]), 5.0, rtol=1e-6)


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(rate=st.floats(0.5, 200.0), n=st.integers(1, 3000))
def test_float32_point_times_up_to_the_period_at_any_rate(rate, n):
    t = np.linspace(0.0, 1.0 / rate, n).astype(np.float32)
    assert len(sweep_from_pointcloud(LOG, cloud(t), limits(rate))[0].t) == n


def test_a_scan_beyond_a_full_turn_by_more_than_a_beam_is_refused():
    with pytest.raises(Rejected) as err:
        sweep_from_laserscan(LOG, laserscan(740, -math.pi, 2 * math.pi / 720, 0.1 / 740), limits(10.0))
    assert err.value.kind == "angles"


def test_what_a_cloud_layout_allows_is_judged_per_message_after_others_of_the_same_fields():
    """The fields' own checks are made once per layout; what depends on each message (its byte order,
    point_step, rows, data) is judged on each, whatever was read before with the same fields."""
    good = cloud(np.linspace(0.0, 0.09, 40))
    sweep, _ = sweep_from_pointcloud(LOG, good, limits(10.0))
    assert len(sweep.xy) == 40
    bad = [({"is_bigendian": True}, "big-endian"), ({"point_step": 8}, "point_step 8 is smaller"),
           ({"data": good.data[:-1]}, "data holds"), ({"height": 2, "width": 20}, "rows padded"),
           ({"height": 2}, "data holds")]
    for changes, words in bad:
        msg = SimpleNamespace(**{**vars(good), **changes})
        with pytest.raises(Rejected, match=words):
            sweep_from_pointcloud(LOG, msg, limits(10.0))
    again, _ = sweep_from_pointcloud(LOG, good, limits(10.0))  # and the good one still reads as it did
    assert np.array_equal(again.xy, sweep.xy) and np.array_equal(again.t, sweep.t)
    renamed = SimpleNamespace(**{**vars(good), "fields": [SimpleNamespace(**{**vars(f), "name": "y" if f.name == "x" else f.name})
                                                           for f in good.fields]})
    with pytest.raises(Rejected, match="no field 'x'"):
        sweep_from_pointcloud(LOG, renamed, limits(10.0))
