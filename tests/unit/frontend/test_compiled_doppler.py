"""The compiled Doppler fit, de-skew and voxel thinning (fmcwlog._core) against their numpy reference.

The fit: the same inliers exactly, and whether the prior's gate changed the answer, the velocity,
covariance and sigma to 1e-9 (the pairs are drawn by numpy's generator for both); de-skewed points
to 1e-12 m; voxel thinning the same points in the same order. On every sweep the improved method
sees processing the 30 s crowd log, and on generated inputs. Where the module is not built the
comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it.
"""

import tempfile

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import deskew as dk
from fmcwlog.frontend import egomotion as eg
from fmcwlog.geometry import transform_points
from fmcwlog.kernels import voxel as vx


def _copy(value):
    return value.copy() if isinstance(value, np.ndarray) else value


@pytest.fixture(scope="module")
def recorded():
    """Every fit and source cloud (de-skew and thinning) the improved front end makes processing the
    30 s crowd log: {"fit": [(args, kwargs)], "source": [...]}, the inputs copied."""
    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.frontend import methods

    seen = {"fit": [], "source": []}
    originals = {name: getattr(methods, name) for name in ("fit_sensor_velocity", "deskewed_source")}

    def capturing(kind, function):
        def capture(*args, **kwargs):
            seen[kind].append((tuple(_copy(a) for a in args), {k: _copy(v) for k, v in kwargs.items()}))
            return function(*args, **kwargs)
        return capture

    methods.fit_sensor_velocity = capturing("fit", eg.fit_sensor_velocity_numpy)
    methods.deskewed_source = capturing("source", dk.deskewed_source_numpy)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/out",
                    ProcessOptions(methods=("improved",), backend="none"), jobs=1)
    finally:
        for name, function in originals.items():
            setattr(methods, name, function)
    return seen


def _reference_fit(xy, v_r, **kwargs):
    return eg.fit_sensor_velocity_numpy(xy, v_r, **kwargs)


def assert_same_fit(fast, ref, tol=1e-9):
    np.testing.assert_array_equal(fast.inliers, ref.inliers)
    np.testing.assert_allclose(fast.v_sensor, ref.v_sensor, rtol=tol, atol=tol, equal_nan=True)
    np.testing.assert_allclose(fast.covariance, ref.covariance, rtol=1e-7, atol=tol, equal_nan=True)
    np.testing.assert_allclose(fast.sigma, ref.sigma, rtol=tol, atol=tol, equal_nan=True)
    assert (fast.unconstrained is None) == (ref.unconstrained is None)
    if ref.unconstrained is not None:
        assert_same_fit(fast.unconstrained, ref.unconstrained, tol)


@needs_core
def test_recorded_fits_agree(recorded, use):
    """Each sweep's fit as the front end asked for it, then with its prior moved 0.6 m/s so that the
    gate holds the fit away from the largest consensus (the ``unconstrained`` refit)."""
    use("compiled")
    assert len(recorded["fit"]) > 200
    gate_changed = 0
    for (xy, v_r), kwargs in recorded["fit"]:
        assert_same_fit(eg.fit_sensor_velocity(xy, v_r, **kwargs), _reference_fit(xy, v_r, **kwargs))
        if kwargs.get("prior") is not None:
            moved = {**kwargs, "prior": kwargs["prior"] + np.array([0.6, 0.0])}
            ref = _reference_fit(xy, v_r, **moved)
            assert_same_fit(eg.fit_sensor_velocity(xy, v_r, **moved), ref)
            gate_changed += ref.unconstrained is not None
    assert gate_changed > 50


