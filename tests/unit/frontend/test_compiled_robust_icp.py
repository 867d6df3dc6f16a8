"""The compiled robust ICP (fmcwlog._core.robust_icp) against its numpy reference, and the map's
search index that both ICP variants share.

Iteration counts, pairs kept, EM fits and convergence are compared exactly, poses, the hessian and
the mixture to 1e-9: on the registrations the improved method makes on a recorded log, and on
generated scenes over the parameters that steer the iterations (gate, Huber, GMMSC and its EM fit,
extrapolation, the pose prior, a mixture handed in, the residual: point-to-line on the map's lines or
point-to-point). Where the module is not built the comparisons
skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it.
"""

from dataclasses import replace

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core, wall_scene
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from fmcwlog.frontend import robust_icp
from fmcwlog.frontend.gmmsc import DistanceMixture, GMMSCParams
from fmcwlog.frontend.icp import ICPParams
from fmcwlog.frontend.keyframe_map import KeyframeMap
from fmcwlog.frontend.point_to_point_icp import register_point_to_point
from fmcwlog.frontend.recovery import inlier_fraction
from fmcwlog.kernels import compiled
from fmcwlog.kernels.nearest import NearestPairs


def assert_same(fast, ref, tol=1e-9):
    """The same counts; poses, RMS distance and mixture means and weights within ``tol`` (m, rad,
    or a fraction), the hessian within ``tol`` of its scale, the variances within ``1e-5 tol`` (m²) or
    ``1e-2 tol`` of themselves (a wide component's E[d²] rounds in proportion to its size)."""
    assert fast.iterations == ref.iterations
    assert fast.n_correspondences_kept == ref.n_correspondences_kept
    assert fast.converged == ref.converged
    assert fast.n_gmm_fits == ref.n_gmm_fits
    np.testing.assert_allclose(fast.pose, ref.pose, rtol=0, atol=tol)
    np.testing.assert_allclose(fast.rmse, ref.rmse, rtol=0, atol=tol, equal_nan=True)
    scale = max(1.0, float(np.abs(ref.hessian).max()))
    np.testing.assert_allclose(fast.hessian, ref.hessian, rtol=0, atol=tol * scale)
    assert (fast.mixture is None) == (ref.mixture is None)
    if ref.mixture is not None:
        for name in ("means", "mix"):
            np.testing.assert_allclose(getattr(fast.mixture, name), getattr(ref.mixture, name), rtol=0, atol=tol)
        # variances: E[d²] - E[d]² cancels for a collapsed component, leaving the rounding of E[d²]
        np.testing.assert_allclose(fast.mixture.sigmas**2, ref.mixture.sigmas**2, rtol=1e-2 * tol, atol=1e-5 * tol)
        assert fast.mixture.merge_overlap == ref.mixture.merge_overlap
        np.testing.assert_allclose(fast.mixture.fit_median, ref.mixture.fit_median, rtol=0, atol=tol, equal_nan=True)


def _agree(a, b, tol):
    try:
        assert_same(a, b, tol)
    except AssertionError:
        return False
    return True


def _both(use, source, target, start, params, mixture=None, prior_pose=None, prior_information=None,
          inlier_distance=None):
    """The numpy reference on a KD-tree, then the compiled kernel through ``register`` on a map index;
    with ``inlier_distance``, the inliers the kernel counted at its pose are those the search and the
    KD-tree count there."""
    ref = robust_icp.register_numpy(source, cKDTree(target), target, start, params, mixture, prior_pose,
                                    prior_information)
    use("compiled")
    fast = robust_icp.register(source, compiled.MapIndex(target), target, start, params, mixture, prior_pose,
                               prior_information, inlier_distance)
    assert isinstance(fast.search, compiled.CompiledNearest)
    if inlier_distance is not None and inlier_distance <= params.max_correspondence_distance and len(source):
        counted = fast.search.counted
        assert counted is not None and counted[0] is fast.pose and counted[1] == inlier_distance
        fraction = inlier_fraction(source, fast.pose, fast.search.tree, inlier_distance, fast.search)
        fast.search.counted = None  # the search's own answer, then the tree's
        assert fraction == inlier_fraction(source, fast.pose, fast.search.tree, inlier_distance, fast.search)
        assert fraction == inlier_fraction(source, fast.pose, cKDTree(target), inlier_distance)
        fast.search.counted = counted
    elif len(source):
        assert fast.search.counted is None
    return fast, ref


