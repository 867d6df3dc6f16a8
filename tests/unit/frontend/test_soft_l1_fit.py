"""The calibration check's robust least squares against scipy's (a second implementation of the
same minimum): ``soft_l1_fit`` and ``scipy.optimize.least_squares(loss="soft_l1")`` on problems
with a known answer, outliers among the residuals and parameters of unlike scales."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from fmcwlog.frontend.self_calibration import soft_l1_fit


def _problem(seed: int, n: int, outliers: float):
    """Residuals of a rational model in 4 parameters of scales 1e-3 to 10, whitened by σ = 0.01,
    a share ``outliers`` of the samples off by 20-100 σ; the truth and a start off from it."""
    rng = np.random.default_rng(seed)
    truth = np.array([0.1, 0.35, 2e-3, 8.0])
    t = rng.uniform(-1.0, 1.0, n)
    clean = truth[0] * t + truth[1] * t**2 + truth[2] / (1.0 + t**2) + truth[3] * 1e-3 * np.cos(3 * t)
    y = clean + rng.normal(0.0, 0.01, n)
    bad = rng.random(n) < outliers
    y[bad] += rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(0.2, 1.0, bad.sum())

    def fun(q):
        return (q[0] * t + q[1] * t**2 + q[2] / (1.0 + t**2) + q[3] * 1e-3 * np.cos(3 * t) - y) / 0.01

    start = truth * rng.uniform(0.7, 1.3, 4)
    return fun, truth, start


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(20, 2000), outliers=st.sampled_from([0.0, 0.05, 0.3]),
       scale=st.sampled_from([0.5, 3.0, 100.0]))
def test_the_minimum_of_scipys_soft_l1(seed, n, outliers, scale):
    fun, truth, start = _problem(seed, n, outliers)
    x, r = soft_l1_fit(fun, start, scale)
    ref = least_squares(fun, start, loss="soft_l1", f_scale=scale, x_scale="jac", method="trf",
                        ftol=1e-14, xtol=1e-14, gtol=1e-14)
    # the same minimum: a cost as low as scipy's (to rounding; where the two differ it is scipy that
    # stopped first, its ftol test), the parameters within 1 % of each one's uncertainty (on the
    # calibration check's own problems the two agree to ~1e-8 of it)
    def cost(res):
        return np.sum(2.0 * scale**2 * (np.sqrt(1.0 + (res / scale) ** 2) - 1.0))

    assert cost(r) <= cost(ref.fun) * (1.0 + 1e-9)
    sigma = np.sqrt(np.diag(np.linalg.pinv(_jac(fun, ref.x).T @ _jac(fun, ref.x))))
    np.testing.assert_array_less(np.abs(x - ref.x), 1e-2 * sigma + 1e-12)
    np.testing.assert_array_equal(r, fun(x))


def test_outliers_weigh_little():
    """With 30 % outliers the robust fit stays near the truth where plain least squares is pulled off."""
    fun, truth, start = _problem(3, 400, 0.3)
    x, _ = soft_l1_fit(fun, start, 3.0)
    plain, _ = soft_l1_fit(fun, start, 1e6)  # a scale beyond every residual: plain least squares
    assert np.abs(x - truth)[:2].max() < 0.01
    assert np.abs(plain - truth)[:2].max() > 2 * np.abs(x - truth)[:2].max()


def test_a_start_at_the_minimum_stays():
    fun, truth, start = _problem(5, 200, 0.0)
    x, _ = soft_l1_fit(fun, start, 3.0)
    again, _ = soft_l1_fit(fun, x, 3.0)
    np.testing.assert_allclose(again, x, rtol=1e-9, atol=1e-12)


def _jac(fun, x):
    h = 1e-6 * np.maximum(np.abs(x), 1e-3)
    return np.stack([(fun(x + e) - fun(x - e)) / (2 * s) for e, s in zip(np.diag(h), h)], -1)
