"""Whether the optimised trajectory draws a more consistent map than the front end's, without ground truth.

Loop closures correct drift only if they are right: one wrong closure (a corridor taken for
the one beside it, a crowd taken for a wall) bends the whole graph, and the optimised
trajectory is then worse than the front end's own. Nothing in the graph says so: the
closure's residual is small at an optimum that obeys it.

What a wrong bend does show is the map: a place seen twice, placed twice by a trajectory,
should be drawn once. For a trajectory, each of a subsample of nodes (the *queries*) has its
points placed by it and compared with the map the same trajectory draws from the nodes at
least ``GAP_M`` metres of path before it (so that only a revisit counts, never the few nodes
just before, which every trajectory places alike; the map is extended every few metres, so some
queries compare with nodes a little farther back): the distance of each point to the nearest
point of that map, capped at ``CAP_M``. Over the points that land within ``CAP_M`` of the earlier
map under either trajectory (a revisit for one or the other), the mean capped distance is the
trajectory's *revisit distance*. Where a drifted loop is closed right, the optimised
trajectory's is smaller (the walls drawn once); where a closure bent it wrongly, larger.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry import transform_points
from ..kernels import compiled
from ..kernels.voxel import voxel_downsample

GAP_M = 15.0  # m of path: the earlier map holds nodes at least this far back (as closures' candidates are)
CAP_M = 0.5  # m: a point's distance counts up to this; one farther sees a place the earlier map does not hold
MAX_QUERIES = 120  # nodes compared, evenly spread over those with an earlier map
QUERY_VOXEL = 0.1  # m: a query's points thinned to this
MAP_VOXEL = 0.1  # m: and each node's points in the earlier maps
REBUILD_NODES = 10  # the earlier map is extended once this many nodes have joined it (a node every 0.5 m)
WORSE_RATIO = 1.05  # the optimised trajectory is worse where its revisit distance exceeds the front end's by 5 %...
WORSE_BY_M = 0.002  # ...and by 2 mm


@dataclass(frozen=True)
class RevisitDistances:
    """The revisit distances (m) of the front end's trajectory and the optimised one, over the same
    ``points`` (query points that land on an earlier map under either), and the ``queries`` (nodes) used."""

    frontend: float
    optimised: float
    points: int
    queries: int


def revisit_distances(points: Sequence[np.ndarray], path_m: np.ndarray, frontend: np.ndarray,
                      optimised: np.ndarray) -> RevisitDistances | None:
    """The revisit distances of two trajectories of the same nodes (module docstring).

    ``points``: each node's points (N_i, 2) in base_link (m); ``path_m`` (K,): the path travelled at
    each node (m, non-decreasing); ``frontend``, ``optimised`` (K, 3): each node's pose (m, m, rad)
    under the two trajectories. None when no node has an earlier map or no point lands on one.
    """
    path_m = np.asarray(path_m, float)
    # node i's earlier map: the nodes 0 .. prefix[i] - 1, all at least GAP_M of path before it
    prefix = np.searchsorted(path_m, path_m - GAP_M, side="right")
    candidates = np.flatnonzero(prefix > 0)
    if candidates.size == 0:
        return None
    queries = candidates[np.unique(np.linspace(0, candidates.size - 1, min(MAX_QUERIES, candidates.size)).astype(int))]
    # both trajectories in one pass: each node's points are read (a node's may come back from the
    # back end's point store) and thinned once, where both earlier maps take them, and none is kept after
    trajectories = (frontend, optimised)
    distances: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
    earlier = [np.empty((0, 2)), np.empty((0, 2))]
    nearest: list[_Nearest] = []
    in_tree = 0
    for q in queries:
        n = int(prefix[q])
        if not nearest or n >= in_tree + REBUILD_NODES:  # the earlier maps grown by a few metres
            added = [voxel_downsample(np.asarray(points[i], float), MAP_VOXEL) for i in range(in_tree, n)]
            earlier = [voxel_downsample(np.concatenate([e, *(transform_points(poses[i], a) for i, a in
                                                                zip(range(in_tree, n), added))]), MAP_VOXEL)
                       for e, poses in zip(earlier, trajectories)]
            nearest, in_tree = [_Nearest(e) for e in earlier], n
        mine = voxel_downsample(np.asarray(points[q], float), QUERY_VOXEL)
        for d, near, poses in zip(distances, nearest, trajectories):
            d.append(np.minimum(near.distances(poses[q], mine), CAP_M))
    per_trajectory = [np.concatenate(d) if d else np.empty(0) for d in distances]
    d_front, d_opt = per_trajectory
    revisit = (d_front < CAP_M) | (d_opt < CAP_M)
    if not revisit.any():
        return None
    return RevisitDistances(float(d_front[revisit].mean()), float(d_opt[revisit].mean()), int(revisit.sum()),
                            int(len(queries)))


class _Nearest:
    """Each point's distance (m) to the nearest point of a map (M, 2), inf where none is closer than
    ``CAP_M``: the compiled core's grid over the map where it is selected, else a KD-tree (the same
    distances: the root of the same sum of squares, the same strict bound)."""

    def __init__(self, map_xy: np.ndarray):
        self._module = compiled.core()
        if self._module is not None:
            self._grid = self._module.TargetGrid(np.ascontiguousarray(map_xy, float), CAP_M)
        else:
            from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports

            self._tree = cKDTree(map_xy, balanced_tree=False, compact_nodes=False)

    def distances(self, pose: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(N,) for the points ``xy`` (N, 2) of a frame at ``pose`` (3,) in the map's frame."""
        if self._module is None:
            d, _ = self._tree.query(transform_points(pose, xy), k=1, distance_upper_bound=CAP_M)
            return d
        n = len(xy)
        moved, index, dist = np.empty((n, 2)), np.empty(n, np.int64), np.empty(n)
        x, y, th = np.asarray(pose, float).tolist()
        self._module.nearest(self._grid, np.ascontiguousarray(xy, float), x, y, th, moved, index, dist)
        return dist


def worse(r: RevisitDistances) -> bool:
    """Whether the optimised trajectory draws revisited places clearly worse than the front end's."""
    return r.optimised > r.frontend * WORSE_RATIO and r.optimised - r.frontend > WORSE_BY_M