@pytest.fixture(scope="module")
def recorded():
    """Every registration the improved method makes processing the 30 s crowd log, with its mixture
    and pose prior: (source, target, start, params, mixture, prior pose, prior information)."""
    import tempfile

    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.frontend import methods

    seen, original = [], methods.register

    def capture(source, tree, target, start, params, mixture=None, prior_pose=None, prior_information=None,
                inlier_distance=None):
        seen.append((source.copy(), target.copy(), np.array(start, float), params, mixture,
                     None if prior_pose is None else np.array(prior_pose, float),
                     None if prior_information is None else np.array(prior_information, float), inlier_distance))
        return robust_icp.register_numpy(source, tree, target, start, params, mixture, prior_pose, prior_information)

    methods.register = capture
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/out",
                    ProcessOptions(methods=("improved",), backend="none"), jobs=1)
    finally:
        methods.register = original
    return seen


@needs_core
def test_recorded_registrations_agree(recorded, use):
    assert len(recorded) > 100
    assert any(r[4] is not None for r in recorded) and any(r[6] is not None for r in recorded)
    assert all(r[7] == 0.1 for r in recorded)  # the recovery's inlier distance, counted by the kernel
    for source, target, start, params, mixture, prior_pose, prior_info, inlier_distance in recorded[::2]:
        fast, ref = _both(use, source, target, start, params, mixture, prior_pose, prior_info, inlier_distance)
        assert_same(fast, ref)
        if ref.n_gmm_fits == 0:
            assert fast.mixture is mixture  # no fit: the given mixture, the same object
        d = inlier_fraction(source, ref.pose, fast.search.tree, 0.1, fast.search)
        assert d == inlier_fraction(source, ref.pose, cKDTree(target), 0.1)


@needs_core
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_segments=st.integers(1, 12), n_points=st.integers(1, 2000),
       n_source=st.integers(0, 600), clutter=st.sampled_from([0.0, 0.1, 0.5]),
       dx=st.floats(-0.3, 0.3), dy=st.floats(-0.3, 0.3), dth=st.floats(-0.15, 0.15),
       gate=st.sampled_from([0.05, 0.3, 0.5, 2.0]), iterations=st.integers(1, 40),
       use_huber=st.booleans(), use_gmmsc=st.booleans(), extrapolate=st.booleans(),
       k=st.integers(1, 4), w_th=st.sampled_from([0.05, 0.3, 0.5, 0.9]), merge=st.sampled_from([0.2, 1.0]),
       refit=st.sampled_from([0.25, 0.8, 1.0]), fit_samples=st.sampled_from([7, 50, 500]),
       em_iter=st.sampled_from([1, 10, 100]), prior=st.booleans(), given_mixture=st.booleans(),
       inlier_distance=st.sampled_from([None, 0.02, 0.1, 0.5]),
       residual=st.sampled_from(["point_to_line", "point_to_point"]), line_ratio=st.sampled_from([1.0, 9.0]),
       line_neighbours=st.sampled_from([3, 7, 12]))
