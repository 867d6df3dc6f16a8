"""The compiled point-to-line ICP's pairing from the submap's neighbour table against the grid's.

The table (``Submap.near``, ``Submap.reach``, built with the normals) lets the compiled ICP keep a
source point's pair between passes and ask the grid only where the table cannot tell; the answers
must be those of the grid asked every pass, bit for bit: the same pairs, iterations, poses,
information and residuals. Scenes: walls, clutter, points on a coarse lattice (equal distances),
duplicated points, fewer points than a neighbourhood, and starts off by up to a metre.
"""

import numpy as np
import pytest
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.backend import registration
from fmcwlog.kernels import compiled


@pytest.fixture
def core(monkeypatch):
    monkeypatch.setenv(compiled.ENV, "compiled")
    monkeypatch.setattr(compiled, "_chosen", None)
    monkeypatch.setattr(compiled, "_core", None)
    return compiled.core()


def _run(module, sub, source, start, p, table, prior=None):
    grid = module.TargetGrid(np.ascontiguousarray(sub.points, float), p.max_distance)
    held = (None, None) if prior is None else (list(prior[0]), list(np.ravel(prior[1])))
    near, reach = (sub.near, sub.reach) if table else (None, None)
    return module.line_icp(grid, sub.normals, sub.has_normal, np.ascontiguousarray(source, float), *map(float, start),
                           p.max_iterations, p.kernel_scale, p.tolerance, *held, near, reach)


def assert_same_with_table(module, target, source, start, p, prior=None):
    sub = registration.build_submap(target, p)
    assert sub.near is not None and sub.reach is not None
    a = _run(module, sub, source, start, p, table=True, prior=prior)
    b = _run(module, sub, source, start, p, table=False, prior=prior)
    assert a[3:] == b[3:]  # pairs, iterations, converged
    assert np.array(a[0]).tobytes() == np.array(b[0]).tobytes()
    assert np.array(a[1]).tobytes() == np.array(b[1]).tobytes()
    assert np.array(a[2]).tobytes() == np.array(b[2]).tobytes()


def _scene(rng, n_walls, n_points, clutter, lattice, duplicates):
    ends = rng.uniform(-4, 4, (n_walls, 4))
    t = rng.random(n_points)
    seg = rng.integers(0, n_walls, n_points)
    target = ends[seg, :2] + t[:, None] * (ends[seg, 2:] - ends[seg, :2])
    target = np.concatenate([target, rng.uniform(-4, 4, (clutter, 2))])
    if lattice:
        target = np.round(target / lattice) * lattice
    if duplicates:
        target = np.concatenate([target, target[rng.integers(0, len(target), duplicates)]])
    return target


@needs_core
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_walls=st.integers(1, 6), n_points=st.integers(1, 800),
       clutter=st.integers(0, 100), lattice=st.sampled_from([0.0, 0.05, 0.1]), duplicates=st.integers(0, 20),
       neighbours=st.integers(3, 10), gate=st.sampled_from([0.05, 0.3, 1.0]), off=st.floats(0.0, 1.0),
       noise=st.sampled_from([0.0, 0.01, 0.05]))
def test_generated_matches_pair_as_the_grid(core, seed, n_walls, n_points, clutter, lattice, duplicates, neighbours,
                                            gate, off, noise):
    rng = np.random.default_rng(seed)
    target = _scene(rng, n_walls, n_points, clutter, lattice, duplicates)
    source = target[rng.choice(len(target), min(len(target), 400), replace=False)] + rng.normal(0, noise, (min(len(target), 400), 2))
    if lattice and noise == 0.0:
        source = np.round(source / lattice) * lattice  # equal distances to several targets
    start = rng.normal(0, off, 3) * (1.0, 1.0, 0.3)
    p = registration.LineICPParams(max_distance=gate, normal_neighbours=neighbours, max_iterations=30)
    assert_same_with_table(core, target, source, start, p)


@needs_core
def test_a_held_match_pairs_as_the_grid(core):
    rng = np.random.default_rng(3)
    target = _scene(rng, 4, 600, 30, 0.0, 0)
    source = target[::2] + rng.normal(0, 0.01, (len(target[::2]), 2))
    prior = (np.array([0.05, -0.02, 0.01]), np.diag([50.0, 50.0, 10.0]))
    assert_same_with_table(core, target, source, (0.1, -0.1, 0.05), registration.LineICPParams(), prior)


@needs_core
def test_fewer_points_than_a_neighbourhood(core):
    target = np.array([[0.0, 0.0], [0.05, 0.0], [0.1, 0.0], [0.1, 0.0]])
    source = np.array([[0.02, 0.01], [0.07, -0.01], [0.11, 0.0], [5.0, 5.0]])
    assert_same_with_table(core, target, source, (0.01, 0.0, 0.0), registration.LineICPParams())


@needs_core
def test_a_bad_table_is_refused(core):
    target = _scene(np.random.default_rng(0), 2, 50, 0, 0.0, 0)
    sub = registration.build_submap(target)
    sub.near[0, 1] = len(target)
    with pytest.raises(ValueError):
        _run(core, sub, target, (0.0, 0.0, 0.0), registration.LineICPParams(), table=True)
