"""Ego-motion from Doppler, checked against finite-difference physics."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.egomotion import (
    base_twist_from_sensor_velocity,
    compensated_velocity,
    fit_sensor_velocity,
    sensor_velocity_from_base_twist,
)
from fmcwlog.geometry import compose, inverse, transform_points


def _room_points(rng, n):
    """Points on the walls of a 12 x 8 m room around the sensor (lidar frame)."""
    ang = rng.uniform(-0.75 * np.pi, 0.75 * np.pi, n)  # 270° field of view
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    # ray / axis-aligned box intersection, box [-4, 8] x [-3, 5]
    with np.errstate(divide="ignore"):
        tx = np.where(u[:, 0] > 0, 8.0 / u[:, 0], -4.0 / u[:, 0])
        ty = np.where(u[:, 1] > 0, 5.0 / u[:, 1], -3.0 / u[:, 1])
    r = np.minimum(np.abs(tx), np.abs(ty))
    return u * r[:, None]


def _quantise(v, q=0.1):
    return np.round(v / q) * q


def test_static_doppler_model_matches_finite_difference_range_rate():
    # Physics check of v_r = -u·v_s: a sensor translating AND rotating; range rate
    # of world-fixed points by finite differences of the actual ranges.
    rng = np.random.default_rng(0)
    world = rng.uniform(-10, 10, (50, 2))
    v_s_lidar = np.array([1.2, -0.4])  # lidar-frame velocity of the origin
    yaw_rate = 0.7
    pose0 = np.array([0.3, -0.2, 0.4])
    dt = 1e-6
    # pose after dt: translate by R(yaw)·v dt, rotate by yaw_rate dt
    pose1 = compose(pose0, np.array([v_s_lidar[0] * dt, v_s_lidar[1] * dt, yaw_rate * dt]))
    p0 = transform_points(inverse(pose0), world)
    p1 = transform_points(inverse(pose1), world)
    rdot = (np.hypot(*p1.T) - np.hypot(*p0.T)) / dt
    np.testing.assert_allclose(compensated_velocity(p0, rdot, v_s_lidar), 0.0, atol=1e-4)


def test_recovers_sensor_velocity_with_movers_and_quantisation():
    rng = np.random.default_rng(1)
    n = 1000
    xy = _room_points(rng, n)
    v_true = np.array([1.3, 0.25])
    u = xy / np.hypot(*xy.T)[:, None]
    v_r = -(u @ v_true)
    movers = rng.random(n) < 0.3
    # movers: own velocity up to 2 m/s in random directions, radial part added
    own = rng.uniform(-2.0, 2.0, (n, 2))
    v_r[movers] += np.sum(u[movers] * own[movers], axis=1)
    v_r = _quantise(v_r)
    fit = fit_sensor_velocity(xy, v_r, random_state=0)
    assert np.all(np.abs(fit.v_sensor - v_true) < 0.005)  # a few mm/s
    # quantisation error is uniform ±0.05: σ ≈ 0.1/√12 ≈ 0.029
    assert 0.02 < fit.sigma < 0.045
    # reported covariance consistent with the actual error scale (σ/√N ~ 1-2 mm/s)
    sd = np.sqrt(np.diag(fit.covariance))
    assert np.all(sd < 0.005) and np.all(sd > 0.0002)
    # static points are inliers; clearly moving points (|own radial| > 0.2) are not
    own_radial = np.sum(u * own, axis=1)
    assert fit.inliers[~movers].mean() > 0.99
    assert not np.any(fit.inliers[movers & (np.abs(own_radial) > 0.2)])
    # compensated velocity of static points is at the quantisation level
    eps = compensated_velocity(xy, v_r, fit.v_sensor)
    assert np.max(np.abs(eps[~movers])) < 0.06


def test_deterministic_and_standing_still():
    rng = np.random.default_rng(2)
    xy = _room_points(rng, 500)
    v_r = _quantise(rng.normal(0.0, 0.01, 500))
    a = fit_sensor_velocity(xy, v_r, random_state=7)
    b = fit_sensor_velocity(xy, v_r, random_state=7)
    np.testing.assert_array_equal(a.v_sensor, b.v_sensor)
    assert np.all(np.abs(a.v_sensor) < 0.003)


def test_degenerate_inputs_do_not_crash():
    fit = fit_sensor_velocity(np.zeros((0, 2)), np.zeros(0))
    assert np.all(np.isnan(fit.v_sensor)) and fit.n_inliers == 0
    # all points along one bearing: no well-posed pair
    xy = np.stack([np.linspace(1, 5, 20), np.zeros(20)], -1)
    fit = fit_sensor_velocity(xy, np.zeros(20))
    assert np.all(np.isnan(fit.v_sensor))


def _lidar_velocity_by_finite_difference(v, omega, mount, dt=1e-7):
    """Velocity of the lidar origin in the lidar frame from two poses of the chassis."""
    base0 = np.zeros(3)
    # exact arc of base_link over dt (non-holonomic: no sideways motion)
    th = omega * dt
    base1 = np.array([v * dt * np.sinc(th / np.pi), v * dt * (1 - np.cos(th)) / th if th else 0.0, th])
    l0 = compose(base0, mount)
    l1 = compose(base1, mount)
    return between_xy(l0, l1) / dt


def between_xy(a, b):
    return transform_points(inverse(a), b[None, :2])[0]


@pytest.mark.parametrize("v,omega", [(1.5, 0.0), (1.0, 0.8), (-0.5, -0.3), (0.0, 1.2)])
@pytest.mark.parametrize("mount", [(0.3, 0.0, 0.0), (0.25, -0.1, 0.3), (-0.4, 0.15, np.pi)])
def test_twist_forward_and_inverse(v, omega, mount):
    mount = np.array(mount)
    vs_fd = _lidar_velocity_by_finite_difference(v, omega, mount)
    vs = sensor_velocity_from_base_twist(v, omega, *mount)
    np.testing.assert_allclose(vs, vs_fd, atol=1e-5)
    tw = base_twist_from_sensor_velocity(vs_fd, *mount)
    assert tw.well_conditioned
    assert tw.v == pytest.approx(v, abs=1e-5)
    assert tw.omega == pytest.approx(omega, abs=1e-5)


def test_twist_covariance_by_monte_carlo():
    mount = np.array([0.3, 0.1, 0.2])
    cov_s = np.array([[4e-6, 1e-6], [1e-6, 9e-6]])
    vs = sensor_velocity_from_base_twist(1.0, 0.5, *mount)
    tw = base_twist_from_sensor_velocity(vs, *mount, covariance=cov_s)
    rng = np.random.default_rng(0)
    samples = rng.multivariate_normal(vs, cov_s, 4000)
    twists = [base_twist_from_sensor_velocity(s, *mount) for s in samples]
    out = np.array([[t.v, t.omega] for t in twists])
    emp = np.cov(out.T)
    np.testing.assert_allclose(emp, tw.covariance, rtol=0.1, atol=1e-8)


def test_twist_ill_conditioned_when_lidar_on_axle():
    tw = base_twist_from_sensor_velocity(np.array([1.0, 0.0]), 0.0, 0.0, 0.0)
    assert not tw.well_conditioned and np.isnan(tw.omega)
    assert tw.v == pytest.approx(1.0)
    tw = base_twist_from_sensor_velocity(np.array([1.0, 0.0]), 0.01, 0.3, 0.0)
    assert not tw.well_conditioned and np.isnan(tw.omega) and np.isnan(tw.v)


def test_seeded_fit_draws_as_a_fresh_generator():
    """An integer seed gives the fit of a fresh ``default_rng(seed)`` every call (the generator is
    reused and put back to its seeded state), and a Generator passed in gives the same."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-10, 10, (400, 2))
    v = np.array([1.2, -0.3])
    v_r = -(xy / np.hypot(xy[:, 0], xy[:, 1])[:, None]) @ v + rng.normal(0, 0.03, 400)
    v_r[:120] += 1.5  # movers: RANSAC's draws decide which hypotheses see them
    first = fit_sensor_velocity(xy, v_r, random_state=7)
    for _ in range(3):
        again = fit_sensor_velocity(xy, v_r, random_state=7)
        fresh = fit_sensor_velocity(xy, v_r, random_state=np.random.default_rng(7))
        assert np.array_equal(again.v_sensor, first.v_sensor) and np.array_equal(fresh.v_sensor, first.v_sensor)
        assert np.array_equal(again.inliers, first.inliers)
    from fmcwlog.frontend.egomotion import _generator
    for _ in range(2):  # the draws themselves, which the fit's refinement could hide
        assert np.array_equal(_generator(7).integers(0, 1000, 64), np.random.default_rng(7).integers(0, 1000, 64))