def test_generated_registrations_agree(use, seed, n_segments, n_points, n_source, clutter, dx, dy, dth, gate,
                                       iterations, use_huber, use_gmmsc, extrapolate, k, w_th, merge, refit,
                                       fit_samples, em_iter, prior, given_mixture, inlier_distance, residual,
                                       line_ratio, line_neighbours):
    # w_th > 0: with 0 a mixture can keep pairs of weight down to subnormal numbers, whose step is
    # rounding noise in either implementation.
    source, target = wall_scene(seed, n_segments, n_points, n_source, (dx, dy, dth),
                                int(clutter * min(n_source, n_points)))
    gmm = replace(GMMSCParams(), n_components=k, w_th=w_th, merge_overlap=merge, max_fit_samples=fit_samples,
                  max_iter=em_iter)
    params = replace(ICPParams(), max_correspondence_distance=gate, max_iterations=iterations, use_huber=use_huber,
                     use_gmmsc=use_gmmsc, extrapolate=extrapolate, gmmsc=gmm, gmm_refit_ratio=refit,
                     gmm_start_translation=0.01, gmm_start_rotation=0.01, residual=residual,
                     line_eigen_ratio=line_ratio, line_neighbours=line_neighbours)
    start = np.zeros(3)
    mixture = DistanceMixture(np.array([0.01, 0.2]), np.array([0.01, 0.1]), np.array([0.7, 0.3]), 0.2,
                              0.02) if given_mixture else None
    prior_pose = np.array([dx, dy, dth]) * 0.5 if prior else None
    prior_info = np.diag([4.0, 1.0, 9.0]) if prior else None
    fast, ref = _both(use, source, target, start, params, mixture, prior_pose, prior_info, inlier_distance)
    # where the reference itself moves by more than 1e-10 for a start 1e-12 away (iterations cut
    # off on a flat cost, extrapolated steps magnifying rounding: a single wall, wide gates, clutter),
    # rounding alone takes any other implementation more than 1e-9 away: such cases are skipped
    nudged = robust_icp.register_numpy(source, cKDTree(target), target, start + 1e-12, params, mixture,
                                       prior_pose, prior_info)
    assume(_agree(nudged, ref, 1e-10))
    assert_same(fast, ref)


@needs_core
def test_singular_step_and_degenerate_mixture(use):
    """Every source point at the origin: no rotation is observed (a singular H, the least-squares
    step) and all distances are equal (no mixture: weights 1)."""
    source = np.zeros((20, 2))
    target = np.array([[0.1, 0.05], [3.0, 3.0]])
    params = replace(ICPParams(), gmm_start_translation=1.0, gmm_start_rotation=1.0)
    fast, ref = _both(use, source, target, np.zeros(3), params)
    assert_same(fast, ref)
    assert ref.n_gmm_fits == 0 and ref.mixture is None and np.linalg.matrix_rank(ref.hessian) == 2
    np.testing.assert_allclose(ref.pose[:2], [0.1, 0.05], atol=1e-12)


def _map(seed=0):
    """A keyframe map of two random wall scans."""
    rng = np.random.default_rng(seed)
    m = KeyframeMap()
    for _ in range(2):
        t = rng.random(800)
        m.add(np.column_stack([8 * t - 4, np.where(rng.random(800) < 0.5, -2.0, 2.0) + 0.01 * rng.normal(size=800)]),
              0.0)
    return m


@needs_core
def test_map_index_builds_once_and_only_what_runs(use):
    """The compiled registrations of both variants share one grid per map state and never build the
    KD-tree; the numpy path builds the tree, which answers as a cKDTree of the points would."""
    m = _map()
    source = m.points[::7] + 0.02
    use("compiled")
    a = robust_icp.register(source, m.tree, m.points, np.zeros(3))
    b = register_point_to_point(source, m.tree, m.points, np.zeros(3))
    assert a.search.grid is b.search.grid
    assert m.tree._tree is None  # the compiled kernels did not need it
    assert inlier_fraction(source, a.pose, m.tree, 0.1) == inlier_fraction(source, a.pose, cKDTree(m.points), 0.1)
    assert m.tree._tree is None  # inlier_fraction took the kept grid
    use("numpy")
    ref = robust_icp.register(source, m.tree, m.points, np.zeros(3))
    assert isinstance(ref.search, NearestPairs) and m.tree._tree is not None
    assert m.tree.n == len(m.points)
    assert_same(a, ref)
    before = m.tree
    m.add(source, 1.0)
    assert m.tree is not before  # a new map state, new structures


def test_map_index_answers_as_its_tree():
    m = _map(1)
    q = np.random.default_rng(2).uniform(-5, 5, (200, 2))
    d, i = m.tree.query(q, k=3, distance_upper_bound=0.5)
    dr, ir = cKDTree(m.points).query(q, k=3, distance_upper_bound=0.5)
    np.testing.assert_array_equal(d, dr)
    np.testing.assert_array_equal(i, ir)
    assert KeyframeMap().tree is None
