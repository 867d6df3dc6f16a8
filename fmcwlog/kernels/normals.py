"""Each point's line normal: a PCA of its nearest neighbours, and whether they lie on a line.

Frames and units: ``points`` (M, 2), m, in any frame; the normals are unit vectors in the same
frame, up to their sign (no use of a normal sees it: a residual ``n · e`` enters a least-squares
step squared, and its Jacobian row with it).

For every point: its ``k = min(neighbours, M)`` nearest points (itself among them; squared distances
``dx² + dy²``, equal ones by index), their mean and covariance (summed one neighbour at a time, nearest
first, divided by ``k``), and the covariance's eigenvalues ``λ_small ≤ λ_large``. The normal is the
eigenvector of ``λ_small``; the point is on a line ("planar") where
``λ_small ≤ min_planarity × max(λ_large, 1e-12 m²)`` and ``k ≥ 3``.

:func:`line_normals` runs the compiled kernel (``submap_normals``, ``src/core/submap.cpp``, which the
back end's submaps use too) where :func:`fmcwlog.kernels.compiled.core` selects it, else
:func:`line_normals_numpy`, the reference: the same neighbours in the same order and the same
arithmetic (LAPACK's ``dlaev2`` for the 2 × 2 eigenproblem, written out), so the two agree bit for bit
on finite points. The compiled robust ICP takes them from :func:`compiled_lines` instead, which computes
a point's normal only once the ICP pairs with it (a few hundred of a map's thousands of points: all
of them cost 1.2 ms a map state on the corridor log, half the front end's step where keyframes come
every other sweep); the numbers are the same.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING, cast

import numpy as np

from . import compiled

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree


def line_normals(points: np.ndarray, neighbours: int, min_planarity: float, tree: cKDTree | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (M, 2) and line flags (M,) of ``points`` (M, 2) (module docstring).

    ``neighbours`` ≥ 1; ``min_planarity`` the largest ratio of the small to the large eigenvalue
    that is a line (e.g. 1/9). ``tree``: the points' ``cKDTree`` where one is at hand (numpy only)."""
    if neighbours < 1:
        raise ValueError("line_normals: neighbours >= 1")
    points = np.ascontiguousarray(points, dtype=float)
    m = len(points)
    module = compiled.core()
    if module is None or m == 0:
        return line_normals_numpy(points, neighbours, min_planarity, tree)
    normals, flags = np.empty((m, 2)), np.empty(m, bool)
    module.submap_normals(points, int(neighbours), float(min_planarity), normals, flags)
    return normals, flags


