"""The back end's compiled kernels (fmcwlog._core) against their numpy reference.

The correlative search must give the same pose, score, second peak and count of poses scored, bit
for bit: on the searches the closures' verification makes processing a recorded log (both
methods) and on generated scenes with every window and level layout. Where the module is not built
the comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it.
"""

import dataclasses
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core, record_small_ring, wall_scene
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.backend import local_edges, registration, verification
from fmcwlog.backend.params import BackendParams
from fmcwlog.kernels import correlative as corr


def assert_same_search(fast: corr.CorrelativeResult, ref: corr.CorrelativeResult) -> None:
    assert fast.score == ref.score and fast.second_score == ref.second_score
    assert fast.evaluated == ref.evaluated
    np.testing.assert_array_equal(fast.pose, ref.pose)
    if ref.second_pose is None:
        assert fast.second_pose is None
    else:
        np.testing.assert_array_equal(fast.second_pose, ref.second_pose)


def _both(use, grid, source, prior, p, with_second=True):
    use("numpy")
    ref = corr.correlative_match(grid, source, prior, p, with_second)
    assert use("compiled") is not None
    return corr.correlative_match(grid, source, prior, p, with_second), ref


@pytest.fixture(scope="module")
def searches():
    """Every closure search of both methods' back ends processing 50 s of a small ring (a lap and a
    half), and the front ends' searches on the 30 s crowd log: (grid, source, prior, parameters)."""
    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.frontend import methods

    seen, original = [], corr.correlative_match
    matched, register = [], registration.register_point_to_line

    def capture(grid, source, prior, p, *args):
        seen.append((grid, np.array(source, float), np.array(prior, float), p))
        return original(grid, source, prior, p, *args)

    def capture_match(source, submap, initial, p, prior=None):
        matched.append((np.array(source, float), submap, np.array(initial, float), p, prior))
        return register(source, submap, initial, p, prior)

    verification.correlative_match = methods.correlative_match = capture
    verification.register_point_to_line = local_edges.register_point_to_line = capture_match
    fused = local_edges.compiled
    local_edges.compiled = SimpleNamespace(core=lambda: None)  # the local edges one match at a time, each captured
    try:
        with tempfile.TemporaryDirectory() as tmp:
            ring = record_small_ring(Path(tmp) / "ring.mcap", 50.0)
            process(str(ring), tmp + "/out", ProcessOptions(), jobs=1)
            closures = len(seen)
            process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/crowd", ProcessOptions(), jobs=1)
    finally:
        verification.correlative_match = methods.correlative_match = original
        verification.register_point_to_line = local_edges.register_point_to_line = register
        local_edges.compiled = fused
    assert closures > 20
    _MATCHES[:] = matched
    return seen


_MATCHES: list = []  # the point-to-line matches of the same runs (filled by ``searches``)


