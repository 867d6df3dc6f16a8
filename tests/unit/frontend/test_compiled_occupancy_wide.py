"""The compiled ray cast's widest sample loop (AVX-512, eight samples at a time, where the CPU has
it; elsewhere the same calls run the AVX2 loop) and its 32-bit window counts (scans of 2^16 rays
or more) against the numpy reference: the same cells and float32 increments, bit for bit, and the
same as the scalar loop's."""

import numpy as np
import pytest
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.kernels import occupancy as occ
from fmcwlog.kernels.occupancy import OccupancyParams


def _same(a: occ.ScanUpdate, b: occ.ScanUpdate) -> None:
    assert (a.y0, a.x0) == (b.y0, b.x0)
    for name in ("rows", "cols", "increment"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name


@pytest.fixture
def widest(use):
    """The compiled kernels with the widest sample loop; yields a function that casts with a given loop."""
    core = use("compiled")
    was = core._occupancy_simd(3)

    def cast_with(level, origin, points, params):
        before = core._occupancy_simd(level)
        try:
            return occ.cast(origin, points, params)
        finally:
            core._occupancy_simd(before)

    yield cast_with
    core._occupancy_simd(was)


def _fan(origin, n, rng, far=30.0):
    """``n`` beams all around ``origin`` (m) with ranges up to ``far`` m, in bearing order."""
    bearing = np.sort(rng.uniform(-np.pi, np.pi, n))
    r = rng.uniform(0.0, far, n)
    return origin + r[:, None] * np.stack([np.cos(bearing), np.sin(bearing)], 1)


@needs_core
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("offset", [(0.0, 0.0), (-123.4567, 88.8), (4.0e5, -3.1e5)])
def test_fans_agree(widest, seed, offset):
    """A thousand beams of up to 30 m (hundreds of samples each) from origins on and off the lattice."""
    rng = np.random.default_rng(seed)
    origin = np.array(offset) + rng.uniform(-1, 1, 2)
    points = _fan(origin, 1000, rng)
    for params in (OccupancyParams(), OccupancyParams(protect_hits=False, max_range=12.0)):
        ref = occ.cast_numpy(origin, points, params)
        _same(widest(3, origin, points, params), ref)
        _same(widest(0, origin, points, params), ref)


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(res=st.sampled_from([0.05, 0.1, 0.03]), step_fraction=st.sampled_from([0.5, 0.3, 1.0]),
       snap=st.booleans(), seed=st.integers(0, 2**16), n=st.integers(1, 60))
def test_generated_scans_agree(widest, res, step_fraction, snap, seed, n):
    """Beams along the lattice's lines and through its corners (snapped), where the division decides."""
    rng = np.random.default_rng(seed)
    origin = rng.uniform(-20, 20, 2)
    points = _fan(origin, n, rng, far=15.0)
    if snap:
        origin = np.round(origin / res) * res
        points = np.round(points / res) * res
        points[::3, 1] = origin[1]
        points[1::3, 0] = origin[0]
    params = OccupancyParams(resolution=res, step_fraction=step_fraction)
    _same(widest(3, origin, points, params), occ.cast_numpy(origin, points, params))


@needs_core
def test_many_rays_agree(widest):
    """2^16 rays and more: the window's counts in 32 bits (a cell near the sensor is crossed by all)."""
    rng = np.random.default_rng(7)
    origin = np.array([0.01, -0.02])
    points = _fan(origin, 70_000, rng, far=2.0)
    params = OccupancyParams()
    _same(widest(3, origin, points, params), occ.cast_numpy(origin, points, params))
