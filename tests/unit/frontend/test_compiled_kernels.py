"""The compiled kernels (fmcwlog._core) against their numpy reference, and the switch between them.

Pairs are compared exactly, poses to 1e-9, iteration counts and pair counts equal: on the
registrations the baseline makes on a recorded log, and on generated scenes. Where the module is
not built the comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it (CI does).
"""

import json
import textwrap
from dataclasses import replace

import numpy as np
import pytest
from helpers import CORE, SAMPLE_LOGS, needs_core, run_python, wall_scene
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from fmcwlog.errors import FmcwlogError
from fmcwlog.frontend import point_to_point_icp as p2p
from fmcwlog.frontend.icp import ICPParams
from fmcwlog.frontend.recovery import inlier_fraction
from fmcwlog.kernels import compiled
from fmcwlog.kernels.nearest import NearestPairs, find_correspondences


def _register(kind, use, *args):
    use(kind)
    res = p2p.register_point_to_point(*args)
    assert isinstance(res.search, compiled.CompiledNearest if kind == "compiled" else NearestPairs)
    return res


def assert_same(fast, ref, tol=1e-9):
    assert fast.iterations == ref.iterations
    assert fast.n_correspondences_kept == ref.n_correspondences_kept
    assert fast.converged == ref.converged
    np.testing.assert_allclose(fast.pose, ref.pose, rtol=0, atol=tol)
    np.testing.assert_allclose(fast.rmse, ref.rmse, rtol=1e-9, equal_nan=True)
    np.testing.assert_allclose(fast.hessian, ref.hessian, rtol=1e-9, atol=1e-9)


def assert_same_pairs(search, source, tree, target, pose, gate):
    """The compiled search's pairs under ``pose`` are the KD-tree's: the same points, the same
    target coordinates, the same distances (to rounding of the moved points)."""
    ref = find_correspondences(source, pose, tree, target, gate)
    moved, idx, dist = search.nearest(pose)
    ours = np.flatnonzero(dist < gate)
    np.testing.assert_array_equal(ours, ref.source_idx)
    np.testing.assert_array_equal(target[idx[ours]], ref.target)
    np.testing.assert_allclose(dist[ours], ref.distances, rtol=0, atol=1e-12)
    np.testing.assert_allclose(moved[ours], ref.moved, rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def recorded():
    """Every registration the baseline makes processing the 30 s corridor log: (source, target, start)."""
    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.frontend import methods

    seen, original = [], methods.register_point_to_point

    def capture(source, tree, target, start, params, inlier_distance=None):
        assert inlier_distance == 0.1  # the recovery's, counted by the kernel
        seen.append((source.copy(), target.copy(), np.array(start, float), params))
        return p2p.register_point_to_point_numpy(source, tree, target, start, params)

    methods.register_point_to_point = capture
    try:
        import tempfile
        with tempfile.TemporaryDirectory() as tmp:
            process(str(SAMPLE_LOGS / "corridor_30s.mcap"), tmp + "/out", ProcessOptions(methods=("baseline",)), jobs=1)
    finally:
        methods.register_point_to_point = original
    return seen[::3]  # a third of them keeps the test quick; they are alike


@needs_core
def test_recorded_registrations_agree(recorded, use):
    assert len(recorded) > 50
    for source, target, start, params in recorded:
        tree = cKDTree(target)
        ref = p2p.register_point_to_point_numpy(source, tree, target, start, params)
        fast = _register("compiled", use, source, tree, target, start, params)
        assert_same(fast, ref)
        for pose in (start, ref.pose):
            assert_same_pairs(fast.search, source, tree, target, pose, params.max_correspondence_distance)
        assert inlier_fraction(source, ref.pose, tree, 0.1, fast.search) == inlier_fraction(source, ref.pose, tree, 0.1)
        assert_counted_inliers(use, source, tree, target, start, params, 0.1)


def assert_counted_inliers(use, source, tree, target, start, params, distance):
    """The inliers the kernel counts at its final pose (``inlier_distance``) are those the search and the
    KD-tree count there; none counted beyond the gate."""
    fast = _register("compiled", use, source, tree, target, start, params, distance)
    if distance > params.max_correspondence_distance or not len(source):
        assert fast.search.counted is None or not len(source)
        return
    counted = fast.search.counted
    assert counted is not None and counted[0] is fast.pose and counted[1] == distance
    fraction = inlier_fraction(source, fast.pose, tree, distance, fast.search)
    fast.search.counted = None
    assert fraction == inlier_fraction(source, fast.pose, tree, distance, fast.search)
    assert fraction == inlier_fraction(source, fast.pose, tree, distance)


def _rotation_well_posed(source, tree, target, pose, gate) -> bool:
    """Whether the first closed-form step's rotation is fixed to far better than the 1e-9 the
    comparison asks: ``θ = atan2(Σ p'×q', Σ p'·q')`` on centred pairs loses every digit when both
    sums are rounding-sized against their terms (e.g. most source points paired with one wall end,
    so the centred targets are near zero). There two correct summation orders (numpy's pairwise,
    the kernel's sequential) give rotations that differ by far more than 1e-9, and neither is wrong."""
    c = find_correspondences(source, pose, tree, target, gate)
    if c.distances.size < 2:
        return True
    p = source[c.source_idx] - source[c.source_idx].mean(axis=0)
    q = c.target - c.target.mean(axis=0)
    cross, dot = p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0], (p * q).sum(axis=1)
    size = np.abs(p[:, 0] * q[:, 1]).sum() + np.abs(p[:, 1] * q[:, 0]).sum() + np.abs(p * q).sum()
    return bool(np.hypot(cross.sum(), dot.sum()) > 1e-6 * size)


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_segments=st.integers(1, 12), n_points=st.integers(1, 2000),
       n_source=st.integers(0, 600), dx=st.floats(-0.4, 0.4), dy=st.floats(-0.4, 0.4), dth=st.floats(-0.2, 0.2),
       gate=st.sampled_from([0.05, 0.3, 0.5, 2.0]), iterations=st.integers(1, 40))
