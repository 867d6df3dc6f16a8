"""The occupancy seen over the last stretch of path: what the tracker reads for free space.

Frames and units: the method's odometry frame (``map``), metres; path lengths in m.

The front end's occupancy grid holds every scan since the start, each drawn at the pose the
front end had then. Since the front end matches against its recent keyframes only
(:mod:`.keyframe_map`), its pose drifts against what it drew a lap ago: on the 2-minute corridor
with the LiDAR sideways the yaw between the two grows to 0.015-0.02 rad, which puts a wall 24 m
away 0.3-0.5 m into space the grid has seen free many times (log-odds at the clamp), and the
tracker's free-space detections (:mod:`.tracking`) would fire on those walls (705 static points
judged moving on that log with free space from the whole grid; docs/design/moving-points.md).

So the tracker reads free space from scans of the last stretch of path only, drawn at poses
consistent with the current one to the drift of that stretch: ``2`` grids, a new one begun every
``window / 2`` m of path (the older dropped); a cell's evidence is the sum of its log-odds in
both, i.e. that of the scans of the last ``window / 2`` to ``window`` m.

The scans are those the front end gives its own grid, handed over as the same
:class:`.occupancy.Scan` objects: each is ray-cast once for both (:mod:`.occupancy`); a second
cast of every scan for the recent grids would cost 0.37 s of a 6.9 s run on the 20 s crowd log.

The recent grids take every scan the front end's grid takes, one every ``grid_distance`` of path
(0.5 m): the cast is shared, so giving them fewer scans saves no casting, and it costs recall
(every third scan: dense-crowd's moving-point F1 0.9830 against 0.9876, 60 s, seed 0;
docs/design/moving-points.md).
"""

from __future__ import annotations

import numpy as np

from ..kernels import compiled
from ..kernels.occupancy import OccupancyGrid, OccupancyParams, Scan, lattice_cells


class RecentOccupancy:
    """Log-odds of the scans of the last ``window`` (m, > 0) of path, at ``resolution`` (m), in
    ``epochs`` (≥ 1) grids of ``window / epochs`` m each. Two by default: four (the evidence of
    the last 34-45 m instead of 22-45 m) give dense-crowd a recall of 0.9779 against 0.9834
    (free space at -1.2; docs/design/moving-points.md)."""

    def __init__(self, window: float, resolution: float, epochs: int = 2):
        self.window = window
        self.resolution = resolution
        self.epochs = epochs
        self.grids: list[OccupancyGrid] = []
        self._started: list[float] = []  # path length (m) at which each grid was begun

    def integrate(self, scan: Scan, path_m: float) -> None:
        """One scan (static points, ``map``), taken after ``path_m`` m of path (non-decreasing
        from call to call); its cast is shared with the other grids it is given to."""
        if not self.grids or path_m - self._started[-1] >= self.window / self.epochs:
            self.grids.append(OccupancyGrid(OccupancyParams(resolution=self.resolution)))
            self._started.append(path_m)
        # the newest grid, and those begun less than a window ago (at most ``epochs`` in all)
        keep = [i for i, s in enumerate(self._started) if path_m - s < self.window][-self.epochs:] or [-1]
        self.grids = [self.grids[i] for i in keep]
        self._started = [self._started[i] for i in keep]
        self.grids[-1].add(scan)

    def seen_free(self, map_xy: np.ndarray, candidates: np.ndarray, threshold: float) -> np.ndarray:
        """(N,) whether each of the ``candidates`` (N,) among points ``map_xy`` (N, 2) lies where the
        summed log-odds of its cell and of each of its 8 neighbours is at most ``threshold`` (cells
        never observed or outside a grid hold 0 there); False for the others.

        The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call, the
        same answers: the same float32 values summed in float64 in the grids' order), else
        :meth:`seen_free_numpy`."""
        core = compiled.core()
        if core is None or len(map_xy) == 0:
            return self.seen_free_numpy(map_xy, candidates, threshold)
        log_odds = [grid.log_odds for grid in self.grids]  # read first: it flushes each grid's queue
        out = np.zeros(len(map_xy), bool)
        core.occupancy_seen_free(
            log_odds, [grid.ix0 for grid in self.grids], [grid.iy0 for grid in self.grids],
            np.ascontiguousarray(map_xy, dtype=float), np.ascontiguousarray(candidates, dtype=bool), float(threshold),
            self.resolution, out)
        return out

    def seen_free_numpy(self, map_xy: np.ndarray, candidates: np.ndarray, threshold: float) -> np.ndarray:
        """:meth:`seen_free` in numpy: the reference the compiled kernel is tested against.

        The point's own cell is looked up first, for all at once, and the 8 neighbours only where it
        passed; each point's lattice cell is computed once for every grid and both lookups."""
        out = np.zeros(len(map_xy), bool)
        if len(map_xy) == 0:
            return out
        ix, iy = lattice_cells(map_xy, self.resolution)
        views = [_GridView(grid) for grid in self.grids]
        own = np.zeros(len(map_xy))
        for view in views:
            own += view.values(ix, iy)
        near = np.flatnonzero((own <= threshold) & candidates)
        around = np.zeros((near.size, len(_AROUND)))
        ix_near, iy_near = ix[near, None] + _AROUND[:, 1], iy[near, None] + _AROUND[:, 0]
        for view in views:
            around += view.values(ix_near, iy_near)
        out[near] = around.max(axis=1, initial=-np.inf) <= threshold
        return out


