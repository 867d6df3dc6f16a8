"""Wheel odometry checked against hand geometry (no values copied from the code).

Ticks go through the motion prior exactly as ``fmcwlog process`` feeds them
(:class:`fmcwlog.frontend.motion_prior.PoseTrack`, one reading at a time).
"""

import numpy as np
import pytest
from helpers import same_bits
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.motion_prior import PoseTrack
from fmcwlog.frontend.odometry import body_increments, integrate_arc, integrate_arcs, ticks_step
from fmcwlog.geometry import compose, interpolate_poses, wrap_angle
from fmcwlog.types import WheelCalibration


def _track(stamps, left, right, cal) -> PoseTrack:
    track = PoseTrack(keep_seconds=1e9)
    for t, lt, rt in zip(stamps, left, right):
        track.add_ticks(float(t), int(lt), int(rt), cal)
    return track


def integrate_wheel_odometry(stamps, left, right, cal, initial_pose=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Poses (N, 3) at each reading, starting from ``initial_pose``."""
    return compose(np.asarray(initial_pose, float), _track(stamps, left, right, cal).pose_at(np.asarray(stamps)))


def wheel_speeds_from_ticks(stamps, left, right, cal) -> tuple[np.ndarray, np.ndarray]:
    """Mean forward speed and yaw rate over each interval, from the track's motion."""
    track = _track(stamps, left, right, cal)
    d = np.array([track.delta(a, b) for a, b in zip(stamps[:-1], stamps[1:])])
    dt = np.diff(stamps)
    # the chord of an arc is shorter than the arc: undo it to get the travelled distance
    arc = np.hypot(d[:, 0], d[:, 1]) * np.where(np.abs(d[:, 2]) > 1e-12, (d[:, 2] / 2) / np.sin(d[:, 2] / 2 + 1e-300), 1.0)
    return np.sign(d[:, 0]) * arc / dt, d[:, 2] / dt


def test_straight_line_exact_distance():
    # r = 0.1 m, k = 1000: one tick = 2π·0.1/1000 m. 5000 ticks = 5 revolutions = π m.
    cal = WheelCalibration(0.1, 0.1, 0.5, 1000)
    n = 51
    stamps = np.linspace(0.0, 5.0, n)
    left = -2_000_000 + np.arange(n, dtype=np.int64) * 100  # arbitrary negative start
    right = 7 + np.arange(n, dtype=np.int64) * 100
    poses = integrate_wheel_odometry(stamps, left, right, cal, initial_pose=(1.0, 2.0, np.pi / 2))
    # heading +y: 5 revolutions of a 0.1 m wheel = π m straight along +y
    np.testing.assert_allclose(poses[-1], [1.0, 2.0 + np.pi, np.pi / 2], atol=1e-12)
    v, w = wheel_speeds_from_ticks(stamps, left, right, cal)
    np.testing.assert_allclose(v, np.pi / 5.0, rtol=1e-12)
    np.testing.assert_allclose(w, 0.0, atol=1e-15)


def test_reverse_driving_negative_ticks():
    cal = WheelCalibration(0.05, 0.05, 0.4, 200)
    stamps = np.arange(11) * 0.1
    ticks = -np.arange(11, dtype=np.int64) * 40  # 2 revolutions backwards in total
    poses = integrate_wheel_odometry(stamps, ticks, ticks, cal)
    np.testing.assert_allclose(poses[-1], [-2 * 2 * np.pi * 0.05, 0.0, 0.0], atol=1e-12)


def test_circle_closes_and_stays_on_circle():
    # Circle of radius R = 1 m turning left, track b = 0.5 m:
    # left wheel on radius 0.75, right on 1.25. Tick length = 2π·0.05/1000 m.
    # Full circle: left 2π·0.75 / tick = 15000 ticks, right 25000 ticks.
    cal = WheelCalibration(0.05, 0.05, 0.5, 1000)
    n = 101
    stamps = np.linspace(0, 20, n)
    left = 123 + np.arange(n, dtype=np.int64) * 150
    right = -99 + np.arange(n, dtype=np.int64) * 250
    poses = integrate_wheel_odometry(stamps, left, right, cal)
    np.testing.assert_allclose(poses[-1, :2], [0.0, 0.0], atol=1e-9)
    assert abs(wrap_angle(poses[-1, 2])) < 1e-9
    # every sample on the circle centred (0, 1) with radius 1, heading tangent
    r = np.hypot(poses[:, 0], poses[:, 1] - 1.0)
    np.testing.assert_allclose(r, 1.0, atol=1e-12)
    # half way round: the top of the circle, heading -x
    np.testing.assert_allclose(poses[50, :2], [0.0, 2.0], atol=1e-12)
    assert abs(wrap_angle(poses[50, 2] - np.pi)) < 1e-12
    v, w = wheel_speeds_from_ticks(stamps, left, right, cal)
    np.testing.assert_allclose(v, 2 * np.pi / 20, rtol=1e-12)  # circumference / time
    np.testing.assert_allclose(w, 2 * np.pi / 20, rtol=1e-12)  # R = v/ω = 1


def test_hand_computed_pivot_about_left_wheel():
    # Left wheel still, right wheel rolls b·π/2: the robot pivots 90° about its left
    # wheel at (0, b/2). The axle midpoint ends at (b/2, b/2) heading +y.
    # b = 0.4, r = 0.1, k = 1000: s_R = 0.2π = 2π·0.1·n/1000  ->  n = 1000 ticks.
    cal = WheelCalibration(0.1, 0.1, 0.4, 1000)
    poses = integrate_wheel_odometry(
        np.array([0.0, 1.0]), np.array([5000, 5000]), np.array([-123, 877]), cal
    )
    np.testing.assert_allclose(poses[-1], [0.2, 0.2, np.pi / 2], atol=1e-12)


def test_unequal_radii_turns_towards_smaller_wheel():
    # Equal ticks, right wheel 10% larger: right travels further -> turns left (ω>0).
    cal = WheelCalibration(0.10, 0.11, 0.5, 100)
    stamps = np.array([0.0, 1.0])
    v, w = wheel_speeds_from_ticks(stamps, np.array([0, 100]), np.array([0, 100]), cal)
    np.testing.assert_allclose(v, [2 * np.pi * 0.105])
    np.testing.assert_allclose(w, [2 * np.pi * 0.01 / 0.5])


def test_matches_loop_of_exact_arc_steps():
    # Second implementation: a Python loop composing each interval's relative arc
    # pose (R sinΔθ, R(1-cosΔθ), Δθ) with geometry.compose.
    rng = np.random.default_rng(3)
    cal = WheelCalibration(0.098, 0.102, 0.45, 512)
    n = 200
    left = np.cumsum(rng.integers(-5, 60, n)).astype(np.int64) - 10**6
    right = np.cumsum(rng.integers(-5, 60, n)).astype(np.int64) + 10**9
    stamps = np.arange(n) * 0.02
    got = integrate_wheel_odometry(stamps, left, right, cal, initial_pose=(3.0, -1.0, 2.5))
    pose = np.array([3.0, -1.0, 2.5])
    tick = 2 * np.pi / cal.ticks_per_revolution
    for i in range(n - 1):
        sl = (left[i + 1] - left[i]) * tick * cal.wheel_radius_left
        sr = (right[i + 1] - right[i]) * tick * cal.wheel_radius_right
        s, dth = (sl + sr) / 2, (sr - sl) / cal.track_width
        if abs(dth) < 1e-12:
            rel = np.array([s, 0.0, 0.0])
        else:
            rad = s / dth
            rel = np.array([rad * np.sin(dth), rad * (1 - np.cos(dth)), dth])
        pose = compose(pose, rel)
        np.testing.assert_allclose(got[i + 1, :2], pose[:2], atol=1e-9)
        assert abs(wrap_angle(got[i + 1, 2] - pose[2])) < 1e-9


def test_stamps_going_back_are_refused_and_repeats_skipped():
    cal = WheelCalibration(0.1, 0.1, 0.5, 100)
    track = _track([0.0, 1.0], [0, 10], [0, 10], cal)
    assert not track.add_ticks(1.0, 20, 20, cal) and track.repeated_stamps == 1  # same stamp: skipped
    with pytest.raises(ValueError, match="backwards"):
        track.add_ticks(0.5, 30, 30, cal)


# --- the one-reading-at-a-time paths against the array formulas, bit for bit
_ticks = st.integers(-(2**40), 2**40)
_cal = st.builds(WheelCalibration, st.floats(0.005, 2.0), st.floats(0.005, 2.0), st.floats(0.02, 10.0),
                 st.integers(1, 10**8))


@settings(max_examples=300, deadline=None)
@given(_ticks, _ticks, _ticks, _ticks, _cal)
def test_one_interval_is_the_array_formula(l0, l1, r0, r1, cal):
    """Two int64 readings (the motion prior's case, on floats) against lists of them (the arrays)."""
    fast = body_increments(np.array([l0, l1]), np.array([r0, r1]), cal)
    slow = body_increments([l0, l1], [r0, r1], cal)
    assert all(a.dtype == b.dtype and a.tobytes() == b.tobytes() for a, b in zip(fast, slow))


@settings(max_examples=300, deadline=None)
@given(st.floats(-5.0, 5.0), st.one_of(st.floats(-3.0, 3.0), st.sampled_from([0.0, -0.0, 1e-300])),
       st.tuples(st.floats(-100.0, 100.0), st.floats(-100.0, 100.0), st.floats(-10.0, 10.0)))
def test_one_arc_is_the_array_formula(ds, dtheta, pose):
    """:func:`integrate_arc` on floats against :func:`integrate_arcs` over one arc."""
    got = integrate_arc(np.float64(ds), np.float64(dtheta), np.array(pose))
    assert same_bits(got, integrate_arcs(np.array([ds]), np.array([dtheta]), pose)[1])


def test_interpolate_poses_is_the_np_unwrap_formula():
    """The runner's reads of the prior (yaw unwrapped without a jump, the short path) and tracks
    that cross ±π (np.unwrap itself) against the formula with ``np.unwrap``."""
    rng = np.random.default_rng(11)
    for crossing in (False, True):
        for _ in range(200):
            n = int(rng.integers(2, 300))
            t = np.cumsum(rng.uniform(0.001, 0.05, n))
            yaw = np.cumsum(rng.normal(0, 0.02 if not crossing else 0.5, n)) + rng.uniform(-3, 3)
            poses = np.column_stack([rng.normal(0, 5, (n, 2)), wrap_angle(yaw)])
            poses[rng.integers(0, n), 2] = -0.0
            q = rng.uniform(t[0] - 0.1, t[-1] + 0.1, 3)
            want = np.empty((3, 3))
            want[:, 0], want[:, 1] = np.interp(q, t, poses[:, 0]), np.interp(q, t, poses[:, 1])
            want[:, 2] = wrap_angle(np.interp(q, t, np.unwrap(poses[:, 2])))
            assert interpolate_poses(q, t, poses).tobytes() == want.tobytes()


@settings(max_examples=300, deadline=None)
@given(_ticks, _ticks, _ticks, _ticks, _cal,
       st.tuples(st.floats(-100.0, 100.0), st.floats(-100.0, 100.0), st.floats(-10.0, 10.0)))
def test_ticks_step_is_increments_then_arc(l0, l1, r0, r1, cal, pose):
    """:func:`ticks_step` (floats, the motion prior's path) against :func:`body_increments` then
    :func:`integrate_arc`, bit for bit."""
    ds, dth = body_increments(np.array([l0, l1]), np.array([r0, r1]), cal)
    want = integrate_arc(ds[0], dth[0], np.array(pose))
    got = ticks_step(*pose, l1 - l0, r1 - r0, cal)
    assert got is not None and np.array(got).tobytes() == want.tobytes()


def test_ticks_step_declines_beyond_int64():
    cal = WheelCalibration(0.1, 0.1, 0.5, 100)
    assert ticks_step(0.0, 0.0, 0.0, 2**63, 0, cal) is None
    assert ticks_step(0.0, 0.0, 0.0, 0, -(2**63) - 1, cal) is None


def test_track_reads_are_the_array_formulas():
    """A track fed reading by reading (the scalar path, its unwrapped yaw kept between reads) gives
    the poses of the array formulas, read after every reading and several times in between, across
    the buffer's shifts and ±π."""
    rng = np.random.default_rng(5)
    cal = WheelCalibration(0.1, 0.11, 0.5, 1000)
    n = 900
    stamps = np.cumsum(rng.uniform(0.015, 0.025, n))
    left = np.cumsum(rng.integers(0, 60, n))
    right = np.cumsum(rng.integers(0, 90, n))
    track = PoseTrack(keep_seconds=2.0)
    poses = [np.zeros(3)]
    for i in range(n):
        track.add_ticks(float(stamps[i]), int(left[i]), int(right[i]), cal)
        if i:
            ds, dth = body_increments(left[i - 1:i + 1], right[i - 1:i + 1], cal)
            poses.append(integrate_arc(ds[0], dth[0], poses[-1]))
        m = len(track)
        kept_t, kept_p = stamps[i + 1 - m:i + 1], np.array(poses[i + 1 - m:i + 1])
        assert track._p[:m].tobytes() == kept_p.tobytes()
        for q in (stamps[i] - 0.05, np.array([stamps[i] - 0.3, stamps[i] + 0.01]), stamps[i]):
            assert track.pose_at(q).tobytes() == interpolate_poses(np.asarray(q), kept_t, kept_p).tobytes()
