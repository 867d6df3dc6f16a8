"""A keyframe with no static points (every point of its sweep on a mover, or dropped as a
no-return) gives no local edge, counted as ``empty``, and the nodes around it still match."""

from __future__ import annotations

import numpy as np

from fmcwlog.backend.keyframes import Node
from fmcwlog.backend.local_edges import LocalMatcher
from fmcwlog.backend.params import BackendParams


def _wall_points(rng: np.random.Generator) -> np.ndarray:
    """Two corridor walls and an end wall, seen from the origin (m, base_link), float32 as a node holds them."""
    x = rng.uniform(-5.0, 5.0, 400)
    walls = [np.column_stack([x, np.full_like(x, side)]) for side in (-1.5, 1.5)]
    y = rng.uniform(-1.5, 1.5, 100)
    walls.append(np.column_stack([np.full_like(y, 5.0), y]))
    return np.concatenate(walls).astype(np.float32)


def test_a_node_without_points_gives_no_edge_and_no_error():
    rng = np.random.default_rng(3)
    empty = np.zeros((0, 2), np.float32)
    nodes = [Node(0, 0, np.zeros(3), _wall_points(rng), None, 0.0),
             Node(1, 1, np.zeros(3), empty, None, 0.0),
             Node(2, 2, np.zeros(3), _wall_points(rng), None, 0.0)]
    matcher = LocalMatcher(BackendParams())
    assert matcher.edges(nodes[:2]) == []  # the empty node as the query
    edges = matcher.edges(nodes[:3])  # and as the submap: the node before it still matches
    assert [(e.a, e.b) for e in edges] == [(0, 2)]
    assert matcher.rejected == {"empty": 2}
