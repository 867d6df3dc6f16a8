"""The back end's nearest-point look-ups on the compiled grid against their KD-tree reference, and the
graph's estimates read in one call against the per-node reads.

The closure's inlier fraction and the revisit distances must be the same floats with the compiled
core selected as without it (the grid finds the same nearest distance under the same strict bound).
Where the module is not built the comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it.
"""

import numpy as np
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_consistency import SCENE, _drifted, _loop, _points

from fmcwlog.backend import consistency, verification
from fmcwlog.backend.graph import Edge, PoseGraph
from fmcwlog.backend.registration import LineICPParams, build_submap, register_point_to_line


@needs_core
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31), bound=st.sampled_from([0.02, 0.1, 0.3, 0.5]),
       shift=st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.2, 0.2)))
def test_inlier_fraction_is_the_kd_trees(use, seed, bound, shift):
    rng = np.random.default_rng(seed)
    target = SCENE[rng.choice(len(SCENE), 600, replace=False)] + rng.normal(0, 0.01, (600, 2))
    query = target[rng.choice(600, 300, replace=False)] + rng.normal(0, 0.02, (300, 2))
    pose = np.array(shift)
    use("numpy")
    ref = verification.inlier_fraction(query, build_submap(target), pose, bound)
    assert use("compiled") is not None
    sub = build_submap(target)
    register_point_to_line(query, sub, pose, LineICPParams())  # leaves the ICP's 0.3 m grid in sub.grids
    assert verification.inlier_fraction(query, sub, pose, bound) == ref
    assert 0.0 <= ref <= 1.0  # a shift of up to 0.42 m can leave no query point within 0.1 m


@needs_core
def test_revisit_distances_are_the_kd_trees(use):
    truth = _loop(laps=1.2)
    path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))])
    points = _points(truth, np.random.default_rng(1))
    front = _drifted(truth, np.radians(0.1))
    use("numpy")
    ref = consistency.revisit_distances(points, path, front, truth)
    assert use("compiled") is not None
    assert consistency.revisit_distances(points, path, front, truth) == ref
    assert ref is not None and ref.points > 0


def test_estimates_in_one_call_are_the_per_node_reads():
    g = PoseGraph()
    rng = np.random.default_rng(2)
    for i in range(30):
        g.add_node(np.array([0.5 * i, 0.1 * rng.normal(), 3.0 * rng.uniform(-1, 1)]))
        if i:
            g.add_odometry(Edge(i - 1, i, np.array([0.5, 0.0, 0.01]), np.diag([1e-4, 1e-4, 1e-5])))
    g.add_closure(Edge(0, 29, np.array([14.0, 0.5, 0.2]), np.diag([1e-2, 1e-2, 1e-3])))
    g.optimize()
    np.testing.assert_array_equal(g.estimates(), np.array([g.estimate(i) for i in range(30)]))
