"""Correlative scan matching (Olson 2009, "Real-time correlative scan matching"): an exhaustive
search of poses around a prior, scored on a likelihood grid of the target points, coarse to fine.

Not in the paper. ICP converges to the nearest local minimum of its cost, so a prior that is
off by more than about half the spacing of the structures it sees (real odometry 5-10° off
after a turn; a loop-closure candidate after metres of drift) ends in a wrong match. The
correlative search scores every pose on a lattice around the prior instead, then ICP refines
the best one.

Frames and units: ``target_xy`` (M, 2) in the target frame (the local map's ``map`` frame, or
a submap's); ``source_xy`` (N, 2) in the source frame (base_link at the sweep's stamp); poses
``(x, y, θ)`` map source into target (m, rad), as in :mod:`fmcwlog.frontend.icp`.

The likelihood of a point is ``exp(-d²/2σ²)`` with ``d`` the distance from its cell to the
nearest target point (a Euclidean distance transform); the score of a pose is the mean
likelihood over the source points, in [0, 1]. The search is branch and bound at two levels,
exact for translations (as Cartographer's): a coarse grid holds, per cell, the maximum of the
fine likelihood over the ``coarse_factor`` × ``coarse_factor`` fine translations a coarse
candidate stands for, so a coarse score bounds every fine score under it; coarse candidates
are refined best first until the next bound is below the best fine score found. Rotations are
searched at the fine angular step everywhere (``resolution`` / the source's 90th-percentile
range: no point moves more than about a cell between two rotations).

Besides the best pose the result carries the best score of a *separate* peak (one whose pose
differs from the best by more than ``peak_separation`` m or ``peak_separation_deg``): a
near-equal second peak means the scene does not fix the pose (a corridor along its axis, or
two look-alike places), which the loop-closure verification uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..geometry import wrap_angle


@dataclass(frozen=True)
class CorrelativeParams:
    """Search window and grids of :func:`correlative_match`.

    linear_window: half-width of the search in x and y around the prior (m, > 0).
    angular_window_deg: half-width of the search in yaw (deg, > 0).
    resolution: fine grid cell and finest translation step (m, > 0).
    coarse_factor: coarse translation step in fine cells (≥ 1; 4 × 5 cm = 20 cm).
    sigma: width of the likelihood around a target point (m, > 0).
    max_points: source points scored (evenly subsampled; ≥ 10): the cost is linear in it.
    max_rotations: cap on the yaw samples (≥ 3); the step grows to respect it.
    peak_separation, peak_separation_deg: a pose this far from the best one (m or deg) belongs
        to another peak (see the module docstring).
    """

    linear_window: float = 0.5
    angular_window_deg: float = 10.0
    resolution: float = 0.05
    coarse_factor: int = 4
    sigma: float = 0.075
    max_points: int = 300
    max_rotations: int = 121
    peak_separation: float = 0.3
    peak_separation_deg: float = 5.0


class LikelihoodGrid:
    """``exp(-d²/2σ²)`` of the distance from each cell centre to the nearest target point, on a
    lattice of ``resolution`` covering the targets plus ``margin`` (m).

    Around it a frame of zeros ``2·reach + 1`` cells wide, ``reach`` (cells) being the largest
    lookup offset the search will add: a point off the grid is clipped ``reach`` cells into the
    frame, where every offset still reads 0, so a lookup is one flat ``take`` with no bounds test.
    ``coarse(k)`` is the grid max-filtered over the ``k × k`` cells ``[i, i+k)``: the bound a
    coarse candidate needs (module docstring)."""

    def __init__(self, target_xy: np.ndarray, resolution: float, sigma: float, margin: float, reach: int = 16):
        self.resolution = resolution
        self.reach = int(reach)
        frame = (2 * self.reach + 1) * resolution
        lo = target_xy.min(axis=0) - margin - frame
        hi = target_xy.max(axis=0) + margin + frame
        self.origin = np.floor(lo / resolution) * resolution
        shape = (np.ceil((hi - self.origin) / resolution).astype(int) + 1)[::-1]  # rows = y
        occupied = np.zeros(shape, bool)
        ij = self.cell(target_xy)
        occupied[ij[:, 1], ij[:, 0]] = True
        dist = ndimage.distance_transform_edt(~occupied) * resolution
        self.fine = self._framed(np.exp(-0.5 * (dist / sigma) ** 2).astype(np.float32))
        self._coarse: dict[int, np.ndarray] = {}

    def _framed(self, grid: np.ndarray) -> np.ndarray:
        f = 2 * self.reach + 1
        grid[:f], grid[-f:], grid[:, :f], grid[:, -f:] = 0, 0, 0, 0
        return grid

    @property
    def shape(self) -> tuple[int, int]:
        return self.fine.shape  # type: ignore[return-value]

    def cell(self, xy: np.ndarray) -> np.ndarray:
        """Integer (ix, iy) of the cells holding points (N, 2)."""
        return np.floor((xy - self.origin) / self.resolution).astype(np.int64)

    def coarse(self, k: int) -> np.ndarray:
        if k not in self._coarse:
            grid = ndimage.maximum_filter(self.fine, size=k, origin=-(k // 2), mode="constant")
            self._coarse[k] = self._framed(grid)
        return self._coarse[k]

    def flat_cells(self, xy: np.ndarray) -> np.ndarray:
        """Flat indices of the cells of points (..., 2), clipped ``reach`` cells into the frame."""
        h, w = self.fine.shape
        ij = np.floor((xy - self.origin) / self.resolution).astype(np.int64)
        ix = np.clip(ij[..., 0], self.reach, w - 1 - self.reach)
        iy = np.clip(ij[..., 1], self.reach, h - 1 - self.reach)
        return iy * w + ix

    def flat_offsets(self, offsets: np.ndarray) -> np.ndarray:
        """Flat index steps of integer cell offsets (T, 2), each within ``reach``."""
        assert np.abs(offsets).max(initial=0) <= self.reach, "offset beyond the grid's frame"
        return offsets[:, 1] * self.fine.shape[1] + offsets[:, 0]


@dataclass
class CorrelativeResult:
    """pose: the best pose (3,) on the search lattice; score: its mean likelihood in [0, 1];
    second_score: the best score of a separate peak (0 when none was found); second_pose: where.
    evaluated: poses scored (fine + coarse), for the record."""

    pose: np.ndarray
    score: float
    second_score: float
    second_pose: np.ndarray | None
    evaluated: int


def subsample(xy: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` points, evenly spread over the array's order (a sweep's order is its bearing)."""
    if len(xy) <= n:
        return xy
    return xy[np.linspace(0, len(xy) - 1, n).astype(int)]


