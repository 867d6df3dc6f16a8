"""The motion prior's drift learnt from matched intervals (:mod:`fmcwlog.frontend.odometry_drift`).

The facts come from a rear-axle differential drive integrated twice from the same wheel turns:
once with the true radii (what the scans see) and once with the calibrated ones (what the ticks
say), as the simulator's robot does it (left radius 0.5 %, right 0.3 % larger than calibrated).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmcwlog.frontend.odometry_drift import OdometryDrift, OdometryDriftParams
from fmcwlog.geometry import between, compose

RADIUS, TRACK = 0.1, 0.45
TRUE_LEFT, TRUE_RIGHT = RADIUS * 1.005, RADIUS * 1.003


def _drive(turns: np.ndarray, left: float, right: float, track: float = TRACK) -> np.ndarray:
    """Poses (N + 1, 3) of a differential drive from wheel turns (N, 2; rad per step), exact arcs."""
    poses = [np.zeros(3)]
    for phi_l, phi_r in turns:
        d = 0.5 * (left * phi_l + right * phi_r)
        dth = (right * phi_r - left * phi_l) / track
        chord = d if dth == 0 else 2 * d / dth * math.sin(dth / 2)
        poses.append(compose(poses[-1], np.array([chord * math.cos(dth / 2), chord * math.sin(dth / 2), dth])))
    return np.array(poses)


def _wheel_turns(speed: float, yaw_rate: float, seconds: float, dt: float = 0.1) -> np.ndarray:
    """Wheel turns per step (rad) that make the calibrated robot drive at ``speed`` and ``yaw_rate``."""
    n = round(seconds / dt)
    v_l, v_r = speed - yaw_rate * TRACK / 2, speed + yaw_rate * TRACK / 2
    return np.tile([v_l * dt / RADIUS, v_r * dt / RADIUS], (n, 1))


def _learn(drift: OdometryDrift, turns: np.ndarray, rng: np.random.Generator, noise: float = 2e-4) -> None:
    """Feed each step: the calibrated odometry's motion, and the true motion with the scans' noise."""
    believed, true = _drive(turns, RADIUS, RADIUS), _drive(turns, TRUE_LEFT, TRUE_RIGHT)
    for k in range(len(turns)):
        scan = between(true[k], true[k + 1]) + rng.normal(0.0, [noise, noise, noise])
        drift.observe(between(believed[k], believed[k + 1]), scan)


def test_a_straight_drive_learns_the_radii_drift():
    drift = OdometryDrift(OdometryDriftParams(scale_sigma=0.02))  # b free to move, within its prior
    _learn(drift, _wheel_turns(1.0, 0.0, 60.0), np.random.default_rng(0))
    a, b, c = drift.drift()
    # what the radii make of one metre: heading (r_L - r_R) / (b r) per metre of the calibrated distance
    mean_scale = (TRUE_LEFT + TRUE_RIGHT) / (2 * RADIUS)
    # the radii turn the heading by (r_L - r_R) / b per wheel radian, per metre of true distance
    assert a == pytest.approx((TRUE_LEFT - TRUE_RIGHT) / (TRACK * RADIUS * mean_scale), rel=0.1)
    assert b == 0.0  # no turn, nothing known of the turns' scale: it does not stand out of its prior
    assert c == pytest.approx(1.0 / mean_scale - 1.0, rel=0.1)  # the ticks' metre is 1 / mean_scale of a true one


def test_a_gap_across_a_corner_is_bridged_closer_to_the_truth():
    """20 s straight (learning), then a 6 s gap holding a 90° turn: the corrected bridge keeps under
    a third of the raw one's heading and position errors. What remains is the turn's own scale (the
    mean radius 0.4 % large: 6 mrad of 90°), which a straight drive cannot show."""
    drift = OdometryDrift(OdometryDriftParams())
    _learn(drift, _wheel_turns(1.0, 0.0, 20.0), np.random.default_rng(1))
    gap = np.vstack([_wheel_turns(1.0, 0.0, 2.0), _wheel_turns(1.0, math.pi / 2 / 2.0, 2.0),
                     _wheel_turns(1.0, 0.0, 2.0)])
    raw = _drive(gap, RADIUS, RADIUS)[-1]
    truth = _drive(gap, TRUE_LEFT, TRUE_RIGHT)[-1]
    fixed = drift.corrected(raw)
    assert abs(fixed[2] - truth[2]) < 0.34 * abs(raw[2] - truth[2])
    assert np.hypot(*(fixed[:2] - truth[:2])) < 0.34 * np.hypot(*(raw[:2] - truth[:2]))


def test_turns_fix_the_turn_scale():
    """A track 1 % wider than calibrated turns every turn 1 % short in the ticks: with a prior on
    the turns' scale, laps of a circle give b ≈ -1 %, and the radii's a as before."""
    wide = TRACK * 1.01
    drift = OdometryDrift(OdometryDriftParams(scale_sigma=0.02))
    turns = np.vstack([_wheel_turns(1.0, 0.0, 5.0), _wheel_turns(1.0, 0.5, 10.0), _wheel_turns(1.0, -0.5, 10.0)] * 2)
    rng = np.random.default_rng(2)
    believed, true = _drive(turns, RADIUS, RADIUS), _drive(turns, TRUE_LEFT, TRUE_RIGHT, wide)
    for k in range(len(turns)):
        drift.observe(between(believed[k], believed[k + 1]), between(true[k], true[k + 1]) + rng.normal(0, 2e-4, 3))
    a, b, _ = drift.drift()
    # Δψ_w - Δψ_s = Δψ_w (1 - b_cal r_true / (b_true r_cal)) for the mean radius, to first order
    mean_scale = (TRUE_LEFT + TRUE_RIGHT) / (2 * RADIUS)
    assert b == pytest.approx(1.0 - mean_scale / 1.01, abs=0.002)
    assert a == pytest.approx((TRUE_LEFT - TRUE_RIGHT) / (wide * RADIUS), rel=0.1)


def test_an_odometry_that_errs_at_random_is_left_as_it_is():
    """Heading errors of 10 mrad at random each interval (no drift): nothing stands out, no correction."""
    drift = OdometryDrift(OdometryDriftParams())
    rng = np.random.default_rng(3)
    step = np.array([0.1, 0.0, 0.0])
    for _ in range(500):
        drift.observe(step + [0.0, 0.0, rng.normal(0.0, 0.01)], step)
    motion = np.array([5.0, 1.0, 1.5])
    assert np.array_equal(drift.corrected(motion), motion)


def test_nothing_is_corrected_before_min_path_or_when_off():
    rng = np.random.default_rng(4)
    few = OdometryDrift(OdometryDriftParams(min_path=5.0))
    _learn(few, _wheel_turns(1.0, 0.0, 4.0), rng)
    off = OdometryDrift(OdometryDriftParams(enabled=False))
    _learn(off, _wheel_turns(1.0, 0.0, 20.0), rng)
    motion = np.array([5.0, 1.0, 1.5])
    for drift in (few, off):
        assert drift.drift() is None
        assert np.array_equal(drift.corrected(motion), motion)


def test_a_slip_is_left_out():
    """An interval whose heading changes differ by more than ``max_heading_error`` (a wheel spun) does
    not move the fit."""
    rng = np.random.default_rng(5)
    clean, slipped = OdometryDrift(OdometryDriftParams()), OdometryDrift(OdometryDriftParams())
    turns = _wheel_turns(1.0, 0.0, 20.0)
    believed, true = _drive(turns, RADIUS, RADIUS), _drive(turns, TRUE_LEFT, TRUE_RIGHT)
    for k in range(len(turns)):
        prior, scan = between(believed[k], believed[k + 1]), between(true[k], true[k + 1]) + rng.normal(0, 2e-4, 3)
        clean.observe(prior, scan)
        slipped.observe(prior + ([0.0, 0.0, 0.3] if k == 100 else 0.0), scan)
    assert slipped.drift() == pytest.approx(clean.drift(), rel=0.02)
