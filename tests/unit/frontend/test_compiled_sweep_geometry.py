"""The compiled sweep geometry (ranges, body mask, bearings, last and middle capture time) against its
numpy reference, bit for bit: on generated sweeps with points at the origin or not finite, and times
sorted, unsorted, not finite, all zero or none; where the module is not built the comparison skips,
unless ``FMCWLOG_KERNELS=compiled`` asks for it."""

import warnings

import numpy as np
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.sweep_geometry import sweep_geometry, sweep_geometry_numpy


def _same(a, b):
    if a is None or b is None:
        return a is None and b is None
    if isinstance(a, float) or isinstance(b, float):
        return type(a) is float and type(b) is float and np.array([a]).tobytes() == np.array([b]).tobytes()
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1500), odd=st.booleans(),
       times=st.sampled_from(["sorted", "unsorted", "nan", "zeros", "negative", "ties"]),
       min_range=st.sampled_from([0.0, 0.3, 15.0, float("nan")]), bearings=st.booleans(), middle=st.booleans())
def test_generated_geometry_agrees(use, seed, n, odd, times, min_range, bearings, middle):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-30, 30, (n, 2))
    if odd and n:
        xy[rng.integers(0, n, 3)] = 0.0
        xy[rng.integers(0, n, 2)] = [np.nan, 1.0]
        xy[rng.integers(0, n, 2)] = [np.inf, -2.0]
    t = {"sorted": np.sort(rng.uniform(0, 0.1, n)), "unsorted": rng.uniform(0, 0.1, n),
         "nan": np.where(rng.random(n) < 0.05, np.nan, np.linspace(0, 0.1, n)), "zeros": np.zeros(n),
         "negative": np.sort(rng.uniform(-0.1, 0.0, n)), "ties": np.repeat(np.linspace(0, 0.1, (n + 1) // 2), 2)[:n]}[times]
    use("compiled")
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # np.median of no times: NaN, with numpy's warning
        got = sweep_geometry(xy, t, min_range, bearings, middle)
        ref = sweep_geometry_numpy(xy, t, min_range, bearings, middle)
    assert got.xy is xy and ref.xy is xy
    for name in ("ranges", "near", "bearings", "last_time", "middle_time"):
        assert _same(getattr(got, name), getattr(ref, name)), name