@needs_core
def test_recorded_deskew_and_thinning_agree(recorded, use):
    """Each sweep's source cloud in one call: the mask and velocities exactly, the points the compiled
    de-skew's placed by the mount bit for bit and numpy's to rounding, the thinning that of those points
    (the first per voxel or the centroids, at the front end's voxel and others)."""
    use("compiled")
    assert len(recorded["source"]) > 200
    moved = 0
    for args, _ in recorded["source"]:
        xy, t, v, omega, mount, near, moving, velocity, size, centroid = args
        moved += moving is not None
        keep = ~near if moving is None else ~(near | moving)
        seen = dk.deskew(xy[keep], t[keep], v, omega, mount)
        np.testing.assert_allclose(seen, dk.deskew_numpy(xy[keep], t[keep], v, omega, mount), rtol=0, atol=1e-12)
        placed = dk.deskew_placed(xy, t, v, omega, mount, mount, keep)
        np.testing.assert_array_equal(placed, transform_points(mount, seen))  # the two compiled steps' bits
        np.testing.assert_allclose(placed, dk.deskew_placed_numpy(xy, t, v, omega, mount, mount, keep),
                                   rtol=0, atol=1e-12)
        for s, c in ((size, centroid), (0.03, False), (0.5, False), (size, True), (0.0, False)):
            use_mask, points, source, kept = dk.deskewed_source(xy, t, v, omega, mount, near, moving, velocity, s, c)
            ref = dk.deskewed_source_numpy(xy, t, v, omega, mount, near, moving, velocity, s, c)
            np.testing.assert_array_equal(use_mask, ref[0])
            np.testing.assert_array_equal(points, placed)
            np.testing.assert_allclose(points, ref[1], rtol=0, atol=1e-12)
            thin = vx.voxel_centroids_numpy if c else vx.voxel_downsample_numpy
            np.testing.assert_array_equal(source, thin(points, s))
            assert (source is points) == (s <= 0 or len(points) == 0)
            np.testing.assert_array_equal(kept, ref[3])
        for s in (size, 0.03, 0.5):
            np.testing.assert_array_equal(vx.voxel_downsample(placed, s), vx.voxel_downsample_numpy(placed, s))
    assert moved > 50


def _doppler_scene(rng, n, movers, nan_share, zero_share):
    """Points in a room (lidar frame, m), their Doppler for a random sensor velocity with noise and
    0.1 m/s quantisation, a share of movers, non-finite Doppler and zero-range points."""
    xy = rng.uniform(-12, 12, (n, 2))
    xy[rng.random(n) < zero_share] = 0.0
    u = eg.unit_bearings_numpy(xy)
    v_true = rng.normal(0, 1.5, 2)
    v_r = np.round((-(u @ v_true) + rng.normal(0, 0.03, n)) / 0.1) * 0.1
    moving = rng.random(n) < movers
    v_r[moving] += rng.normal(0, 1.5, moving.sum())
    v_r[rng.random(n) < nan_share] = np.nan
    return xy, v_r, v_true


@needs_core
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1500), movers=st.floats(0, 0.7),
       nan_share=st.sampled_from([0.0, 0.1, 0.9]), zero_share=st.sampled_from([0.0, 0.05]),
       threshold=st.sampled_from([0.05, 0.15, 0.5]), hypotheses=st.integers(0, 100),
       sine=st.sampled_from([0.0, 0.25, 0.99]), refinements=st.integers(0, 3),
       score_points=st.sampled_from([-2, 1, 7, 256, 5000]), prior=st.sampled_from([None, "true", "off", "nan"]),
       gate=st.sampled_from([0.1, 0.3, 2.0]), seeded=st.booleans(), bearings=st.booleans())
def test_generated_fits_agree(use, seed, n, movers, nan_share, zero_share, threshold, hypotheses, sine, refinements,
                              score_points, prior, gate, seeded, bearings):
    rng = np.random.default_rng(seed)
    xy, v_r, v_true = _doppler_scene(rng, n, movers, nan_share, zero_share)
    prior_value = {None: None, "true": v_true, "off": v_true + rng.normal(0, 1.0, 2),
                   "nan": np.array([np.nan, 0.0])}[prior]
    kwargs = dict(inlier_threshold=threshold, n_hypotheses=hypotheses, min_pair_sine=sine, refinements=refinements,
                  score_points=score_points, prior=prior_value, prior_gate=gate,
                  bearings=eg.unit_bearings_numpy(xy) if bearings else None)
    draw_seed = int(rng.integers(0, 1000))
    use("compiled")
    # an integer seed, or two generators in the same state (each fit consumes its own)
    fast = eg.fit_sensor_velocity(xy, v_r, random_state=draw_seed if seeded else np.random.default_rng(draw_seed),
                                  **kwargs)
    ref = _reference_fit(xy, v_r, **{**kwargs, "random_state": draw_seed if seeded else np.random.default_rng(draw_seed)})
    assert_same_fit(fast, ref)


