"""The fused twist against the physics of a rigid body: at every mount, finite, and right.

The lidar's velocity is computed here independently, by finite differences of the lidar's
pose under a constant base twist (``lidar_motion``), not from the fusion's own design matrix.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.deskew import lidar_motion
from fmcwlog.frontend.twist_fusion import (
    WheelNoise,
    doppler_design,
    fuse_twist,
    hold_covariance,
    wheel_covariance,
)


def _lidar_velocity(v: float, omega: float, mount) -> np.ndarray:
    """Velocity (2,) of the lidar origin in the lidar frame, by a central difference over ±1 ms."""
    h = 1e-3
    poses = lidar_motion(np.array([-h, h]), v, omega, mount)
    d = poses[1, :2] - poses[0, :2]
    return d / (2 * h)


MOUNTS = [(0.35, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.25, 0.0), (0.35, 0.0, np.pi / 2), (0.35, 0.0, -np.pi / 2),
          (0.35, 0.0, np.pi), (-0.3, 0.1, 0.5)]


@pytest.mark.parametrize("mount", MOUNTS)
def test_design_matrix_is_the_rigid_body_velocity(mount):
    for v, omega in [(1.0, 0.0), (0.5, 0.8), (-0.4, -1.2)]:
        np.testing.assert_allclose(doppler_design(mount) @ [v, omega], _lidar_velocity(v, omega, mount), atol=1e-6)


def _fuse(mount, truth, wheel_bias, doppler_sigma=0.002):
    z = _lidar_velocity(*truth, mount)
    x_w = np.asarray(truth) + wheel_bias
    return fuse_twist(z, np.eye(2) * doppler_sigma**2, doppler_design(mount), x_w, wheel_covariance(x_w, WheelNoise()))


def test_lever_arm_ahead_of_the_axle_takes_both_from_doppler():
    bias = np.array([0.02, 0.03])
    f = _fuse((0.35, 0.0, 0.0), (1.0, 0.5), wheel_bias=bias)
    assert f.doppler_share[0] > 0.9 and f.doppler_share[1] > 0.9
    # the wheels' 2 cm/s and 0.03 rad/s count only by their share
    assert np.all(np.abs(f.twist - [1.0, 0.5]) <= (1 - f.doppler_share) * bias + 1e-4)


def test_over_the_axle_omega_comes_from_the_wheels_and_v_from_doppler():
    """l_x = 0: the lateral Doppler equation reads 0 = 0; ω is the wheels', v is Doppler's."""
    f = _fuse((0.0, 0.0, 0.0), (1.0, 0.5), wheel_bias=np.array([0.02, 0.03]))
    assert f.twist[1] == pytest.approx(0.53, abs=1e-9) and f.doppler_share[1] == pytest.approx(0.0, abs=1e-9)
    assert f.twist[0] == pytest.approx(1.0, abs=0.001) and f.doppler_share[0] > 0.9


def test_sideways_mount_corrects_doppler_with_the_wheels_omega():
    """l = (0, 0.25): Doppler sees v - ω l_y only; the wheels' ω turns it into v (error ω_err · l_y)."""
    f = _fuse((0.0, 0.25, 0.0), (1.0, 0.5), wheel_bias=np.array([0.02, 0.03]))
    v, omega = f.twist
    assert v - 0.25 * omega == pytest.approx(1.0 - 0.25 * 0.5, abs=0.001)  # what Doppler sees, kept
    s_w = np.sqrt(np.diag(wheel_covariance((1.02, 0.53), WheelNoise())))
    assert abs(omega - 0.5) < 2 * s_w[1] and abs(v - 1.0) < 2 * s_w[0]  # the rest, from the wheels


def test_covariance_by_monte_carlo():
    mount = (0.2, 0.15, 0.4)
    a = doppler_design(mount)
    truth = np.array([0.8, 0.6])
    c_d = np.array([[9e-6, 2e-6], [2e-6, 4e-6]])
    c_w = wheel_covariance(truth, WheelNoise())
    rng = np.random.default_rng(0)
    out = np.array([fuse_twist(a @ truth + rng.multivariate_normal([0, 0], c_d), c_d, a,
                               truth + rng.multivariate_normal([0, 0], c_w), c_w).twist for _ in range(4000)])
    f = fuse_twist(a @ truth, c_d, a, truth, c_w)
    assert np.all(np.abs(out.mean(0) - truth) < 4 * np.sqrt(np.diag(f.covariance) / 4000))
    np.testing.assert_allclose(np.cov(out.T), f.covariance, rtol=0.1)
    assert np.all(f.doppler_share >= 0) and np.all(f.doppler_share <= 1)


def test_without_doppler_the_wheels_or_the_hold_pass_through():
    noise = WheelNoise()
    f = fuse_twist(None, None, doppler_design((0.0, 0.0, 0.0)), np.array([0.3, 0.1]), hold_covariance(noise))
    assert list(f.twist) == [0.3, 0.1] and list(f.doppler_share) == [0.0, 0.0]


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-1.0, 1.0), y=st.floats(-1.0, 1.0), yaw=st.floats(-np.pi, np.pi),
       v=st.floats(-2.0, 2.0), omega=st.floats(-2.0, 2.0))
def test_any_mount_gives_a_finite_twist_within_its_uncertainty(x, y, yaw, v, omega):
    """With exact Doppler and wheels off by 1 σ, the fused twist is finite and within a few σ of the truth."""
    mount = (x, y, yaw)
    c_w = wheel_covariance((v, omega), WheelNoise())
    f = fuse_twist(_lidar_velocity(v, omega, mount), np.eye(2) * 0.002**2, doppler_design(mount),
                   np.array([v, omega]) + np.sqrt(np.diag(c_w)), c_w)
    assert np.all(np.isfinite(f.twist)) and np.all(np.isfinite(f.covariance))
    err = f.twist - [v, omega]
    assert err @ np.linalg.solve(f.covariance, err) < 9.0  # the wheels' 1-σ bias, shrunk by Doppler