def target_normals(tree: object, points: np.ndarray, neighbours: int, min_planarity: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`line_normals` of ``points``, kept by ``tree`` where it is their
    :class:`~fmcwlog.kernels.compiled.MapIndex` (computed once per map state), else computed now."""
    key = ("line_normals", int(neighbours), float(min_planarity))
    if isinstance(tree, compiled.MapIndex) and tree.points is points:
        found = tree.cache.get(key)
        if found is None:
            found = tree.cache[key] = line_normals(points, neighbours, min_planarity,
                                                   tree.tree if compiled.core() is None else None)
        return cast("tuple[np.ndarray, np.ndarray]", found)
    return line_normals(points, neighbours, min_planarity)


def compiled_lines(module: ModuleType, tree: object, points: np.ndarray, neighbours: int, min_planarity: float
                   ) -> object:
    """The compiled module's ``LineNormals`` of ``points`` (each point's normal computed when the robust
    ICP first pairs with it, then kept), kept by ``tree`` where it is their
    :class:`~fmcwlog.kernels.compiled.MapIndex` (one per map state), else made now."""
    key = ("compiled_lines", int(neighbours), float(min_planarity))
    if isinstance(tree, compiled.MapIndex) and tree.points is points:
        found = tree.cache.get(key)
        if found is None:
            found = tree.cache[key] = module.LineNormals(np.ascontiguousarray(points, dtype=float), int(neighbours),
                                                         float(min_planarity))
        return found
    return module.LineNormals(np.ascontiguousarray(points, dtype=float), int(neighbours), float(min_planarity))


def _neighbours(points: np.ndarray, k: int, tree: cKDTree | None) -> np.ndarray:
    """(M, k) indices of each point's ``k`` nearest points, nearest first, equal squared distances
    ``dx² + dy²`` by index (the compiled kernel's order)."""
    m = len(points)
    if tree is None:
        from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
        tree = cKDTree(points)
    ask = min(k + 1, m)
    _, idx = tree.query(points, k=ask)
    idx = np.asarray(idx).reshape(m, ask)
    d2 = _squared(points, idx)
    order = np.lexsort((idx, d2), axis=1)
    idx = np.take_along_axis(idx, order, axis=1)
    d2 = np.take_along_axis(d2, order, axis=1)
    if ask > k:  # a tie at the k-th place may reach beyond the tree's answer: all within that distance
        for q in np.flatnonzero(d2[:, k] <= d2[:, k - 1]):
            within = np.asarray(tree.query_ball_point(points[q], np.sqrt(d2[q, k - 1]) * (1 + 1e-9) + 1e-300))
            dq = _squared(points, within[None, :], points[q][None, :])[0]
            first = np.lexsort((within, dq))[:k]
            idx[q, :k] = within[first]
    return idx[:, :k]


def _squared(points: np.ndarray, idx: np.ndarray, at: np.ndarray | None = None) -> np.ndarray:
    """Squared distances ``dx² + dy²`` (the compiled kernel's arithmetic) from each row's point (or
    ``at``'s row) to the points ``idx`` (rows)."""
    at = points if at is None else at
    dx = points[idx, 0] - at[:, 0:1]
    dy = points[idx, 1] - at[:, 1:2]
    return dx * dx + dy * dy


def line_normals_numpy(points: np.ndarray, neighbours: int, min_planarity: float, tree: cKDTree | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`line_normals` in numpy: the reference the compiled kernel is tested against."""
    points = np.asarray(points, dtype=float)
    m = len(points)
    if m == 0:
        return np.empty((0, 2)), np.empty(0, bool)
    k = min(int(neighbours), m)
    idx = _neighbours(points, k, tree)
    nb = points[idx]  # (M, k, 2)
    sx, sy = nb[:, 0, 0].copy(), nb[:, 0, 1].copy()
    for i in range(1, k):
        sx += nb[:, i, 0]
        sy += nb[:, i, 1]
    mx, my = sx / k, sy / k
    cxx, cxy, cyy = np.zeros(m), np.zeros(m), np.zeros(m)
    for i in range(k):
        dx, dy = nb[:, i, 0] - mx, nb[:, i, 1] - my
        cxx += dx * dx
        cxy += dx * dy
        cyy += dy * dy
    cxx /= k
    cxy /= k
    cyy /= k
    small, large, nx, ny = _eigen_2x2(cxx, cxy, cyy)
    flags = (small <= min_planarity * np.maximum(large, 1e-12)) & (k >= 3)
    return np.stack([nx, ny], axis=1), flags


def _eigen_2x2(a: np.ndarray, b: np.ndarray, c: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """LAPACK's ``dlaev2`` on ``[[a, b], [b, c]]``, element-wise: the eigenvalues ascending and the unit
    eigenvector of the smaller (the compiled kernel's ``eigen_2x2``, branch for branch)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        sm, df = a + c, a - c
        adf, tb = np.abs(df), b + b
        ab = np.abs(tb)
        swap = np.abs(a) <= np.abs(c)
        acmx, acmn = np.where(swap, c, a), np.where(swap, a, c)
        q1 = ab / adf
        q2 = adf / ab
        rt = np.where(adf > ab, adf * np.sqrt(1.0 + q1 * q1),
                      np.where(adf < ab, ab * np.sqrt(1.0 + q2 * q2), ab * np.sqrt(2.0)))
        rt1 = np.where(sm < 0.0, 0.5 * (sm - rt), np.where(sm > 0.0, 0.5 * (sm + rt), 0.5 * rt))
        rt2 = np.where(sm != 0.0, (acmx / rt1) * acmn - (b / rt1) * b, -0.5 * rt)
        sgn1 = np.where(sm < 0.0, -1, 1)
        sgn2 = np.where(df >= 0.0, 1, -1)
        cs = np.where(df >= 0.0, df + rt, df - rt)
        ct = -tb / cs
        tn = -cs / tb
        sn_a = 1.0 / np.sqrt(1.0 + ct * ct)
        cs_c = 1.0 / np.sqrt(1.0 + tn * tn)
        big = np.abs(cs) > ab
        zero = ab == 0.0
        cs1 = np.where(big, ct * sn_a, np.where(zero, 1.0, cs_c))
        sn1 = np.where(big, sn_a, np.where(zero, 0.0, tn * cs_c))
        same = sgn1 == sgn2
        cs1, sn1 = np.where(same, -sn1, cs1), np.where(same, cs1, sn1)
    ordered = rt2 <= rt1
    return (np.where(ordered, rt2, rt1), np.where(ordered, rt1, rt2), np.where(ordered, -sn1, cs1),
            np.where(ordered, cs1, sn1))
