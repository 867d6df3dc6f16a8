"""GMMSC rejection against known generating distributions."""

import numpy as np
from scipy.stats import norm

from fmcwlog.frontend.gmmsc import (
    DistanceMixture,
    GMMSCParams,
    fit_distance_mixture,
    gmmsc_weights,
)


def _contaminated(seed, n=1000, outlier_frac=0.2, sigma=0.02, d_max=1.0):
    rng = np.random.default_rng(seed)
    n_out = int(n * outlier_frac)
    d = np.concatenate([np.abs(rng.normal(0, sigma, n - n_out)), rng.uniform(0, d_max, n_out)])
    is_out = np.arange(n) >= n - n_out
    return d, is_out


def test_rejects_uniform_outliers_with_high_precision():
    for seed in range(5):
        d, is_out = _contaminated(seed)
        res = gmmsc_weights(d)
        rej = ~res.keep
        assert is_out[rej].mean() > 0.95  # precision: rejected pairs are outliers
        # recall: outliers beyond 4σ of the inlier half-normal are all found; those
        # inside it are indistinguishable and may stay
        assert rej[is_out & (d > 0.08)].mean() > 0.99
        assert rej[~is_out].mean() < 0.02  # few inliers lost


def test_em_recovers_generating_mixture():
    rng = np.random.default_rng(0)
    d = np.concatenate([rng.normal(0.10, 0.01, 7000), rng.normal(0.50, 0.05, 3000)])
    m = fit_distance_mixture(d, GMMSCParams(max_fit_samples=10_000, max_iter=100))
    order = np.argsort(m.means)
    np.testing.assert_allclose(m.means[order], [0.10, 0.50], atol=0.005)
    np.testing.assert_allclose(m.sigmas[order], [0.01, 0.05], rtol=0.05)
    np.testing.assert_allclose(m.mix[order], [0.7, 0.3], atol=0.02)
    assert m.inlier == order[0]


def test_posterior_is_eq21_by_scipy():
    m = DistanceMixture(
        means=np.array([0.4, 0.02]), sigmas=np.array([0.2, 0.01]), mix=np.array([0.3, 0.7]),
        merge_overlap=1.0,
    )
    d = np.linspace(0.0, 1.0, 201)
    dens = np.stack([m.mix[k] * norm.pdf(d, m.means[k], m.sigmas[k]) for k in range(2)], -1)
    expected = dens[:, 1] / dens.sum(axis=1)  # inlier = smallest mean = index 1
    np.testing.assert_allclose(m.posterior(d), expected, atol=1e-12)
    # the used weights are eq. 21 above the inlier mean where eq. 21 already decreases,
    # clamped to the value at the mean below it, and never increase with distance
    w = m.weights(d)
    above = d >= 0.02
    np.testing.assert_allclose(w[above], np.minimum.accumulate(expected[above]), atol=1e-12)
    at_mean = 0.7 * norm.pdf(0.02, 0.02, 0.01)
    at_mean /= at_mean + 0.3 * norm.pdf(0.02, 0.4, 0.2)
    np.testing.assert_allclose(w[~above], at_mean, atol=1e-12)
    assert np.all(np.diff(w) <= 1e-15)


def test_raw_eq21_is_not_monotone_but_weights_are():
    # narrow inlier at 0.05: at d = 0 (5σ below its mean) raw eq. 21 prefers the
    # broad outlier component; the weight used must not punish a perfect match
    m = DistanceMixture(np.array([0.05, 0.3]), np.array([0.01, 0.15]), np.array([0.8, 0.2]))
    assert m.posterior(np.array([0.0]))[0] < 0.5
    assert m.weights(np.array([0.0]))[0] > 0.99


def test_single_population_is_not_split():
    rng = np.random.default_rng(4)
    rayleigh = np.hypot(*rng.normal(0, 0.01, (2, 1000)))  # 2-D residual norms, no outliers
    assert gmmsc_weights(rayleigh).keep.all()
    half_normal = np.abs(rng.normal(0, 0.02, 800))
    assert gmmsc_weights(half_normal).keep.all()
    # point-to-wall distances under range noise: half-normal with a scale that
    # varies with the incidence angle (heavier tail)
    scaled = np.abs(rng.normal(0, 1, 1000)) * rng.uniform(0.001, 0.006, 1000)
    assert gmmsc_weights(scaled).keep.all()
    # plain eq. 21 (no grouping) would throw away a large part of good pairs
    plain = gmmsc_weights(rayleigh, GMMSCParams(merge_overlap=1.0))
    assert (~plain.keep).mean() > 0.2


def test_degenerate_inputs():
    for d in (np.zeros(0), np.array([0.1, 0.2]), np.full(50, 0.3)):
        res = gmmsc_weights(d)
        assert res.keep.all() and np.all(res.weights == 1.0) and res.weights.shape == d.shape
    d, _ = _contaminated(0)
    res = gmmsc_weights(d, GMMSCParams(n_components=1))
    assert res.keep.all() and np.all(res.weights == 1.0)
    # K = 3 works and still keeps the inliers
    d, is_out = _contaminated(1)
    res = gmmsc_weights(d, GMMSCParams(n_components=3))
    assert res.keep[~is_out].mean() > 0.97 and (~res.keep)[is_out & (d > 0.08)].mean() > 0.99


def test_deterministic_and_evaluate_without_refit():
    d, _ = _contaminated(2)
    a, b = gmmsc_weights(d), gmmsc_weights(d)
    np.testing.assert_array_equal(a.weights, b.weights)
    c = gmmsc_weights(d, mixture=a.mixture, refit=False)
    np.testing.assert_array_equal(a.weights, c.weights)
    warm = gmmsc_weights(d, mixture=a.mixture)  # warm-started refit converges to the same
    np.testing.assert_allclose(warm.weights, a.weights, atol=5e-3)  # EM tolerance


def test_em_matches_sklearn_gaussian_mixture():
    """The EM written out for 1-D distances is sklearn's GaussianMixture (a second implementation),
    from the same start, over K, budgets and data with and without outliers."""
    import warnings

    from sklearn.exceptions import ConvergenceWarning
    from sklearn.mixture import GaussianMixture

    from fmcwlog.frontend.gmmsc import _initial_guess

    rng = np.random.default_rng(7)
    cases = [(_contaminated(3)[0], 2, 10, 1e-3), (_contaminated(4, outlier_frac=0.5)[0], 3, 50, 1e-6),
             (np.abs(rng.normal(0, 0.02, 400)), 2, 100, 1e-8), (rng.uniform(0, 0.5, 300), 4, 5, 1e-3)]
    for d, k, max_iter, tol in cases:
        p = GMMSCParams(n_components=k, max_iter=max_iter, tol=tol, max_fit_samples=10_000)
        means, var, mix = _initial_guess(d, k)
        gmm = GaussianMixture(n_components=k, covariance_type="diag", max_iter=max_iter, tol=tol,
                              reg_covar=p.reg_covar, weights_init=mix, means_init=means[:, None],
                              precisions_init=(1.0 / var)[:, None], random_state=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gmm.fit(d[:, None])
        m = fit_distance_mixture(d, p)
        np.testing.assert_allclose(m.means, gmm.means_[:, 0], rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(m.sigmas, np.sqrt(gmm.covariances_[:, 0]), rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(m.mix, gmm.weights_, rtol=1e-7, atol=1e-12)