@needs_core
def test_fit_failures_and_bearings(use):
    """Too few usable points, only parallel pairs, every Doppler NaN: the failed fit of numpy; the
    bearings bit for bit."""
    use("compiled")
    rng = np.random.default_rng(1)
    along = np.column_stack([rng.uniform(1, 9, 50), np.zeros(50)])  # one bearing: no pair is far from parallel
    cases = [(np.zeros((0, 2)), np.zeros(0)), (np.ones((2, 2)), np.zeros(2)), (along, np.full(50, -0.5)),
             (rng.uniform(-5, 5, (30, 2)), np.full(30, np.nan)), (np.zeros((40, 2)), np.zeros(40))]
    for xy, v_r in cases:
        fast, ref = eg.fit_sensor_velocity(xy, v_r), _reference_fit(xy, v_r)
        assert np.isnan(fast.v_sensor).all() and not fast.inliers.any()
        assert_same_fit(fast, ref)
    xy = np.concatenate([rng.uniform(-20, 20, (500, 2)), np.zeros((3, 2)), [[np.nan, 1.0], [np.inf, 2.0]]])
    assert eg.unit_bearings(xy).tobytes() == eg.unit_bearings_numpy(xy).tobytes()


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 1200), v=st.floats(-3.0, 3.0), omega=st.floats(-3.0, 3.0),
       v_y=st.floats(-1.0, 1.0), mount=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4.0, 4.0)),
       t_ref=st.sampled_from([0.0, 0.03, 0.1]))
@example(seed=0, n=1, v=0.0, omega=2.2250738585e-313, v_y=1.0, mount=(0.0, 0.0, 0.0), t_ref=0.0)  # subnormal turn
@example(seed=1, n=50, v=1.0, omega=1e-4, v_y=0.5, mount=(0.3, -0.1, 1.0), t_ref=0.03)  # the series' edge
def test_generated_deskew_agrees(use, seed, n, v, omega, v_y, mount, t_ref):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-40, 40, (n, 2))
    t = np.sort(rng.uniform(0, 0.1, n))
    use("compiled")
    got = dk.deskew(xy, t, v, omega, np.array(mount), t_ref, v_y)
    np.testing.assert_allclose(got, dk.deskew_numpy(xy, t, v, omega, np.array(mount), t_ref, v_y), rtol=0, atol=1e-12)


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1200), v=st.floats(-3.0, 3.0), omega=st.floats(-3.0, 3.0),
       mount=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4.0, 4.0)),
       pose=st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(-10.0, 10.0)),
       share=st.sampled_from([None, 0.0, 0.5, 1.0]))
def test_generated_deskew_placed_agrees(use, seed, n, v, omega, mount, pose, share):
    """De-skewed and placed in one call: the compiled de-skew's points under the pose bit for bit,
    numpy's to rounding; the kept points in their order (``share``: the kept fraction, None: no mask)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-40, 40, (n, 2))
    t = np.sort(rng.uniform(0, 0.1, n))
    keep = None if share is None else rng.uniform(size=n) < share
    mount, pose = np.array(mount), np.array(pose)
    use("compiled")
    got = dk.deskew_placed(xy, t, v, omega, mount, pose, keep)
    kx, kt = (xy, t) if keep is None else (xy[keep], t[keep])
    assert got.shape == kx.shape
    np.testing.assert_array_equal(got, transform_points(pose, dk.deskew(kx, kt, v, omega, mount)) if len(kx) else kx)
    np.testing.assert_allclose(got, dk.deskew_placed_numpy(xy, t, v, omega, mount, pose, keep), rtol=0, atol=1e-9)


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 3000), spread=st.sampled_from([0.5, 30.0, 1e9]),
       size=st.sampled_from([0.0, -1.0, 1e-3, 0.1, 0.25, 7.0]), odd=st.booleans())
def test_generated_thinning_is_the_same(use, seed, n, spread, size, odd):
    """The same points in the same order: repeated points, negative voxels, far points whose voxel
    index passes 2^32 (keys alike in the low bits) and, with ``odd``, NaN and infinite coordinates."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-spread, spread, (n, 2))
    if n:
        xy[rng.integers(0, n, n // 3)] = xy[rng.integers(0, n, n // 3)]  # duplicates
    if odd and n:
        xy[rng.integers(0, n, 3)] = [np.nan, 1.0]
        xy[rng.integers(0, n, 2)] = [np.inf, -np.inf]
    use("compiled")
    with np.errstate(invalid="ignore"):
        ref = vx.voxel_downsample_numpy(xy, size)
    got = vx.voxel_downsample(xy, size)
    assert got.tobytes() == ref.tobytes() and got.shape == ref.shape


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1500), v=st.floats(-3.0, 3.0), omega=st.floats(-3.0, 3.0),
       mount=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4.0, 4.0)),
       near_share=st.sampled_from([0.0, 0.1, 1.0]), moving_share=st.sampled_from([None, 0.0, 0.3, 1.0]),
       velocity=st.sampled_from([None, "float64", "float32"]), size=st.sampled_from([0.0, -1.0, 0.03, 0.1, 7.0]),
       centroid=st.booleans(), odd=st.booleans())
