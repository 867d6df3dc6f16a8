"""The per-sweep glue around the compiled stages against its numpy reference: the keyframe map's
merge (compiled kernel), the registration covariance and the Doppler prior's information (Python
floats where the compiled kernels run), and the float shortcuts that must give numpy's bits."""

import math

import numpy as np
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import methods
from fmcwlog.frontend.keyframe_map import KeyframeMap, LocalMapParams
from fmcwlog.frontend.params import FrontEndParams
from fmcwlog.frontend.sensor_checks import _norm
from fmcwlog.geometry import between, between_floats


def _keyframes(seed: int, count: int, n: int, spread: float) -> list[np.ndarray]:
    """``count`` keyframes of ``n`` points each, drifting along x, many sharing voxels."""
    rng = np.random.default_rng(seed)
    return [rng.normal([0.4 * k, 0.0], spread, size=(n, 2)) for k in range(count)]


def _map_after(kind, use, frames, voxel, params):
    use(kind)
    m = KeyframeMap(voxel, params)
    states = []
    for k, xy in enumerate(frames):
        m.add(xy, 0.4 * k)
        states.append((m._keys.copy(), m.points.copy(), m._owner.copy()))
    return states


@needs_core
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31), count=st.integers(1, 12), n=st.integers(0, 300),
       spread=st.sampled_from([0.05, 1.0, 30.0]), voxel=st.sampled_from([0.01, 0.05, 0.3]),
       max_keyframes=st.integers(1, 6), window=st.sampled_from([0.5, 2.0, 100.0]))
def test_keyframe_merge_is_numpys(use, seed, count, n, spread, voxel, max_keyframes, window):
    """The compiled merge leaves the same keys, points and owners as np.unique's, keyframe by keyframe."""
    params = LocalMapParams(window_distance=window, max_keyframes=max_keyframes, min_keyframes=1)
    frames = _keyframes(seed, count, n, spread)
    fast = _map_after("compiled", use, frames, voxel, params)
    ref = _map_after("numpy", use, frames, voxel, params)
    for (k1, p1, o1), (k2, p2, o2) in zip(fast, ref):
        assert k1.dtype == k2.dtype and p1.dtype == p2.dtype and o1.dtype == o2.dtype
        np.testing.assert_array_equal(k1, k2)
        np.testing.assert_array_equal(p1, p2)
        np.testing.assert_array_equal(o1, o2)


@needs_core
def test_keyframe_merge_declines_unsorted_keys(use):
    """A map whose keys are not strictly increasing is not the kernel's to merge (None)."""
    core = use("compiled")
    keys = np.array([5, 3], np.int64)
    assert core.keyframe_map_merge(np.zeros((1, 2)), 0.1, keys, np.zeros((2, 2)), np.zeros(2, np.int64), 0, 1) is None


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31), scale=st.sampled_from([1e-6, 1.0, 1e4]), ridge=st.sampled_from([1e-3, 1.0]))
def test_registration_covariance_matches_numpy(use, seed, scale, ridge):
    """σ² H⁻¹ on floats is numpy's to rounding; a singular or NaN H gives None both ways."""
    rng = np.random.default_rng(seed)
    j = rng.normal(size=(20, 3))
    h = (j.T @ j + ridge * np.eye(3)) * scale
    use("compiled")
    np.testing.assert_allclose(methods.registration_covariance(h, 0.05),
                               methods.registration_covariance_numpy(h, 0.05), rtol=1e-9, atol=0)
    assert methods.registration_covariance(np.zeros((3, 3)), 0.05) is None
    assert methods.registration_covariance_numpy(np.zeros((3, 3)), 0.05) is None
    nan = np.full((3, 3), np.nan)
    assert methods.registration_covariance(nan, 0.05) is None and methods.registration_covariance_numpy(nan, 0.05) is None


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(yaw=st.floats(-4.0, 4.0), v_var=st.floats(0.0, 1.0), w_var=st.floats(0.0, 1.0), dt=st.floats(0.0, 0.5))
def test_doppler_prior_information_matches_numpy(use, yaw, v_var, w_var, dt):
    """The closed-form information on floats is numpy's inverse to rounding."""
    p = FrontEndParams()
    use("compiled")
    fast = methods.doppler_prior_information(yaw, v_var, w_var, dt, p)
    ref = methods.doppler_prior_information_numpy(yaw, v_var, w_var, dt, p)
    np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_numpy_kernels_keep_the_references(use):
    """With the numpy kernels the covariance and the prior are the numpy functions' bits."""
    use("numpy")
    h = np.array([[4.0, 1.0, 0.2], [1.0, 3.0, 0.1], [0.2, 0.1, 2.0]])
    np.testing.assert_array_equal(methods.registration_covariance(h, 0.05), methods.registration_covariance_numpy(h, 0.05))
    p = FrontEndParams()
    np.testing.assert_array_equal(methods.doppler_prior_information(0.3, 0.01, 0.02, 0.1, p),
                                  methods.doppler_prior_information_numpy(0.3, 0.01, 0.02, 0.1, p))


poses = st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-10.0, 10.0))


@settings(max_examples=300, deadline=None)
@given(a=poses, b=poses)
def test_between_floats_is_betweens_bits(a, b):
    a, b = np.array(a), np.array(b)
    assert np.array(between_floats(a, b)).tobytes() == between(a, b).tobytes()
    assert between_floats(a, np.zeros(2)) is None


@settings(max_examples=300, deadline=None)
@given(v=st.tuples(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True)))
def test_float_shortcuts_are_numpys(v):
    """The finiteness tests and the norm give numpy's answers, NaN and inf included."""
    arr = np.array(v)
    assert methods._finite(arr) == bool(np.all(np.isfinite(arr)))
    assert methods._finite_pair(v) == all(np.isfinite(v))
    assert methods._finite(np.array([arr, arr])) == bool(np.all(np.isfinite(arr)))
    with np.errstate(over="ignore"):  # both overflow alike on the largest floats
        norm = _norm(arr)
        ref = np.linalg.norm(arr)
    assert (math.isnan(norm) and math.isnan(ref)) or norm == ref


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pose=poses, seed=st.integers(0, 2**31), n=st.integers(0, 50), scale=st.sampled_from([1e-3, 1.0, 1e5]))
def test_compiled_transform_is_numpys_bits(use, pose, seed, n, scale):
    """The front end's transform through the compiled kernel gives transform_points' bits."""
    from fmcwlog.geometry import transform_points

    pts = np.random.default_rng(seed).normal(size=(n, 2)) * scale
    pose = np.array(pose)
    use("compiled")
    fast = methods._transform(pose, pts)
    ref = transform_points(pose, pts)
    assert fast.shape == ref.shape == (n, 2) and fast.dtype == ref.dtype
    assert fast.tobytes() == ref.tobytes()
