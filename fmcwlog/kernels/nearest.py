"""Nearest-neighbour pairs between a source and a target point set, under successive poses.

Frames and units: ``source_xy`` (N, 2) in the source frame (m), ``target_xy`` (M, 2) in the target
frame (m), a pose ``(x, y, θ)`` maps source into target (``q ≈ R(θ) p + t``,
:func:`fmcwlog.geometry.transform_points`). The caller builds the target's ``cKDTree`` once and
passes it in.

:func:`find_correspondences` is one KD-tree query: each moved source point's nearest target point
within the gate. :class:`NearestPairs` gives exactly the same pairs at every pose of an iterative
registration while asking the tree far less: once per registration it keeps each point's
``CANDIDATES`` nearest target points (within the gate plus ``QUERY_MARGIN``; the last at distance
``reach``), and later iterations take the closest candidate by direct arithmetic. By the triangle
inequality a point that has moved ``s`` since it was asked has no other target point nearer than
``reach - s``, so the candidate is exact while closer than that, and no pair exists while that
exceeds the gate; only the points failing both are asked again (0-2 % of them an iteration).
Both ICP variants (:mod:`fmcwlog.frontend.icp`) and the back end's registration use it. The
measurements behind this design are in ``docs/design/nearest-pairs.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..geometry import transform_points

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree


@dataclass
class Correspondences:
    """Nearest-neighbour pairs within the distance gate.

    source_idx (K,): indices into ``source_xy``; moved (K, 2): those points in
    the target frame under the current pose; target (K, 2): their nearest target
    points; distances (K,): ``‖moved - target‖`` (m); target_idx (K,): the target points'
    indices into ``target_xy``.
    """

    source_idx: np.ndarray
    moved: np.ndarray
    target: np.ndarray
    distances: np.ndarray
    target_idx: np.ndarray


def find_correspondences(
    source_xy: np.ndarray,
    pose: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    max_distance: float,
    workers: int = 1,
) -> Correspondences:
    """Transform the source by ``pose`` and pair each point with its nearest target point.

    Pairs farther than ``max_distance`` (m) are dropped (the tree's
    ``distance_upper_bound`` prunes the search itself).
    """
    moved = transform_points(pose, source_xy)
    dist, idx = target_tree.query(
        moved, k=1, distance_upper_bound=max_distance, workers=workers
    )
    ok = np.isfinite(dist)
    src = np.flatnonzero(ok)
    near = idx[ok]
    return Correspondences(src, moved[ok], target_xy[near], dist[ok], near)


QUERY_MARGIN = 0.1  # m beyond the gate the tree is asked about: a point moves this far before its "none" expires
CANDIDATES = 6  # nearest map points kept per source point (module docstring: 4 gave the baseline -18 %, 6 -27 %)


class NearestPairs:
    """The nearest target point of every source point under successive poses (module docstring).

    ``source_xy`` (N, 2) in the source frame, ``target_tree`` over ``target_xy`` (M, 2);
    :meth:`pairs` answers as :func:`find_correspondences` would for the same pose, querying
    the tree only for the points whose answer may lie outside their stored candidates.

    Layout, for few numpy calls an iteration (each costs ~1 µs; the arrays are ~300-1000 points):
    the candidates' coordinates as one (N, CANDIDATES, 2) array, so that the distances of all
    of them are three calls; the answer kept as a flat index into it (row × CANDIDATES + column),
    which gives a pair's target point by one ``take`` and its map index by another.
    """

    def __init__(self, source_xy: np.ndarray, target_tree: cKDTree, target_xy: np.ndarray,
                 max_distance: float, workers: int = 1):
        self.source = source_xy
        self.tree = target_tree
        self.target = target_xy
        self.gate = max_distance
        self.bound = max_distance + QUERY_MARGIN
        self.workers = workers
        self._padded = np.vstack([target_xy, [np.inf, np.inf]])  # the tree's "none" index is M: infinitely far
        n = len(source_xy)
        self._at = np.empty((n, 2))  # where each point was when the tree was last asked (target frame)
        self._candidates = np.empty((n, CANDIDATES), np.int64)  # its nearest target indices then
        self._xy = np.empty((n, CANDIDATES, 2))  # and their coordinates, one candidate a row
        self._flat_xy = self._xy.reshape(n * CANDIDATES, 2)  # a view
        self._by_axis = np.empty((2, CANDIDATES, n))  # the same coordinates as x and y planes (fast broadcasts)
        self._d2 = np.empty((n, CANDIDATES))  # squared distances to them, filled each iteration
        self._first = np.arange(n) * CANDIDATES  # flat index of each point's first (nearest when asked)
        self._swapped = source_xy[:, ::-1].copy()  # (y, x) of each source point: the rotation in 3 calls
        self._reach = np.zeros(n)  # every other target point was at least this far from it then, m
        self._asked = False

    def _ask(self, moved: np.ndarray, which: np.ndarray | slice) -> np.ndarray:
        """Query the tree for ``moved[which]``, store the answers and return the nearest's distance
        (the tree's own ``√((Δx)² + (Δy)²)``, the arithmetic of :meth:`_closest`)."""
        pts = moved[which]
        d, idx = self.tree.query(pts, k=CANDIDATES, distance_upper_bound=self.bound, workers=self.workers)
        self._at[which], self._candidates[which] = pts, idx
        self._xy[which] = q = self._padded[idx]
        self._by_axis[:, :, which] = q.T
        self._reach[which] = np.minimum(d[:, -1], self.bound) - 1e-9  # less the distances' rounding
        return d[:, 0]

    def _closest(self, moved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For every moved point: the flat index of its closest stored candidate and its distance."""
        diff = self._by_axis - moved.T[:, None, :]
        diff *= diff
        d2 = self._d2
        np.add(diff[0], diff[1], out=d2.T)  # the tree's own arithmetic: (Δx)² + (Δy)², then the root
        flat = d2.argmin(axis=1)
        flat += self._first
        return flat, np.sqrt(d2.take(flat))

    def _moved(self, pose: np.ndarray) -> np.ndarray:
        """The source (N, 2) under ``pose``: :func:`~fmcwlog.geometry.transform_points`, the same
        operations in the same order (``c x - s y + t_x``, ``s x + c y + t_y``), in three calls."""
        pose = np.asarray(pose, dtype=float)
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        moved = self.source * c
        moved += self._swapped * np.array((-s, s))  # -(s y) = (-s) y exactly; the sums commute exactly
        moved += pose[:2]
        return moved

    def _search(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Under ``pose``: the moved source (N, 2), each point's answer as a flat candidate index
        (N,) and its distance (N,), above the gate (possibly inf) where no target point is within it."""
        moved = self._moved(pose)
        if not self._asked:
            self._asked = True
            return moved, self._first.copy(), self._ask(moved, slice(None))
        flat, dist = self._closest(moved)
        # a target point outside the candidates was at least ``reach`` from the point's anchor, so
        # at least ``limit = reach - s`` from it now (moved by s): the candidate wins while closer
        # than that, and nothing is within the gate while that exceeds the gate; both fail where
        # limit <= min(distance, gate)
        shift = moved - self._at
        shift *= shift
        limit = self._reach - np.sqrt(shift[:, 0] + shift[:, 1])
        unsure = np.flatnonzero(limit <= np.minimum(dist, self.gate))
        if unsure.size:
            dist[unsure] = self._ask(moved, unsure)
            flat[unsure] = self._first[unsure]
        return moved, flat, dist

    def nearest(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Under ``pose``: the moved source (N, 2), each point's nearest target index (N,) and its
        distance (N,); where no target point is within the gate, the distance is above the gate
        (possibly inf) and the index is not to be used."""
        moved, flat, dist = self._search(pose)
        return moved, self._candidates.take(flat), dist

    def pairs(self, pose: np.ndarray) -> Correspondences:
        """The pairs within the gate under ``pose``, as :func:`find_correspondences` gives them."""
        moved, flat, dist = self._search(pose)
        src = np.flatnonzero(dist < self.gate)
        at = flat.take(src)
        return Correspondences(src, moved.take(src, axis=0), self._flat_xy.take(at, axis=0), dist.take(src),
                               self._candidates.take(at))
