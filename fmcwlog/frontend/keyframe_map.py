"""The local map scans are matched against: the recent keyframes, each placed by its own estimate.

Not the paper's (it does not say what the map is). A map that keeps the first point ever seen
in each voxel of the whole floor lets drift poison it: once the pose has drifted, a revisit is
matched against old, misplaced walls and the bad match adds drift (on the Intel log, 7 % of
the revisit matches went wrong against 2.6 % of first visits, and 5.6 % of all matches carried
90 % of the heading error). Here the map holds only the keyframes of the last
``window_distance`` metres of path (at most ``max_keyframes``), one point per voxel, the newest
keyframe's point where two fall in one voxel; older places are the back end's business (loop
closures). Its size is bounded by the window, not the floor, so the search structures rebuilt at
every keyframe stay small. They are built once per map state and only when asked for
(:class:`~fmcwlog.kernels.compiled.MapIndex`): the KD-tree where the numpy kernels query it, the
compiled kernels' grid where they run.

The map also gives, on demand, a likelihood grid of its points for the correlative search
(:mod:`.correlative`), built once per map state and only when a search is needed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..config import Checked, param
from ..kernels import compiled
from ..kernels.compiled import MapIndex
from ..kernels.correlative import CorrelativeParams, LikelihoodGrid, grid_for
from ..kernels.voxel import voxel_keys


@dataclass(frozen=True)
class LocalMapParams(Checked):
    """window_distance: keyframes more than this far back along the path leave the map (m, > 0).
    max_keyframes: at most this many keyframes (≥ 1), whatever the distance (turning on the spot).
    min_keyframes: at least this many stay (≥ 1), however far back (a long straight gap).
    max_twist_skew_deg: a sweep whose yaw rate changed since the last one by ``Δω`` is not a
        keyframe while ``|Δω| × (its duration)`` exceeds this (deg, ≥ 0): it straddles the start
        or end of a turn, its constant-twist deskew is wrong by about that much, and it would
        enter the map (and the back end) rotated. On the 200 s ring log, 12 such sweeps were
        0.6-2.3° off, each reverting at the next sweep. A log without per-point times (duration
        0) is never held back."""

    window_distance: float = param(10.0, "m", gt=0.0, le=1000.0)
    max_keyframes: int = param(60, "keyframes", ge=1, le=10_000)
    min_keyframes: int = param(3, "keyframes", ge=1, le=10_000)
    max_twist_skew_deg: float = param(0.5, "deg", ge=0.0, le=180.0)


@dataclass
class _Keyframe:
    ident: int
    path_m: float  # distance travelled when it was taken, m


@dataclass
class KeyframeMap:
    """Points (M, 2) in ``map`` of the recent keyframes, with their search index (a
    :class:`~fmcwlog.kernels.compiled.MapIndex`, which answers as their KD-tree; None while the
    map is empty; see module docstring)."""

    voxel_size: float = 0.05
    params: LocalMapParams = field(default_factory=LocalMapParams)
    points: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    tree: MapIndex | None = None
    _keys: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    _owner: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    _keyframes: deque = field(default_factory=deque)
    _next_id: int = 0
    _grids: dict[CorrelativeParams, tuple[int, LikelihoodGrid]] = field(default_factory=dict)

    def add(self, xy: np.ndarray, path_m: float) -> None:
        """A keyframe's points (N, 2) in ``map``, taken after ``path_m`` metres of travel; the
        keyframes that leave the window go, and the search index is renewed."""
        ident = self._next_id
        self._next_id += 1
        self._keyframes.append(_Keyframe(ident, path_m))
        p = self.params
        while len(self._keyframes) > max(p.min_keyframes, 1) and (
                len(self._keyframes) > p.max_keyframes or path_m - self._keyframes[0].path_m > p.window_distance):
            self._keyframes.popleft()
        oldest = self._keyframes[0].ident
        core = compiled.core()
        merged = None
        if core is not None and type(xy) is np.ndarray and xy.dtype == np.float64 and xy.shape[1:] == (2,):
            merged = core.keyframe_map_merge(np.ascontiguousarray(xy), float(self.voxel_size), self._keys,
                                             self.points, self._owner, oldest, ident)
        self._keys, self.points, self._owner = merged or self._merge_numpy(xy, oldest, ident)
        # An unbalanced, uncompacted tree builds about twice as fast and answers the ICP's
        # queries as fast (measured on 20k wall points); it is rebuilt at every keyframe.
        self.tree = MapIndex(self.points, balanced_tree=False, compact_nodes=False) if len(self.points) else None

    def _merge_numpy(self, xy: np.ndarray, oldest: int, ident: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The map's keys, points and owners once keyframe ``ident``'s points ``xy`` (N, 2) join it
        and those of keyframes before ``oldest`` leave: sorted by voxel key, one point per voxel,
        the newest keyframe's. The reference the compiled kernel (``keyframe_map_merge``, one call,
        the same arrays) is tested against."""
        keep = self._owner >= oldest
        new_keys = voxel_keys(xy, self.voxel_size) if len(xy) else np.empty(0, np.int64)
        keys = np.concatenate([new_keys, self._keys[keep]])
        points = np.concatenate([xy, self.points[keep]])
        owner = np.concatenate([np.full(len(xy), ident), self._owner[keep]])
        keys, first = np.unique(keys, return_index=True)  # the first occurrence: the newest keyframe's point
        return keys, points[first], owner[first]

    def likelihood_grid(self, p: CorrelativeParams, keyframes_old: int = 0) -> LikelihoodGrid:
        """The likelihood grid of the map's points for a correlative search with ``p``, cached per
        ``p`` until more than ``keyframes_old`` keyframes have entered the map since it was built
        (0: until the map changes)."""
        found = self._grids.get(p)
        if found is None or self._next_id - found[0] > keyframes_old:
            found = self._grids[p] = (self._next_id, grid_for(self.points, p))
        return found[1]

    @property
    def keyframes(self) -> int:
        return len(self._keyframes)

    def __len__(self) -> int:
        return len(self.points)