def test_generated_registrations_agree(use, seed, n_segments, n_points, n_source, dx, dy, dth, gate, iterations):
    source, target = wall_scene(seed, n_segments, n_points, n_source, (dx, dy, dth), n_source // 10)
    tree = cKDTree(target)
    params = replace(ICPParams(), max_correspondence_distance=gate, max_iterations=iterations)
    start = np.zeros(3)
    assume(_rotation_well_posed(source, tree, target, start, gate))
    ref = p2p.register_point_to_point_numpy(source, tree, target, start, params)
    fast = _register("compiled", use, source, tree, target, start, params)
    assert_same(fast, ref)
    assert_same_pairs(fast.search, source, tree, target, ref.pose, gate)
    # the reference's own search gives the same pairs again
    pairs = NearestPairs(source, tree, target, gate).pairs(ref.pose)
    np.testing.assert_array_equal(pairs.source_idx, find_correspondences(source, ref.pose, tree, target, gate).source_idx)
    for distance in (0.02, 0.1, 0.5):
        assert_counted_inliers(use, source, tree, target, start, params, distance)


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_source=st.integers(10, 300), steps=st.integers(0, 4),
       dth=st.sampled_from([0.0, 1e-3, 0.02]), iterations=st.integers(1, 40))
def test_lattice_ties_agree(use, seed, n_source, steps, dth, iterations):
    """A target on a lattice of 1/4 m and a source off it by multiples of 1/8 m, each point moved by
    about 1e-10 m: many source points within 1e-10 m of halfway between two or four targets as the
    ICP starts (near ties: exact ties go to whichever point the KD-tree meets first), and more as it
    moves. Each iteration's pairs decide the next pose, so the poses, pair counts and iteration
    counts agree only if every look-up does, the ones an earlier iteration's search answers for the
    next included."""
    rng = np.random.default_rng(seed)
    ij = np.stack(np.meshgrid(np.arange(-12, 13), np.arange(-12, 13)), axis=-1).reshape(-1, 2)
    target = ij[rng.permutation(len(ij))] * 0.25
    target = np.ascontiguousarray(target + rng.normal(0.0, 1e-10, target.shape))
    source = target[rng.choice(len(target), n_source, replace=False)] + rng.integers(-2, 3, (n_source, 2)) * 0.125
    source = np.ascontiguousarray(source + steps * np.array([0.125, 0.0]) + rng.normal(0.0, 1e-10, source.shape))
    tree = cKDTree(target)
    params = replace(ICPParams(), max_correspondence_distance=0.3, max_iterations=iterations)
    start = np.array([0.0, 0.0, dth])
    assume(_rotation_well_posed(source, tree, target, start, 0.3))
    ref = p2p.register_point_to_point_numpy(source, tree, target, start, params)
    fast = _register("compiled", use, source, tree, target, start, params)
    assert_same(fast, ref)
    for distance in (0.125, 0.2):
        assert_counted_inliers(use, source, tree, target, start, params, distance)


@needs_core
def test_far_and_odd_inputs(use):
    """No target, a point far outside the grid, a huge map: no pair or the exact one, never a crash."""
    params = ICPParams()
    source = np.array([[0.0, 0.0], [1e6, -1e6], [0.25, 0.0]] * 5)
    for target in (np.empty((0, 2)), np.array([[0.2, 0.0]]), np.array([[0.2, 0.0], [5e5, 5e5], [-5e5, -5e5]])):
        tree = cKDTree(target) if len(target) else cKDTree(np.array([[1e300, 1e300]]))
        ref = p2p.register_point_to_point_numpy(source, tree, target, np.zeros(3), params) if len(target) else None
        fast = _register("compiled", use, source, tree, target, np.zeros(3), params)
        if ref is not None:
            assert_same(fast, ref)
            assert_same_pairs(fast.search, source, tree, target, np.zeros(3), params.max_correspondence_distance)
        else:
            assert fast.n_correspondences_kept == 0 and fast.iterations == 1 and not fast.converged


def test_switch(use):
    assert use("numpy") is None
    with pytest.raises(FmcwlogError, match="FMCWLOG_KERNELS"):
        use("fast")
    if CORE is not None:
        assert use("compiled") is CORE
        assert use("") is not None  # the default where it loads


def test_falls_back_to_numpy_without_the_module():
    """A fresh interpreter where fmcwlog._core cannot be found: numpy, no error; asked for, one error."""
    code, out, err = run_python(textwrap.dedent("""
        import json, os, sys
        import numpy as np
        from scipy.spatial import cKDTree
        os.environ.pop("FMCWLOG_KERNELS", None)
        sys.modules["fmcwlog._core"] = None  # not built
        from fmcwlog.kernels import compiled
        compiled._installed_builds = lambda: []
        from fmcwlog.frontend.point_to_point_icp import register_point_to_point
        target = np.random.default_rng(0).uniform(0, 5, (300, 2))
        res = register_point_to_point(target[:100] + 0.01, cKDTree(target), target, np.zeros(3))
        found = [compiled.core(), type(res.search).__name__]
        os.environ["FMCWLOG_KERNELS"] = "compiled"
        compiled._chosen = None
        try:
            compiled.core()
        except Exception as e:
            found.append(type(e).__name__)
        print(json.dumps(found))
    """))
    assert code == 0, err
    assert json.loads(out) == [None, "NearestPairs", "FmcwlogError"]
