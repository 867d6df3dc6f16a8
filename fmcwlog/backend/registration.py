"""Point-to-line ICP of a keyframe against a submap, with the information matrix of the match.

The back end's own registration, the same for both methods (the comparison stays fair).
Point-to-line rather than the front ends' point-to-point: a loop closure matches sparse scans
taken from another place, whose points do not fall on each other, and its information must
show which directions the scene leaves free (along a corridor: none of the normals points
there, so ``H`` has a zero eigenvalue in that direction, which point-to-point pairs hide).

Frames and units as in :mod:`fmcwlog.frontend.icp`: ``source_xy`` (N, 2) in the source frame,
the submap (M, 2) with unit normals (M, 2) in the target frame, poses map source into target.
Residual ``r = nᵀ(R p + t - q)`` (m); Jacobian ``[n_x, n_y, nᵀ R' p]`` with ``R' p = (-(Rp)_y, (Rp)_x)``;
Cauchy weights ``1 / (1 + (r/c)²)``.

Cost: the pairing uses the shared :class:`~fmcwlog.kernels.nearest.NearestPairs`, which
keeps each point's 6 nearest targets and asks the tree again only for points that moved too far
for them to still hold the nearest (exact); a KD-tree query of every point would take about
170 µs of each 250-300 µs iteration (some 480 source points). Each pass computes the residuals
and Jacobian once, gathers a pair's target point and normal in one ``take`` from an (M, 4) array,
and calls LAPACK's ``gesv`` directly (the routine ``np.linalg.solve`` calls, without about 17 µs
of checks in its wrapper); each submap's PCA is summed one neighbour at a time. On the 120 s
corridor's back ends (``fmcwlog run``) the 1,639 registrations take 3.15 s CPU; what each of
these steps saves is measured in docs/design/speed-experiments.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..config import Checked, param
from ..geometry import wrap_angle
from ..kernels import compiled
from ..kernels.nearest import NearestPairs
from ..kernels.normals import line_normals_numpy

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree


@dataclass(frozen=True)
class LineICPParams(Checked):
    """max_iterations: iteration cap.
    max_distance: pairs farther apart than this are dropped (m; the search before has put the
        source within about one grid cell).
    kernel_scale: Cauchy scale ``c`` of the residuals (m).
    normal_neighbours: target points in the PCA that gives each normal (≥ 3).
    min_planarity: a target neighbourhood whose smaller/larger eigenvalue ratio exceeds this is
        not a line (a corner, clutter) and gives no pair (0-1).
    tolerance: stop when a step moves less than this (m, and rad × 1 m).
    """

    max_iterations: int = param(20, "", ge=1, le=1000)
    max_distance: float = param(0.3, "m", gt=0.0, le=10.0)
    kernel_scale: float = param(0.05, "m", gt=0.0, le=10.0)
    normal_neighbours: int = param(6, "points", ge=3, le=100)
    min_planarity: float = param(0.1, "", ge=0.0, le=1.0)
    tolerance: float = param(1e-4, "m", gt=0.0, le=1.0)


@dataclass
class Submap:
    """Target points (M, 2), their unit normals (M, 2), which have one (M,), and the KD-tree (built
    on first use where the compiled core built the normals without it).

    ``near`` (M, k) int32 and ``reach`` (M, k + 1), m: each point's ``k`` nearest points (itself among
    them, nearest first; -1 past M) and distances that every point but the first ``j`` of its row lies
    at or beyond; built with the normals by the compiled core (None otherwise), they let its pairing
    answer most passes without a grid query (``src/core/line_icp.cpp``).

    ``paired`` (M + 1,): ``has_normal`` with a last ``False`` for the index ``M`` that the tree
    returns where no point lies within the search's bound, so one lookup says which source points
    pair; ``points_normals`` (M, 4): each point beside its normal (both built here, not by the caller)."""

    points: np.ndarray
    normals: np.ndarray
    has_normal: np.ndarray
    _tree: cKDTree | None = field(default=None, repr=False)
    near: np.ndarray | None = field(default=None, repr=False)
    reach: np.ndarray | None = field(default=None, repr=False)
    paired: np.ndarray = field(init=False, repr=False)
    points_normals: np.ndarray = field(init=False, repr=False)
    grids: dict = field(init=False, repr=False, default_factory=dict)  # the compiled core's grid per gate (m)

    def __post_init__(self) -> None:
        self.paired = np.append(self.has_normal, False)
        self.points_normals = np.hstack([self.points, self.normals])  # one gather a pass for both

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
            self._tree = cKDTree(self.points)
        return self._tree


def build_submap(points: np.ndarray, p: LineICPParams = LineICPParams()) -> Submap:
    """Normals by PCA over each point's ``normal_neighbours`` nearest points (vectorised).

    ``points`` (M, 2), m, in the submap's frame; the :class:`Submap` holds them, their unit
    normals and a KD-tree over them.

    The compiled core (``src/core/normals.hpp``) computes them where it is selected, else
    :func:`~fmcwlog.kernels.normals.line_normals_numpy`, its reference (the same neighbours, ties by
    index, and the same arithmetic: bit for bit the same normals)."""
    module = compiled.core()
    if module is not None and len(points):
        points = np.ascontiguousarray(points, float)
        normals, has_normal = np.empty((len(points), 2)), np.empty(len(points), bool)
        if not np.isfinite(points).all():  # the neighbour table assumes finite points
            module.submap_normals(points, p.normal_neighbours, p.min_planarity, normals, has_normal)
            return Submap(points, normals, has_normal)
        near = np.empty((len(points), p.normal_neighbours), np.int32)
        reach = np.empty((len(points), p.normal_neighbours + 1))
        module.submap_normals(points, p.normal_neighbours, p.min_planarity, normals, has_normal, near, reach)
        return Submap(points, normals, has_normal, near=near, reach=reach)
    from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
    tree = cKDTree(points)
    normals, planar = line_normals_numpy(points, p.normal_neighbours, p.min_planarity, tree)
    return Submap(points, normals, planar, tree)


@dataclass
class LineICPResult:
    """pose (3,); hessian (3, 3) ``JᵀWJ`` at the final pose, in (x, y of the target frame, yaw):
    the information up to the residuals' variance (divide by σ², m²); residuals (K,) of the final
    pairs (m); pairs K; iterations; converged."""

    pose: np.ndarray
    hessian: np.ndarray
    residuals: np.ndarray
    pairs: int
    iterations: int
    converged: bool


_DAMPING = 1e-9 * np.eye(3)  # keeps a step defined where the scene leaves a direction free


def _system(pose: np.ndarray, sub: Submap, nearest: NearestPairs, c: float):
    """Residuals (K,), Jacobian rows (K, 3) and Cauchy weights (K,) of the source points that pair
    at ``pose`` (module docstring). Each array is computed once, with the arithmetic of the plain
    ``einsum`` form (its two-term sum written out), so the results are bit for bit those of that
    form (checked on the 2,895 matches of the 200 s ring log)."""
    moved, idx, dist = nearest.nearest(pose)
    ok = sub.paired.take(idx)  # the target point has a normal (the index M, no target, has none)
    ok &= dist < nearest.gate
    sel = np.flatnonzero(ok)
    both = sub.points_normals.take(idx.take(sel), axis=0)  # (K, 4): the target point and its normal
    n = both[:, 2:]
    m = moved.take(sel, axis=0)
    d = m - both[:, :2]
    r = n[:, 0] * d[:, 0] + n[:, 1] * d[:, 1]
    rp = m - pose[:2]  # R p
    j = np.empty((len(r), 3))
    j[:, :2] = n
    j[:, 2] = n[:, 0] * -rp[:, 1] + n[:, 1] * rp[:, 0]
    w = 1.0 / (1.0 + (r / c) ** 2)
    return r, j, w


def register_point_to_line(source_xy: np.ndarray, submap: Submap, initial: np.ndarray,
                           p: LineICPParams = LineICPParams(),
                           prior: tuple[np.ndarray, np.ndarray] | None = None) -> LineICPResult:
    """Gauss-Newton with Cauchy weights from ``initial`` (module docstring).

    ``source_xy`` (N, 2), m, in the source frame; ``submap``: :func:`build_submap` of the target
    points (target frame); ``initial`` (3,): the source-to-target pose to start from (m, m, rad).
    Fewer than 3 pairs end the iterations (``converged`` False); nothing is raised.
    ``prior``: a pose (3,) and an information (3, 3) in the units of ``JᵀWJ`` (m⁻² and rad⁻² times
    m²) added to every step, e.g. to hold a direction the scene leaves free where an estimate put
    it; the returned ``hessian`` does not include it."""
    module = compiled.core()
    if module is not None:
        return _compiled(module, source_xy, submap, initial, p, prior)
    from scipy.linalg.lapack import dgesv  # here, not at import: scipy.linalg is 0.13 s of imports

    pose = np.asarray(initial, float).copy()
    c = p.kernel_scale
    nearest = NearestPairs(source_xy, submap.tree, submap.points, p.max_distance)
    converged, it = False, 0
    for it in range(1, p.max_iterations + 1):  # noqa: B007 (the count is returned)
        r, j, w = _system(pose, submap, nearest, c)
        if len(r) < 3:
            break
        jw = j * w[:, None]
        h, g = jw.T @ j, jw.T @ r
        if prior is not None:
            dp = pose - prior[0]
            dp[2] = wrap_angle(dp[2])
            h, g = h + prior[1], g + prior[1] @ dp
        # LAPACK's gesv, as np.linalg.solve calls it, without its wrapper's 17 µs of checks a call
        _, _, step, info = dgesv(h + _DAMPING, g)
        if info != 0:  # exactly singular
            break
        delta = -step
        pose = pose + delta
        pose[2] = wrap_angle(pose[2])
        if np.hypot(delta[0], delta[1]) < p.tolerance and abs(delta[2]) < p.tolerance:
            converged = True
            break
    r, j, w = _system(pose, submap, nearest, c)
    h = (j * w[:, None]).T @ j if len(r) else np.zeros((3, 3))
    return LineICPResult(pose, h, r, len(r), it, converged)


def _compiled(module, source_xy: np.ndarray, submap: Submap, initial: np.ndarray, p: LineICPParams,
              prior: tuple[np.ndarray, np.ndarray] | None) -> LineICPResult:
    """:func:`register_point_to_line` in the compiled core (``src/core/line_icp.cpp``): the same
    pairs, the same iterations; its sums run in point order, so poses agree to rounding. The
    submap's neighbour table, where it has one, spares most passes' grid queries (the same pairs)."""
    grid = submap.grids.get(p.max_distance)
    if grid is None:
        grid = submap.grids[p.max_distance] = module.TargetGrid(np.ascontiguousarray(submap.points, float),
                                                                p.max_distance)
    x, y, th = np.asarray(initial, float).tolist()
    held = (None, None) if prior is None else (np.asarray(prior[0], float).tolist(),
                                               np.asarray(prior[1], float).ravel().tolist())
    pose, h, residuals, pairs, iterations, converged = module.line_icp(
        grid, np.ascontiguousarray(submap.normals, float), np.ascontiguousarray(submap.has_normal, bool),
        np.ascontiguousarray(source_xy, float), x, y, th, p.max_iterations, p.kernel_scale, p.tolerance, *held,
        submap.near, submap.reach)
    hessian = np.array(h).reshape(3, 3) if pairs else np.zeros((3, 3))
    return LineICPResult(np.array(pose), hessian, residuals, pairs, iterations, converged)
