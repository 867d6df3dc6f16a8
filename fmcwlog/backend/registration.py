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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..config import Checked, param
from ..geometry import transform_points, wrap_angle


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
    """Target points (M, 2), their unit normals (M, 2), which have one (M,), and the KD-tree."""

    points: np.ndarray
    normals: np.ndarray
    has_normal: np.ndarray
    tree: cKDTree


def build_submap(points: np.ndarray, p: LineICPParams = LineICPParams()) -> Submap:
    """Normals by PCA over each point's ``normal_neighbours`` nearest points (vectorised)."""
    tree = cKDTree(points)
    k = min(p.normal_neighbours, len(points))
    _, idx = tree.query(points, k=k)
    nb = points[np.atleast_2d(idx.T).T] if k > 1 else points[:, None, :]
    d = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", d, d) / max(k, 1)
    w, v = np.linalg.eigh(cov)  # ascending eigenvalues
    normals = v[:, :, 0]
    planar = w[:, 0] <= p.min_planarity * np.maximum(w[:, 1], 1e-12)
    return Submap(points, normals, planar & (k >= 3), tree)


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


def _system(src: np.ndarray, pose: np.ndarray, sub: Submap, max_distance: float, c: float):
    moved = transform_points(pose, src)
    dist, idx = sub.tree.query(moved, k=1, distance_upper_bound=max_distance)
    ok = np.isfinite(dist)
    ok[ok] = sub.has_normal[idx[ok]]
    n = sub.normals[idx[ok]]
    m = moved[ok]
    r = np.einsum("ij,ij->i", n, m - sub.points[idx[ok]])
    rp = m - pose[:2]
    j = np.column_stack([n[:, 0], n[:, 1], n[:, 0] * -rp[:, 1] + n[:, 1] * rp[:, 0]])
    w = 1.0 / (1.0 + (r / c) ** 2)
    return r, j, w


def register_point_to_line(source_xy: np.ndarray, submap: Submap, initial: np.ndarray,
                           p: LineICPParams = LineICPParams(),
                           prior: tuple[np.ndarray, np.ndarray] | None = None) -> LineICPResult:
    """Gauss-Newton with Cauchy weights from ``initial`` (module docstring).

    ``prior``: a pose (3,) and an information (3, 3) in the units of ``JᵀWJ`` (m⁻² and rad⁻² times
    m²) added to every step, e.g. to hold a direction the scene leaves free where an estimate put
    it; the returned ``hessian`` does not include it."""
    pose = np.asarray(initial, float).copy()
    c = p.kernel_scale
    converged, it = False, 0
    for it in range(1, p.max_iterations + 1):  # noqa: B007 (the count is returned)
        r, j, w = _system(source_xy, pose, submap, p.max_distance, c)
        if len(r) < 3:
            break
        h = (j * w[:, None]).T @ j
        g = (j * w[:, None]).T @ r
        if prior is not None:
            dp = pose - prior[0]
            dp[2] = wrap_angle(dp[2])
            h, g = h + prior[1], g + prior[1] @ dp
        try:
            delta = -np.linalg.solve(h + 1e-9 * np.eye(3), g)
        except np.linalg.LinAlgError:
            break
        pose = pose + delta
        pose[2] = wrap_angle(pose[2])
        if np.hypot(delta[0], delta[1]) < p.tolerance and abs(delta[2]) < p.tolerance:
            converged = True
            break
    r, j, w = _system(source_xy, pose, submap, p.max_distance, c)
    h = (j * w[:, None]).T @ j if len(r) else np.zeros((3, 3))
    return LineICPResult(pose, h, r, len(r), it, converged)