@needs_core
def test_recorded_line_matches_agree(searches, use):
    """Every point-to-line match of those runs (local edges and closures): the same pairs and
    iterations, the pose and information to rounding."""
    assert len(_MATCHES) > 100
    for source, submap, initial, p, prior in _MATCHES[::2]:
        use("numpy")
        ref = registration.register_point_to_line(source, submap, initial, p, prior)
        use("compiled")
        fast = registration.register_point_to_line(source, submap, initial, p, prior)
        assert (fast.pairs, fast.iterations, fast.converged) == (ref.pairs, ref.iterations, ref.converged)
        np.testing.assert_allclose(fast.pose, ref.pose, rtol=0, atol=1e-9)
        np.testing.assert_allclose(fast.hessian, ref.hessian, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(fast.residuals, ref.residuals, rtol=0, atol=1e-9)


@needs_core
def test_recorded_closure_searches_agree(searches, use):
    assert len(searches) > 5
    for grid, source, prior, p in searches:
        fast, ref = _both(use, grid, source, prior, p)
        assert_same_search(fast, ref)
        # a window three times as wide, one level more: the widened searches after a drift
        wide = dataclasses.replace(p, linear_window=3 * p.linear_window, levels=min(p.levels + 1, corr.MAX_LEVELS))
        fast, ref = _both(use, corr.grid_for(grid_points(grid), wide), source, prior, wide)
        assert_same_search(fast, ref)


def grid_points(grid: corr.LikelihoodGrid) -> np.ndarray:
    """The centres of the cells a grid's targets lie in (a target set that gives the same grid)."""
    iy, ix = np.nonzero(grid.fine == grid.fine.max())
    return np.c_[grid.origin[0] + (ix + 0.5) * grid.resolution, grid.origin[1] + (iy + 0.5) * grid.resolution]


def _scene(seed, n_walls, n_points, n_source, offset):
    """Walls within ±6 m and a view of them with n_source // 10 + 1 clutter points (:func:`helpers.wall_scene`)."""
    return wall_scene(seed, n_walls, n_points, n_source, offset, n_source // 10 + 1, extent=6.0)


@needs_core
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_walls=st.integers(1, 8), n_points=st.integers(1, 1500),
       n_source=st.integers(1, 400), dx=st.floats(-1, 1), dy=st.floats(-1, 1), dth=st.floats(-0.3, 0.3),
       window=st.floats(0.05, 2.5), angle=st.floats(0.5, 30), resolution=st.sampled_from([0.03, 0.05, 0.1]),
       factor=st.integers(2, 5), levels=st.integers(1, 3), max_points=st.integers(10, 300),
       with_second=st.booleans())
def test_generated_searches_agree(use, seed, n_walls, n_points, n_source, dx, dy, dth, window, angle, resolution,
                                  factor, levels, max_points, with_second):
    source, target = _scene(seed, n_walls, n_points, n_source, (dx, dy, dth))
    p = corr.CorrelativeParams(linear_window=window, angular_window_deg=angle, resolution=resolution,
                               coarse_factor=factor, levels=levels, sigma=1.5 * resolution, max_points=max_points,
                               max_rotations=61)
    grid = corr.grid_for(target, p)
    fast, ref = _both(use, grid, source, np.array([0.1, -0.05, 0.02]), p, with_second)
    assert_same_search(fast, ref)


@needs_core
def test_equal_scores_are_visited_in_the_same_order(use):
    """A target of one point and a source of one point: whole plateaus of equal scores, visited
    highest first and equal ones by index by both."""
    p = corr.CorrelativeParams(linear_window=0.5, resolution=0.1, sigma=0.1, levels=2, max_rotations=31)
    grid = corr.grid_for(np.array([[0.0, 0.0], [1.0, 0.0]]), p)
    for source in (np.array([[0.5, 0.0]]), np.array([[0.3, 0.0], [0.3, 0.0]]), np.zeros((3, 2))):
        fast, ref = _both(use, grid, source, np.array([0.2, 0.0, 0.0]), p)
        assert_same_search(fast, ref)


def test_the_search_order_is_highest_first_then_by_index():
    values = np.array([0.5, 0.25, 0.5, 0.0, 0.25, 0.5, 0.0], np.float32)
    assert corr._descending(values).tolist() == [0, 2, 5, 1, 4, 3, 6]
    big = np.repeat(np.float32([0.0, 1.0, 0.5]), 700)  # long enough for any sort to leave the small-array path
    assert corr._descending(big).tolist() == list(range(700, 1400)) + list(range(1400, 2100)) + list(range(700))


def _both_grids(use, target, p):
    use("numpy")
    ref = corr.grid_for(target, p)
    assert use("compiled") is not None
    return corr.grid_for(target, p), ref


def assert_same_grids(fast: corr.LikelihoodGrid, ref: corr.LikelihoodGrid, p: corr.CorrelativeParams) -> None:
    """The same float32 grids, bit for bit: the fine one and every coarse one the search reads."""
    assert fast.fine.tobytes() == ref.fine.tobytes() and fast.shape == ref.shape
    np.testing.assert_array_equal(fast.origin, ref.origin)
    for e in range(1, p.levels):
        assert fast.coarse(p.coarse_factor**e).tobytes() == ref.coarse(p.coarse_factor**e).tobytes()


@needs_core
def test_recorded_likelihood_grids_agree(searches, use):
    for grid, _, _, p in searches[::3]:
        assert_same_grids(*_both_grids(use, grid_points(grid), p), p)


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_walls=st.integers(1, 8), n_points=st.integers(1, 1500),
       window=st.floats(0.05, 2.5), resolution=st.sampled_from([0.03, 0.05, 0.1]), sigma=st.floats(0.5, 4),
       factor=st.integers(2, 5), levels=st.integers(1, 3))
def test_generated_likelihood_grids_agree(use, seed, n_walls, n_points, window, resolution, sigma, factor, levels):
    """Walls, clusters and lone points; σ from half a cell to four cells (the likelihood table's end)."""
    _, target = _scene(seed, n_walls, n_points, 1, (0.0, 0.0, 0.0))
    p = corr.CorrelativeParams(linear_window=window, resolution=resolution, sigma=sigma * resolution,
                               coarse_factor=factor, levels=levels)
    assert_same_grids(*_both_grids(use, target, p), p)


def assert_same_submaps(use, points, p=registration.LineICPParams()):
    """The same points and planar flags; each normal the same line to rounding (either sign) where
    the point has one (elsewhere the covariance is near round, its eigenvectors ill-defined, and no
    pair uses them)."""
    use("numpy")
    ref = registration.build_submap(points, p)
    use("compiled")
    fast = registration.build_submap(points, p)
    np.testing.assert_array_equal(fast.points, ref.points)
    np.testing.assert_array_equal(fast.has_normal, ref.has_normal)
    used = ref.has_normal
    np.testing.assert_allclose(np.abs((fast.normals[used] * ref.normals[used]).sum(axis=1)), 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(fast.normals, axis=1), 1.0, rtol=0, atol=1e-12)


@needs_core
def test_recorded_submaps_agree(searches, use):
    """The submaps of every point-to-line match of the recorded runs (closures and local edges)."""
    for _, submap, _, p, _ in _MATCHES[::4]:
        assert_same_submaps(use, submap.points, p)


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_walls=st.integers(1, 8), n_points=st.integers(1, 2000),
       noise=st.sampled_from([0.0, 0.002, 0.02]), clutter=st.integers(0, 300), neighbours=st.integers(3, 12))
def test_generated_submaps_agree(use, seed, n_walls, n_points, noise, clutter, neighbours):
    """Walls (noisy or exact), clutter, and as few points as the neighbourhood or fewer."""
    rng = np.random.default_rng(seed)
    _, target = _scene(seed, n_walls, n_points, 1, (0.0, 0.0, 0.0))
    points = np.concatenate([target + rng.normal(0, noise, target.shape), rng.uniform(-6, 6, (clutter, 2))])
    assert_same_submaps(use, points, registration.LineICPParams(normal_neighbours=neighbours))


def test_closure_search_defaults_fit_the_compiled_limit():
    assert BackendParams().search.max_points <= corr.MAX_COMPILED_POINTS
