"""The improved front end's per-sweep glue where the compiled kernels run, against its numpy path:
the twist fusion on Python floats (:meth:`ImprovedFrontEnd.fuse`), the sensor check given the
predicted lidar velocity, and the growing arrays' batched rows; and a whole log stepped both ways."""

import numpy as np
import pytest
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.methods import Doppler, ImprovedFrontEnd, PriorMotion
from fmcwlog.frontend.params import FrontEndParams
from fmcwlog.frontend.twist_fusion import wheel_covariance, wheel_variances
from fmcwlog.kernels.growing import GrowingArray
from fmcwlog.types import Calibration


def _spd(rng: np.random.Generator, scale: float) -> np.ndarray:
    """A random symmetric positive definite 2x2 matrix of size ``scale``."""
    m = rng.normal(0, 1, (2, 2))
    return scale * (m @ m.T + 0.1 * np.eye(2))


@needs_core
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), mount=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4, 4)),
       wheels=st.booleans(), scale=st.sampled_from([1e-6, 1e-3, 1.0]), singular=st.booleans())
def test_front_end_fuse_on_floats_is_numpys(use, seed, mount, wheels, scale, singular):
    """:meth:`ImprovedFrontEnd.fuse` under the compiled switch (floats, the floor and the wheels'
    covariance as numbers) against its numpy path, with the wheels' twist and with the hold's."""
    rng = np.random.default_rng(seed)
    doppler = Doppler(rng.normal(0, 1.5, 2), np.ones((2, 2)) if singular else _spd(rng, scale), np.zeros(3, bool))
    prior = PriorMotion(twist=(float(rng.normal(0, 1)), float(rng.normal(0, 0.5)))) if wheels else PriorMotion()
    scan_twist = (float(rng.normal(0, 1)), float(rng.normal(0, 0.5)))
    out = {}
    for kind in ("numpy", "compiled"):
        use(kind)
        fe = ImprovedFrontEnd(FrontEndParams(), Calibration(None, mount, 0.1, 0.01))
        fe.scan_twist = scan_twist
        out[kind] = fe.fuse(doppler, prior)
    got, ref = out["compiled"], out["numpy"]
    for g, r in ((got.twist, ref.twist), (got.covariance, ref.covariance), (got.doppler_share, ref.doppler_share)):
        assert g.shape == r.shape and g.dtype == r.dtype
        # norm-wise, as a solve's rounding is bounded: with a singular Doppler covariance (the floor
        # alone regularises it) a component 3000 times smaller than the other differed by 9e-12
        np.testing.assert_allclose(g, r, rtol=1e-8, atol=1e-10 * max(1.0, float(np.max(np.abs(r)))))
    np.testing.assert_allclose(got.chi2, ref.chi2, rtol=1e-7, atol=1e-9, equal_nan=True)


@given(v=st.floats(-50, 50), w=st.floats(-5, 5))
def test_wheel_variances_are_the_covariance_diagonal(v, w):
    """The two floats are :func:`wheel_covariance`'s diagonal, bit for bit."""
    from fmcwlog.frontend.params import FrontEndParams

    noise = FrontEndParams().wheel_noise
    cov = wheel_covariance((v, w), noise)
    assert wheel_variances((v, w), noise) == (cov[0, 0], cov[1, 1])
    assert cov[0, 1] == 0.0 and cov[1, 0] == 0.0


@settings(max_examples=60, deadline=None)
@given(rows=st.lists(st.one_of(st.tuples(st.floats(allow_nan=True), st.floats(), st.integers(-2**40, 2**40)),
                               st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3)), max_size=300),
       capacity=st.integers(0, 8), reads=st.sets(st.integers(0, 300), max_size=5))
def test_growing_array_batches_tuples_as_rows(rows, capacity, reads):
    """Tuple rows stored in batches hold what one assignment a row holds, in order, whatever the
    mix with array rows, the starting capacity and the reads in between."""
    g = GrowingArray(np.float64, (3,), capacity=max(capacity, 1))
    ref = np.zeros((len(rows), 3))
    for i, row in enumerate(rows):
        ref[i] = row
        g.append(tuple(row) if isinstance(row, tuple) else np.array(row))
        assert len(g) == i + 1
        if i in reads:
            np.testing.assert_array_equal(g.values, ref[: i + 1])
    assert g.values.tobytes() == ref.tobytes()


def test_growing_array_keeps_an_array_row_as_given_then():
    """An array row is stored when appended: changing the caller's array later changes nothing."""
    g = GrowingArray(np.float64, (2,))
    row = np.array([1.0, 2.0])
    g.append((0.5, 0.25))
    g.append(row)
    row[:] = 9.0
    np.testing.assert_array_equal(g.values, [[0.5, 0.25], [1.0, 2.0]])


@needs_core
@pytest.mark.parametrize("method", ["improved", "baseline"])
def test_stepped_log_compiled_against_numpy(use, method):
    """A recorded log stepped with each kernel switch: the same sweeps registered and the same
    moving counts, poses within 1e-9 (the glue's float paths differ from numpy's by rounding)."""
    from pathlib import Path

    from fmcwlog.api import ProcessOptions, process

    log = Path(__file__).resolve().parents[3] / "sample_logs" / "crowd_30s.mcap"
    if not log.exists():
        pytest.skip("sample log missing")
    import tempfile

    from fmcwlog.frontend.methods import FrontEnd

    results = {}
    for kind in ("numpy", "compiled"):
        use(kind)
        got = []
        step = FrontEnd.step

        def spy(self, sweep, prior, _got=got, _step=step):
            r = _step(self, sweep, prior)
            _got.append((r.pose.copy(), r.iterations, r.moving_points, r.moving_mask.tobytes(), r.keyframe))
            return r

        FrontEnd.step = spy
        try:
            with tempfile.TemporaryDirectory() as tmp:
                process(str(log), tmp + "/o", ProcessOptions(methods=(method,)), jobs=1)
        finally:
            FrontEnd.step = step
        results[kind] = got
    a, b = results["numpy"], results["compiled"]
    assert len(a) == len(b) > 0
    assert [x[1:] for x in a] == [x[1:] for x in b]
    np.testing.assert_allclose(np.array([x[0] for x in b]), np.array([x[0] for x in a]), rtol=0, atol=1e-9)
