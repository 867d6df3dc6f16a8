"""De-skewing checked by ray-casting a wall from a sensor driving along a circle."""

import numpy as np
import pytest

from fmcwlog.frontend.deskew import deskew, se2_exp


def _base_pose_on_circle(t, v, omega, start):
    """Pose of base_link at times t on the circle driven from ``start`` (x0, y0, yaw0).

    Written with the circle's centre and radius (R = v/ω), not with an exponential.
    """
    x0, y0, th0 = start
    if omega == 0.0:
        return np.stack([x0 + v * t * np.cos(th0), y0 + v * t * np.sin(th0), th0 + 0 * t], -1)
    rad = v / omega
    cx, cy = x0 - rad * np.sin(th0), y0 + rad * np.cos(th0)  # centre, left of heading
    th = th0 + omega * t
    return np.stack([cx + rad * np.sin(th), cy - rad * np.cos(th), th], -1)


def _lidar_pose(base, mount):
    c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
    return np.stack(
        [
            base[:, 0] + c * mount[0] - s * mount[1],
            base[:, 1] + s * mount[0] + c * mount[1],
            base[:, 2] + mount[2],
        ],
        -1,
    )


def _raycast_wall(lidar, bearing, wall_x):
    """Hit points (lidar frame at capture) of beams at ``bearing`` on the wall x = wall_x (world)."""
    ang = lidar[:, 2] + bearing
    rng = (wall_x - lidar[:, 0]) / np.cos(ang)
    return np.stack([rng * np.cos(bearing), rng * np.sin(bearing)], -1), np.stack(
        [lidar[:, 0] + rng * np.cos(ang), lidar[:, 1] + rng * np.sin(ang)], -1
    )


def _to_frame(pose, pts):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = pts - pose[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1)


@pytest.mark.parametrize("v,omega", [(1.5, 0.0), (1.5, 0.9), (1.0, -1.4), (0.0, 1.0)])
@pytest.mark.parametrize("t_ref", [0.0, 0.0375, 0.075])
def test_deskewed_points_match_wall_seen_from_reference_pose(v, omega, t_ref):
    mount = np.array([0.3, -0.05, 0.1])
    start = np.array([0.0, 0.0, 0.2])
    n = 600
    bearing = np.linspace(-0.7, 0.7, n)  # beams towards the wall ahead
    t = np.linspace(0.0, 0.075, n)  # sweep time of each beam
    lidar = _lidar_pose(_base_pose_on_circle(t, v, omega, start), mount)
    seen, world = _raycast_wall(lidar, bearing, wall_x=5.0)
    ref = _lidar_pose(_base_pose_on_circle(np.array([t_ref]), v, omega, start), mount)[0]
    expected = _to_frame(ref, world)
    got = deskew(seen, t, v, omega, mount, t_ref=t_ref)
    np.testing.assert_allclose(got, expected, atol=1e-9)
    # and the skew was real: the raw points are off by centimetres when moving
    if t_ref == 0.0 and v > 0:
        assert np.max(np.linalg.norm(seen - expected, axis=1)) > 0.05


def test_lateral_twist_and_identity():
    xy = np.array([[1.0, 2.0], [3.0, -1.0]])
    np.testing.assert_allclose(deskew(xy, np.array([0.0, 0.05]), 0.0, 0.0), xy)
    # pure sideways motion v_y = 1 m/s for 0.1 s, no mount: a point seen at t = 0.1
    # is 0.1 m further left in the frame at t = 0
    got = deskew(np.array([[2.0, 0.0]]), np.array([0.1]), 0.0, 0.0, v_y=1.0)
    np.testing.assert_allclose(got, [[2.0, 0.1]], atol=1e-15)
    assert deskew(np.zeros((0, 2)), np.zeros(0), 1.0, 1.0).shape == (0, 2)


def test_se2_exp_quarter_circle():
    # v = π/2 m/s, ω = π/2 rad/s for 1 s: a quarter circle of radius 1 -> (1, 1, π/2)
    p = se2_exp(np.pi / 2, 0.0, np.pi / 2, np.array([1.0]))
    np.testing.assert_allclose(p[0], [1.0, 1.0, np.pi / 2], atol=1e-15)
    # tiny ω is continuous with the straight line: y ≈ v ω dt² / 2
    got = se2_exp(1.0, 0.0, 1e-12, np.array([2.0]))[0]
    np.testing.assert_allclose(got, [2.0, 2e-12, 2e-12], rtol=1e-9, atol=0)