def test_generated_deskewed_source_agrees(use, seed, n, v, omega, mount, near_share, moving_share, velocity, size,
                                          centroid, odd):
    """The fused source cloud against its steps: the mask and velocities exactly (their dtype kept), the
    points those of the compiled :func:`deskew_placed` bit for bit (numpy's to rounding), the thinning that
    of those points (the same values; a NaN sum's sign bit aside); with ``odd``, NaN and infinite
    coordinates."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-40, 40, (n, 2))
    if odd and n:
        xy[rng.integers(0, n, 3)] = [np.nan, 1.0]
        xy[rng.integers(0, n, 2)] = [np.inf, -np.inf]
    t = np.sort(rng.uniform(0, 0.1, n))
    near = rng.uniform(size=n) < near_share
    moving = None if moving_share is None else rng.uniform(size=n) < moving_share
    vel = None if velocity is None else rng.normal(0, 2, n).astype(velocity)
    mount = np.array(mount)
    use("compiled")
    with np.errstate(invalid="ignore"):
        got = dk.deskewed_source(xy, t, v, omega, mount, near, moving, vel, size, centroid)
        ref = dk.deskewed_source_numpy(xy, t, v, omega, mount, near, moving, vel, size, centroid)
        keep = ref[0]
        np.testing.assert_array_equal(got[0], keep)
        assert got[1].tobytes() == dk.deskew_placed(xy, t, v, omega, mount, mount, keep).tobytes()
        assert got[1].shape == (int(keep.sum()), 2)
        np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-9)
        thin = vx.voxel_centroids_numpy if centroid else vx.voxel_downsample_numpy
        expected = thin(got[1], size)
        assert got[2].shape == expected.shape
        np.testing.assert_array_equal(got[2], expected)  # (NaN sums may differ in the NaN's sign bit)
    if vel is None:
        assert got[3] is None
    else:
        assert got[3].dtype == vel.dtype and got[3].tobytes() == ref[3].tobytes()


def _spd(rng, scale):
    """A random symmetric positive definite 2x2 matrix of about ``scale``."""
    m = rng.normal(0, 1, (2, 2))
    return (m @ m.T + 0.05 * np.eye(2)) * scale


@needs_core
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), mount=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4, 4)),
       doppler=st.sampled_from(["fit", "none", "singular", "nan"]), wheels=st.sampled_from(["fine", "singular"]),
       scale=st.sampled_from([1e-6, 1e-3, 1.0]))
def test_fused_twist_agrees(use, seed, mount, doppler, wheels, scale):
    """:func:`fuse_twist` under the compiled switch (floats) against :func:`fuse_twist_numpy`."""
    from fmcwlog.frontend.twist_fusion import doppler_design, fuse_twist, fuse_twist_numpy

    rng = np.random.default_rng(seed)
    a = doppler_design(mount)
    z = rng.normal(0, 1.5, 2)
    c_d = {"fit": _spd(rng, scale), "none": None, "singular": np.ones((2, 2)), "nan": np.full((2, 2), np.nan)}[doppler]
    x_w = rng.normal(0, 1.0, 2)
    c_w = _spd(rng, 1e-3) if wheels == "fine" else np.zeros((2, 2))
    use("compiled")
    if wheels == "singular":
        for fuse in (fuse_twist, fuse_twist_numpy):
            with pytest.raises(ValueError, match="positive definite"):
                fuse(z, c_d, a, x_w, c_w)
        return
    got, ref = fuse_twist(None if doppler == "none" else z, c_d, a, x_w, c_w), fuse_twist_numpy(
        None if doppler == "none" else z, c_d, a, x_w, c_w)
    for g, r in ((got.twist, ref.twist), (got.covariance, ref.covariance), (got.doppler_share, ref.doppler_share)):
        np.testing.assert_allclose(g, r, rtol=1e-8, atol=1e-12 * max(1.0, float(np.max(np.abs(r)))))
    np.testing.assert_allclose(got.chi2, ref.chi2, rtol=1e-7, atol=1e-9, equal_nan=True)
