"""The map scans are matched against: a voxel grid of points in ``map``, with its KD-tree.

Points are kept one per voxel (the first to arrive), so the map's size grows
with the area seen, not with the length of the log. The KD-tree is rebuilt
only when points are added, i.e. once per keyframe, never per ICP iteration.
For an indoor floor the whole map within sensor range is the "local map";
when the robot comes back to a place it is matched against what it built
there before, which bounds the drift of a loop without a back end.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree


def voxel_keys(xy: np.ndarray, size: float) -> np.ndarray:
    """One int64 key per point naming its square voxel of side ``size`` (m)."""
    ij = np.floor(xy / size).astype(np.int64)
    return (ij[:, 0] << 32) ^ (ij[:, 1] & 0xFFFFFFFF)


def voxel_downsample(xy: np.ndarray, size: float) -> np.ndarray:
    """The first point (in order) of each occupied voxel; (M, 2) with M <= N."""
    if len(xy) == 0 or size <= 0:
        return xy
    _, first = np.unique(voxel_keys(xy, size), return_index=True)
    return xy[np.sort(first)]


@dataclass
class VoxelMap:
    voxel_size: float = 0.05  # m
    points: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    _keys: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    tree: cKDTree | None = None

    def add(self, xy: np.ndarray) -> int:
        """Add points (M, 2) in ``map``; only those falling in empty voxels are kept.
        Rebuilds the KD-tree; returns how many points were added."""
        if len(xy) == 0:
            return 0
        keys = voxel_keys(xy, self.voxel_size)
        keys, first = np.unique(keys, return_index=True)
        # the map's keys are kept sorted: a binary search per new key instead of sorting the map's
        # keys with them (np.isin) at every keyframe
        at = np.searchsorted(self._keys, keys)
        new = self._keys.take(at, mode="clip") != keys if len(self._keys) else np.ones(len(keys), bool)
        if not new.any():
            return 0
        self.points = np.concatenate([self.points, xy[first[new]]])
        self._keys = np.insert(self._keys, at[new], keys[new])
        # An unbalanced, uncompacted tree builds in 2.6 ms instead of 4.7 ms for 20k wall points
        # and answers the ICP's queries as fast (0.19 vs 0.20 ms for 500 points): it is rebuilt
        # at every keyframe, queried ~5 times per sweep.
        self.tree = cKDTree(self.points, balanced_tree=False, compact_nodes=False)
        return int(new.sum())

    def __len__(self) -> int:
        return len(self.points)