def _rotations(prior_yaw: float, source: np.ndarray, p: CorrelativeParams) -> np.ndarray:
    reach = max(float(np.percentile(np.hypot(source[:, 0], source[:, 1]), 90)), p.resolution)
    window = np.radians(p.angular_window_deg)
    step = max(p.resolution / reach, 2 * window / (p.max_rotations - 1))
    k = int(np.ceil(window / step))
    return prior_yaw + step * np.arange(-k, k + 1)


def _scores(table: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Mean likelihood per (rotation, offset): ``cells`` (R, N) flat cells of the rotated points,
    ``offsets`` (T,) flat offsets; returns (R, T)."""
    return table.ravel().take(cells[:, :, None] + offsets[None, None, :]).mean(axis=1)


def correlative_match(grid: LikelihoodGrid, source_xy: np.ndarray, prior: np.ndarray,
                      p: CorrelativeParams = CorrelativeParams()) -> CorrelativeResult:
    """The pose within the window around ``prior`` that best fits ``source_xy`` to the grid's targets.

    Branch and bound over translations (module docstring); every yaw sample at both levels.
    """
    src = subsample(np.asarray(source_xy, float), p.max_points)
    prior = np.asarray(prior, float)
    thetas = _rotations(float(prior[2]), src, p)
    res, k = grid.resolution, max(int(p.coarse_factor), 1)
    # rotated points placed at the prior's translation, in fine cells; the window's corner offset
    c, s = np.cos(thetas)[:, None], np.sin(thetas)[:, None]
    placed = np.stack([c * src[:, 0] - s * src[:, 1] + prior[0], s * src[:, 0] + c * src[:, 1] + prior[1]], -1)
    cells = grid.flat_cells(placed)  # (R, N)
    n_fine = int(np.ceil(p.linear_window / res))
    n_coarse = int(np.ceil((2 * n_fine + 1) / k))
    coarse_offsets = np.array([(i, j) for j in range(n_coarse) for i in range(n_coarse)]) * k - n_fine
    upper = _scores(grid.coarse(k), cells, grid.flat_offsets(coarse_offsets))  # (R, T) bounds
    order = np.argsort(upper, axis=None)[::-1]
    fine_steps = np.array([(i, j) for j in range(k) for i in range(k)])
    best, best_at = -1.0, (0, np.zeros(2, int))
    evaluated = upper.size
    fine_by_candidate: list[tuple[float, int, np.ndarray]] = []
    for flat in order:
        r, t = np.unravel_index(flat, upper.shape)
        if upper[r, t] <= best:
            break
        offs = coarse_offsets[t] + fine_steps
        offs = offs[(np.abs(offs) <= n_fine).all(axis=1)]
        s = _scores(grid.fine, cells[r:r + 1], grid.flat_offsets(offs))[0]
        evaluated += len(offs)
        i = int(np.argmax(s))
        fine_by_candidate.append((float(s[i]), int(r), offs[i]))
        if s[i] > best:
            best, best_at = float(s[i]), (int(r), offs[i])
    pose = _pose(prior, thetas, best_at[0], best_at[1], res)
    second, second_pose, more = _second_peak(grid, cells, thetas, prior, upper, coarse_offsets, fine_steps,
                                             n_fine, pose, fine_by_candidate, p)
    return CorrelativeResult(pose, best, second, second_pose, evaluated + more)


def _pose(prior: np.ndarray, thetas: np.ndarray, r: int, offset: np.ndarray, res: float) -> np.ndarray:
    return np.array([prior[0] + offset[0] * res, prior[1] + offset[1] * res, float(wrap_angle(thetas[r]))])


def _separate(a: np.ndarray, b: np.ndarray, p: CorrelativeParams) -> np.ndarray:
    """Whether poses (..., 3) lie on another peak than pose ``b`` (3,)."""
    dyaw = np.abs((a[..., 2] - b[2] + np.pi) % (2 * np.pi) - np.pi)
    return (np.hypot(a[..., 0] - b[0], a[..., 1] - b[1]) > p.peak_separation) | (dyaw > np.radians(p.peak_separation_deg))


def _second_peak(grid: LikelihoodGrid, cells: np.ndarray, thetas: np.ndarray, prior: np.ndarray, upper: np.ndarray,
                 coarse_offsets: np.ndarray, fine_steps: np.ndarray, n_fine: int, best_pose: np.ndarray,
                 refined: list[tuple[float, int, np.ndarray]], p: CorrelativeParams) -> tuple[float, np.ndarray | None, int]:
    """The best fine score among poses separate from ``best_pose``: the refined candidates first,
    then the coarse candidates whose centre is separate, best bound first, until the bound
    drops below it."""
    res = grid.resolution
    second, second_pose = 0.0, None
    for s, r, off in refined:
        q = _pose(prior, thetas, r, off, res)
        if s > second and _separate(q, best_pose, p):
            second, second_pose = s, q
    half = (np.sqrt(len(fine_steps)) - 1) / 2
    centres = np.empty(upper.shape + (3,))
    centres[..., 0] = prior[0] + (coarse_offsets[None, :, 0] + half) * res
    centres[..., 1] = prior[1] + (coarse_offsets[None, :, 1] + half) * res
    centres[..., 2] = thetas[:, None]
    bound = np.where(_separate(centres, best_pose, p), upper, -1.0)
    evaluated = 0
    for flat in np.argsort(bound, axis=None)[::-1]:
        r, t = np.unravel_index(flat, upper.shape)
        if bound[r, t] <= second:
            break
        offs = coarse_offsets[t] + fine_steps
        offs = offs[(np.abs(offs) <= n_fine).all(axis=1)]
        s = _scores(grid.fine, cells[r:r + 1], grid.flat_offsets(offs))[0]
        evaluated += len(offs)
        i = int(np.argmax(s))
        q = _pose(prior, thetas, int(r), offs[i], res)
        if s[i] > second and _separate(q, best_pose, p):
            second, second_pose = float(s[i]), q
    return second, second_pose, evaluated