_AROUND = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])  # (rows, cols): a cell and its 8 neighbours


class _GridView:
    """A grid's log-odds as they stand (its queue cast, read once), looked up by lattice cell."""

    def __init__(self, grid: OccupancyGrid):
        log_odds = grid.log_odds  # read once: each property read flushes the grid's queue
        self.height, self.width = log_odds.shape
        self.flat = log_odds.reshape(-1)
        self.ix0, self.iy0 = grid.ix0, grid.iy0

    def values(self, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        """The log-odds (float32, ``ix``'s shape) of lattice cells ``(ix, iy)`` (int64); 0 outside the grid."""
        if self.width == 0:
            return np.zeros(ix.shape, np.float32)
        r = iy - self.iy0
        c = ix - self.ix0
        inside = (r.view(np.uint64) < self.height) & (c.view(np.uint64) < self.width)  # negatives wrap past
        r *= self.width
        r += c
        return np.where(inside, self.flat.take(r, mode="clip"), np.float32(0.0))


def local_max_log_odds(grid: OccupancyGrid, map_xy: np.ndarray) -> np.ndarray:
    """(N,) the largest log-odds (float32) of a point's cell in ``grid`` and its 8 neighbours (0 where
    never observed or outside the grid): ≥ a few hits is static structure mapped repeatedly. The
    compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call, the same
    values), else :func:`local_max_log_odds_numpy`."""
    core = compiled.core()
    if core is None or len(map_xy) == 0:
        return local_max_log_odds_numpy(grid, map_xy)
    log_odds = grid.log_odds  # read first: it flushes the grid's queue
    out = np.empty(len(map_xy), np.float32)
    core.occupancy_local_max(log_odds, grid.ix0, grid.iy0, np.ascontiguousarray(map_xy, dtype=float), grid.resolution, out)
    return out


def local_max_log_odds_numpy(grid: OccupancyGrid, map_xy: np.ndarray) -> np.ndarray:
    """:func:`local_max_log_odds` in numpy: the reference the compiled kernel is tested against."""
    if len(map_xy) == 0:
        return np.zeros(0)
    ix, iy = lattice_cells(map_xy, grid.resolution)
    return _GridView(grid).values(ix[:, None] + _AROUND[:, 1], iy[:, None] + _AROUND[:, 0]).max(axis=1)
