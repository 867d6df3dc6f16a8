"""The back end's nodes' points read one node at a time (:class:`~fmcwlog.backend.keyframes.NodePoints`):
the same points as the nodes hold, in memory or in the point store, and the same revisit distances."""

from __future__ import annotations

import numpy as np

from fmcwlog.backend.consistency import revisit_distances
from fmcwlog.backend.keyframes import Node, NodePoints
from fmcwlog.backend.point_store import PointStore


def _nodes(store: PointStore, k: int = 160, seed: int = 3) -> list[Node]:
    """``k`` nodes 0.5 m apart on a 20 m circle (two laps and a half), each seeing the same walls (half a circle 4 m across the centre, half 2 m)."""
    rng = np.random.default_rng(seed)
    walls = np.column_stack([np.cos(a := np.linspace(0, 2 * np.pi, 400, endpoint=False)),
                             np.sin(a)]) * np.array([[4.0], [2.0]]).repeat(200, 0)
    nodes = []
    for i in range(k):
        th = i * 0.5 / 3.2
        pose = np.array([3.2 * np.cos(th), 3.2 * np.sin(th), th + np.pi / 2])
        c, s = np.cos(pose[2]), np.sin(pose[2])
        local = (walls - pose[:2]) @ np.array([[c, -s], [s, c]])  # the walls in the node's frame
        pts = (local[rng.random(len(local)) < 0.5] + rng.normal(0, 0.01, (1, 2))).astype(np.float32)
        node = Node(i, 10**9 + i * 10**8, pose, pts, None, 0.5 * i)
        if i % 3:  # most in the store, some in memory, as the back end leaves them
            node.spill(store)
        nodes.append(node)
    return nodes


def test_node_points_are_the_nodes_points():
    store = PointStore()
    try:
        nodes = _nodes(store)
        lazy = NodePoints(nodes)
        assert len(lazy) == len(nodes)
        for i, node in enumerate(nodes):
            assert lazy[i].dtype == np.float32 and np.array_equal(lazy[i], node.points)
    finally:
        store.close()


def test_revisit_distances_from_node_points_are_those_from_a_list():
    store = PointStore()
    try:
        nodes = _nodes(store)
        front = np.array([n.frontend_pose for n in nodes])
        bent = front + np.column_stack([np.linspace(0, 0.3, len(nodes)), np.zeros(len(nodes)),
                                        np.linspace(0, 0.02, len(nodes))])
        path = np.array([n.path_m for n in nodes])
        whole = revisit_distances([n.points.copy() for n in nodes], path, front, bent)
        assert whole is not None and whole.queries > 10
        assert whole.optimised > whole.frontend  # the bent trajectory draws the revisited walls twice
        assert revisit_distances(NodePoints(nodes), path, front, bent) == whole
    finally:
        store.close()
