"""De-skewing checked by ray-casting a wall from a sensor driving along a circle."""

import numpy as np
import pytest
from helpers import same_bits
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.deskew import advance, deskew, deskew_numpy, lidar_motion, se2_exp
from fmcwlog.geometry import compose, inverse, transform_points


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


# --- se2_exp against the matrix exponential (scipy's: an independent fact), and its fast paths
# against the module's own plain formula (the path arrays of twists take), bit for bit: the outputs
# of a run may not change with the fast paths.
def _expm_pose(vx, vy, omega, dt):
    """x, y of exp(dt·ξ) for the twist ξ = (vx, vy, ω), by scipy.linalg.expm of its 3x3 matrix."""
    from scipy.linalg import expm

    m = expm(np.array([[0.0, -omega, vx], [omega, 0.0, vy], [0.0, 0.0, 0.0]]) * dt)
    return m[0, 2], m[1, 2]


def _plain(vx, vy, omega, dt):
    """:func:`se2_exp` given the twist as 0-d arrays: the plain ``np.sinc`` formula, no fast path."""
    return se2_exp(np.array(vx), np.array(vy), np.array(omega), dt)


_twist = st.one_of(st.floats(-5.0, 5.0), st.sampled_from([0.0, -0.0, 1e-12, -1e-300]))


@settings(max_examples=300, deadline=None)
@given(_twist, _twist, st.one_of(_twist, st.floats(-50.0, 50.0)), st.floats(-1.0, 1.0))
def test_se2_exp_is_the_matrix_exponential_and_its_fast_paths_the_plain_formula(vx, vy, omega, dt):
    """One ``dt`` (Python floats; numpy squares a 0-d result with ``pow``) and many (in place,
    ``x * x``): the pose scipy's matrix exponential gives, and the plain path's bits."""
    got = se2_exp(vx, vy, omega, np.array(dt))
    assert got[2] == omega * dt
    np.testing.assert_allclose(got[:2], _expm_pose(vx, vy, omega, dt), rtol=1e-9, atol=1e-12)
    assert same_bits(got, _plain(vx, vy, omega, np.array(dt)))
    dts = np.array([dt, 0.0, -0.0, 0.5 * dt, 0.075])
    assert se2_exp(vx, vy, omega, dts).tobytes() == _plain(vx, vy, omega, dts).tobytes()


def test_se2_exp_scalar_over_many_twists():
    """20 000 random twists and intervals of the front end's sizes, one at a time: the plain path's
    bits; and every 400th, the matrix exponential's pose."""
    rng = np.random.default_rng(5)
    for k, (vx, w, dt) in enumerate(zip(rng.uniform(-2, 2, 20_000), rng.uniform(-2, 2, 20_000),
                                        rng.uniform(0, 0.2, 20_000))):
        got = se2_exp(float(vx), 0.0, float(w), np.array(dt))
        assert same_bits(got, _plain(float(vx), 0.0, float(w), np.array(dt)))
        if k % 400 == 0:
            np.testing.assert_allclose(got[:2], _expm_pose(vx, 0.0, w, dt), rtol=1e-12, atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-1.0, 1.0),
       st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4.0, 4.0)), st.integers(0, 2**32 - 1))
def test_deskew_column_path_is_the_pose_chain(v, omega, v_y, mount, seed):
    """:func:`deskew_numpy` (column by column) against ``transform_points(L⁻¹ ⊕ exp ⊕ L, xy)``
    through (N, 3) pose arrays, bit for bit, and :func:`lidar_motion` against the same chain; the
    compiled kernel (if selected) to rounding."""
    rng = np.random.default_rng(seed)
    n = 300
    xy = rng.uniform(-30, 30, (n, 2))
    t = np.sort(rng.uniform(0, 0.1, n))
    m = np.array(mount)
    chain = compose(compose(inverse(m), _plain(v, v_y, omega, t - 0.03)), m)  # the plain formulas, array by array
    assert lidar_motion(t, v, omega, m, 0.03, v_y).tobytes() == chain.tobytes()
    assert deskew_numpy(xy, t, v, omega, m, 0.03, v_y).tobytes() == transform_points(chain, xy).tobytes()
    np.testing.assert_allclose(deskew(xy, t, v, omega, m, 0.03, v_y), transform_points(chain, xy), rtol=0, atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(pose=st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4),
                      st.one_of(st.floats(-10.0, 10.0), st.sampled_from([np.inf, -np.inf, np.nan]))),
       v=st.floats(-5.0, 5.0), omega=st.one_of(st.floats(-4.0, 4.0), st.sampled_from([0.0, -0.0, 1e-300])),
       dt=st.floats(-1.0, 1.0), numpy_scalars=st.booleans())
def test_advance_is_compose_of_se2_exp(pose, v, omega, dt, numpy_scalars):
    """The float prediction gives the bits of ``compose(pose, se2_exp(...))`` (NaN where it does)."""
    if numpy_scalars:
        v, omega, dt = np.float64(v), np.float64(omega), np.float64(dt)
    pose = np.array(pose)
    with np.errstate(invalid="ignore"):
        want = compose(pose, se2_exp(v, 0.0, omega, np.array(dt)))
        got = advance(pose, v, omega, dt)
    assert got.dtype == want.dtype and got.shape == want.shape
    np.testing.assert_array_equal(got.view(np.int64) if np.isfinite(want).all() else np.isnan(got),
                                  want.view(np.int64) if np.isfinite(want).all() else np.isnan(want))
