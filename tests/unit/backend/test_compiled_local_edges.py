"""The local edges in one compiled call a node (src/core/local_edges.cpp) against the numpy reference.

Each node's edges must come from the same earlier nodes, after the same ICP iterations, with the
same matches rejected for the same reasons; the relative poses and covariances agree to rounding.
Checked on the nodes both methods' back ends make processing the 30 s crowd log and on generated
paths through random walls (empty and sparse nodes, poses off by more than the gates, new pieces).
Where the module is not built the comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it.
"""

import dataclasses
import tempfile

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core, wall_scene
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.backend import local_edges
from fmcwlog.backend.keyframes import Node
from fmcwlog.backend.params import BackendParams


def _matched(use, kind, nodes, firsts, p):
    """Each node's edges (after the first) from a fresh matcher under the kernel ``kind``, the
    rejections, and the ICP iterations of every match that ran one (node order)."""
    use(kind)
    matcher = local_edges.LocalMatcher(p)
    iterations, register = [], local_edges.register_point_to_line

    def counted(*args, **kw):
        result = register(*args, **kw)
        iterations.append(result.iterations)
        return result

    local_edges.register_point_to_line = counted
    try:
        found = []
        for i in range(1, len(nodes)):
            found.append(matcher.edges(nodes[: i + 1], firsts[i]))
            if kind == "compiled":
                iterations += [k for k in matcher.iterations if k]
    finally:
        local_edges.register_point_to_line = register
    return found, matcher.rejected, iterations


def assert_same_edges(use, nodes, firsts=None, p=BackendParams()):
    firsts = firsts or [0] * len(nodes)
    ref, ref_rejected, ref_iterations = _matched(use, "numpy", nodes, firsts, p)
    fast, fast_rejected, fast_iterations = _matched(use, "compiled", nodes, firsts, p)
    assert fast_rejected == ref_rejected
    assert fast_iterations == ref_iterations
    for a, b in zip(fast, ref, strict=True):
        assert [(e.a, e.b) for e in a] == [(e.a, e.b) for e in b]
        for x, y in zip(a, b):
            np.testing.assert_allclose(x.relative, y.relative, rtol=0, atol=1e-9)
            np.testing.assert_allclose(x.covariance, y.covariance, rtol=0, atol=1e-9 * np.abs(y.covariance).max())
    return sum(len(a) for a in ref), ref_rejected


@pytest.fixture(scope="module")
def recorded_nodes():
    """The nodes both methods' back ends make processing the 30 s crowd log, as each reached the
    local matcher (points copied: a back end moves older nodes' points to a temporary file)."""
    from fmcwlog.api import ProcessOptions, process

    seen: dict[int, list] = {}
    edges = local_edges.LocalMatcher.edges

    def capture(self, nodes, first=0):
        kept = seen.setdefault(id(self), [])
        for n in nodes[len(kept):]:
            kept.append((Node(n.index, n.stamp_ns, n.frontend_pose.copy(), n.points.copy(), None, n.path_m), first))
        return edges(self, nodes, first)

    local_edges.LocalMatcher.edges = capture
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/crowd", ProcessOptions(), jobs=1)
    finally:
        local_edges.LocalMatcher.edges = edges
    return list(seen.values())


@needs_core
def test_recorded_local_edges_agree(recorded_nodes, use):
    assert len(recorded_nodes) == 2  # one matcher a method
    for kept in recorded_nodes:
        nodes, firsts = [n for n, _ in kept], [f for _, f in kept]
        count, _ = assert_same_edges(use, nodes, firsts)
        assert count > 1.5 * len(nodes)
        # a wider gate and fewer links: other matches pass and the submaps leave sooner
        wide = dataclasses.replace(BackendParams(), local_links=2, local_gate=0.5, local_gate_deg=10.0)
        assert_same_edges(use, nodes[:40], firsts[:40], wide)


def _path_nodes(seed, count, n_walls, n_points, step, noise, empty, sparse):
    """Nodes along a random path through random walls, each seeing the wall points within 7 m in
    its own frame (1 cm noise, float32); the front end's poses off the truth by ``noise`` (m, rad per
    step), node ``empty`` without points, node ``sparse`` with 5."""
    rng = np.random.default_rng(seed)
    _, walls = wall_scene(seed, n_walls, n_points, 1, (0.0, 0.0, 0.0), 0, extent=8.0)
    truth = np.cumsum(np.c_[rng.uniform(0, step, (count, 2)), rng.uniform(-0.2, 0.2, count)], axis=0)
    nodes = []
    for i, (x, y, th) in enumerate(truth):
        near = walls[np.hypot(walls[:, 0] - x, walls[:, 1] - y) < 7.0]
        c, s = np.cos(th), np.sin(th)
        local = (near - (x, y)) @ np.array([[c, -s], [s, c]]) + rng.normal(0, 0.01, near.shape)
        if i == empty:
            local = local[:0]
        elif i == sparse:
            local = local[:5]
        pose = truth[i] + rng.normal(0, noise, 3)
        nodes.append(Node(i, i, pose, np.ascontiguousarray(local, np.float32), None, float(i)))
    return nodes


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(2, 9), n_walls=st.integers(1, 8),
       n_points=st.integers(1, 1500), step=st.floats(0.0, 1.0), noise=st.sampled_from([0.0, 0.005, 0.05, 0.3]),
       empty=st.integers(-1, 8), sparse=st.integers(-1, 8), piece=st.integers(0, 8), links=st.integers(1, 5),
       voxel=st.sampled_from([0.02, 0.05, 0.1]), gate=st.sampled_from([0.02, 0.1, 1.0]))
def test_generated_local_edges_agree(use, seed, count, n_walls, n_points, step, noise, empty, sparse, piece, links,
                                     voxel, gate):
    nodes = _path_nodes(seed, count, n_walls, n_points, step, noise, empty, sparse)
    firsts = [0 if i < piece else piece for i in range(count)]  # a new piece from node ``piece`` on
    p = dataclasses.replace(BackendParams(), local_links=links, local_query_voxel=voxel, local_submap_voxel=voxel,
                            local_gate=gate)
    assert_same_edges(use, nodes, firsts, p)


@needs_core
def test_a_node_the_core_has_not_seen_is_added_from_its_points(use):
    """A matcher made after the nodes it matches against (the first node, or nodes matched under
    the reference before): their points are handed over, and the edges are the reference's."""
    nodes = _path_nodes(3, 6, 6, 1200, 0.5, 0.005, -1, -1)
    use("numpy")
    ref = local_edges.LocalMatcher(BackendParams()).edges(nodes)
    assert use("compiled") is not None
    matcher = local_edges.LocalMatcher(BackendParams())
    fast = matcher.edges(nodes)
    assert [(e.a, e.b) for e in fast] == [(e.a, e.b) for e in ref] and len(ref) == 4
    for x, y in zip(fast, ref):
        np.testing.assert_allclose(x.relative, y.relative, rtol=0, atol=1e-9)
    assert matcher._core.held == 5  # nodes 1-5: node 0 is past the four links of the next node