@pytest.mark.parametrize("seed", range(40))
def test_refinement_is_least_squares_on_its_inliers_with_their_covariance(seed):
    """Inliers settled or still moving at the last pass, 0-3 refinements. The fit is what its
    docstring says, computed here by another solver (numpy's SVD least squares, not the normal
    equations): least squares of ``v_r = -u·v`` on the inliers of the start, re-selected
    ``refinements`` times. What it returns follows from that ``v`` by definition: the inliers are
    the points within the threshold of it, σ the residuals' RMS over n - 2 degrees of freedom, the
    covariance σ² (AᵀA)⁻¹ of those inliers (the pseudo-inverse's, A = -u), whether or not the last
    least squares was skipped because the inliers had not changed. Fewer than 3 inliers at a
    selection (two unknowns, no residual left) is no fit: NaN, and no inliers."""
    from fmcwlog.frontend.egomotion import _refine, unit_bearings

    rng = np.random.default_rng(seed)
    xy = _room_points(rng, int(rng.integers(20, 400)))
    u = unit_bearings(xy)
    v_true = rng.normal(0, 1.5, 2)
    v_r = _quantise(-(u @ v_true) + rng.normal(0, rng.choice([0.02, 0.08]), len(xy)))
    movers = rng.random(len(xy)) < 0.3
    v_r[movers] += rng.normal(0, 1.0, movers.sum())
    valid = np.isfinite(v_r)
    start = v_true + rng.normal(0, rng.choice([0.01, 0.2]), 2)
    for refinements in (0, 1, 2, 3):
        got = _refine(u, v_r, valid, start, 0.15, refinements)
        v, too_few = start, False
        for _ in range(max(1, refinements)):
            inliers = valid & (np.abs(v_r + u @ v) < 0.15)
            too_few |= inliers.sum() < 3
            v = np.linalg.lstsq(-u[inliers], v_r[inliers], rcond=None)[0] if inliers.sum() >= 3 else v
        if too_few or (valid & (np.abs(v_r + u @ v) < 0.15)).sum() < 3:  # no fit, said as NaN with no inliers
            assert np.isnan(got.v_sensor).all() and np.isnan(got.sigma) and not got.inliers.any()
            continue
        np.testing.assert_allclose(got.v_sensor, v, rtol=1e-9, atol=1e-12)
        eps = v_r + u @ got.v_sensor
        assert np.array_equal(got.inliers, valid & (np.abs(eps) < 0.15))
        n = int(got.inliers.sum())
        assert got.sigma == pytest.approx(np.sqrt(np.sum(eps[got.inliers] ** 2) / (n - 2)), rel=1e-12)
        pinv = np.linalg.pinv(-u[got.inliers])
        np.testing.assert_allclose(got.covariance, got.sigma**2 * pinv @ pinv.T, rtol=1e-9, atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([0.0, -0.0, 1.0, -0.5, np.nan, np.inf]),
                          st.sampled_from([0.0, -0.0, 0.3, np.nan]), st.sampled_from([0.0, 0.2, np.nan, -np.inf])),
                max_size=30))
def test_usable_is_a_finite_doppler_with_a_bearing(rows):
    """Zero, signed-zero, NaN and infinite bearings and Dopplers, row by row in plain Python: a point
    is usable when its Doppler is a finite number and its bearing is not the zero vector (a point at
    zero range; -0.0 is zero too), the definition its docstring gives."""
    from fmcwlog.frontend.egomotion import usable

    a = np.array(rows, float).reshape(-1, 3)
    u, v_r = a[:, :2], a[:, 2]
    want = [math.isfinite(vr) and not (ux == 0.0 and uy == 0.0) for ux, uy, vr in rows]
    assert usable(u, v_r).tolist() == want
