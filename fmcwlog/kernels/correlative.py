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

Cost: the 235 verification searches of the 200 s ``ring`` log's back ends (seed 0, CPU time)
take 2.5 s, against 5.3 s for the same branch and bound without the following, which visit
nothing else and keep every pose, score and count: a candidate's children (2-D and flat) are
built once per (level, offset) rather than per yaw sample; the children of the next 32 top
candidates are scored in one gather (each score's float32 sum runs over the points in the same
order as one at a time, checked bit for bit), and each set once for both the best and the
second-peak search; a set whose largest score cannot beat the best is skipped unsorted; the
second peak's separation is read from a lattice computed once. The likelihood grid's distance
transform runs inside its frame only (the frame is zeroed anyway): 0.5 s for those 235 grids
against 1.2 s over the whole grid, the same float32 grid (docs/design/speed-experiments.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import Checked, param
from ..geometry import wrap_angle
from . import compiled

# the grids carry a frame of zeros coarse_factor^(levels-1) cells wide: 8^3 cells at most
MAX_LEVELS = 4
MAX_COARSE_FACTOR = 8


@dataclass(frozen=True)
class CorrelativeParams(Checked):
    """Search window and grids of :func:`correlative_match`.

    linear_window: half-width of the search in x and y around the prior (m, > 0).
    angular_window_deg: half-width of the search in yaw (deg, > 0).
    resolution: fine grid cell and finest translation step (m, > 0).
    coarse_factor: each level's translation step is this many of the next's (≥ 2; 4 × 5 cm = 20 cm).
    levels: levels of the branch and bound (1 to :data:`MAX_LEVELS`): the coarsest step is ``coarse_factor^(levels-1)``
        fine cells (use 3 for windows of metres).
    sigma: width of the likelihood around a target point (m, > 0).
    max_points: source points scored (evenly subsampled; ≥ 10): the cost is linear in it.
    max_rotations: cap on the yaw samples (≥ 3); the step grows to respect it.
    peak_separation, peak_separation_deg: a pose this far from the best one (m or deg) belongs
        to another peak (see the module docstring).
    """

    linear_window: float = param(0.5, "m", gt=0.0, le=20.0)
    angular_window_deg: float = param(10.0, "deg", gt=0.0, le=180.0)
    # below 1 cm a window of metres is a grid of 10⁷ cells and more
    resolution: float = param(0.05, "m", ge=0.01, le=1.0)
    coarse_factor: int = param(4, "", ge=2, le=MAX_COARSE_FACTOR)
    levels: int = param(2, "", ge=1, le=MAX_LEVELS)
    sigma: float = param(0.075, "m", gt=0.0, le=1.0)
    max_points: int = param(300, "points", ge=10, le=100_000)
    max_rotations: int = param(121, "", ge=3, le=3601)
    peak_separation: float = param(0.3, "m", gt=0.0, le=20.0)
    peak_separation_deg: float = param(5.0, "deg", gt=0.0, le=180.0)


def _likelihood(dist: np.ndarray, sigma: float) -> np.ndarray:
    """``exp(-d²/2σ²)`` (float32) of distances ``dist`` (m)."""
    return np.exp(-0.5 * (dist / sigma) ** 2).astype(np.float32)


# beyond this many σ² the likelihood's float32 is 0 (exp(-120) ≈ 8e-53; float32 ends near 1.4e-45)
_ZERO_BEYOND = 240.0


def _likelihood_table(resolution: float, sigma: float, shape: tuple[int, int]) -> np.ndarray:
    """:func:`_likelihood` of the distance of every squared distance in cells ``d2`` (the index)
    that a grid of ``shape`` cells holds, ``sqrt(d2) · resolution`` (the distance transform's own
    arithmetic); past its end the likelihood is 0, as it is at its end."""
    largest = (shape[0] - 1) ** 2 + (shape[1] - 1) ** 2
    n = min(int(np.ceil(_ZERO_BEYOND * (sigma / resolution) ** 2)) + 2, largest + 1)
    table = _likelihood(np.sqrt(np.arange(n, dtype=np.float64)) * resolution, sigma)
    assert n == largest + 1 or table[-1] == 0.0, "the likelihood table ends before the likelihood is 0"
    return table


class LikelihoodGrid:
    """``exp(-d²/2σ²)`` of the distance from each cell centre to the nearest target point, on a
    lattice of ``resolution`` covering the targets plus ``margin`` (m).

    Around it a frame of zeros ``2·reach + 1`` cells wide, ``reach`` (cells) being the largest
    lookup offset the search will add: a point off the grid is clipped ``reach`` cells into the
    frame, where every offset still reads 0, so a lookup is one flat ``take`` with no bounds test.
    ``coarse(k)`` is the grid max-filtered over the ``k × k`` cells ``[i, i+k)``: the bound a
    coarse candidate needs (module docstring). The compiled core (``src/core/likelihood_grid.cpp``)
    builds the same float32 grids, bit for bit: an exact integer distance transform whose squared
    distances index :func:`_likelihood_table`, and the same maximum filter."""

    def __init__(self, target_xy: np.ndarray, resolution: float, sigma: float, margin: float, reach: int = 16):
        self.resolution = resolution
        self.reach = int(reach)
        frame = (2 * self.reach + 1) * resolution
        lo = target_xy.min(axis=0) - margin - frame
        hi = target_xy.max(axis=0) + margin + frame
        self.origin = np.floor(lo / resolution) * resolution
        shape = (np.ceil((hi - self.origin) / resolution).astype(int) + 1)[::-1]  # rows = y
        ij = self.cell(target_xy)
        # the frame is zeroed anyway: where every target lies inside it (as the margin makes it),
        # the distance transform of the inside alone gives the inside the same distances (the
        # nearest target is the same cell), at about half the cells
        f = 2 * self.reach + 1
        fits = min(shape) > 2 * f and ij.min() >= f and (ij[:, ::-1] < shape - f).all()
        module = compiled.core()
        if fits and module is not None:
            self.fine = np.zeros(shape, np.float32)
            table = _likelihood_table(resolution, sigma, (int(shape[0]) - 2 * f, int(shape[1]) - 2 * f))
            module.likelihood_fill(np.ascontiguousarray(ij, np.int64), self.fine, f, table)
            self._coarse: dict[int, np.ndarray] = {}
            return
        occupied = np.zeros(shape, bool)
        occupied[ij[:, 1], ij[:, 0]] = True
        from scipy import ndimage  # here, not at import: 0.3 s that only a recovery search needs

        if fits:
            inside = (slice(f, int(shape[0]) - f), slice(f, int(shape[1]) - f))
            dist = ndimage.distance_transform_edt(~occupied[inside]) * resolution
            self.fine = np.zeros(shape, np.float32)
            self.fine[inside] = _likelihood(dist, sigma)
        else:
            dist = ndimage.distance_transform_edt(~occupied) * resolution
            self.fine = self._framed(_likelihood(dist, sigma))
        self._coarse = {}

    def _framed(self, grid: np.ndarray) -> np.ndarray:
        f = 2 * self.reach + 1
        grid[:f], grid[-f:], grid[:, :f], grid[:, -f:] = 0, 0, 0, 0
        return grid

    @property
    def shape(self) -> tuple[int, int]:
        """The fine grid's (rows, columns), its frame included."""
        return (int(self.fine.shape[0]), int(self.fine.shape[1]))

    def cell(self, xy: np.ndarray) -> np.ndarray:
        """Integer (ix, iy) of the cells holding points (N, 2)."""
        return np.floor((xy - self.origin) / self.resolution).astype(np.int64)

    def coarse(self, k: int) -> np.ndarray:
        """The grid of the maximum fine likelihood over each ``k`` × ``k`` block of translations (the
        branch and bound's bound), framed as the fine one; computed once per ``k``."""
        if k not in self._coarse:
            module = compiled.core()
            if module is not None:
                grid = np.empty_like(self.fine)
                module.max_filter_framed(self.fine, grid, k, 2 * self.reach + 1)
                self._coarse[k] = grid
                return grid
            from scipy import ndimage

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


def grid_for(target_xy: np.ndarray, p: CorrelativeParams) -> LikelihoodGrid:
    """The likelihood grid a search with ``p`` needs over ``target_xy``: its cell, its σ, a margin
    of the window plus 3σ, and a frame for the largest offset (the window plus the coarsest step)."""
    reach = int(np.ceil(p.linear_window / p.resolution)) + p.coarse_factor ** max(p.levels - 1, 0) + 1
    return LikelihoodGrid(target_xy, p.resolution, p.sigma, p.linear_window + 3 * p.sigma, reach)


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


def _descending(values: np.ndarray) -> np.ndarray:
    """Indices of ``values`` (1-D), highest first, equal values in the order of their indices: the
    order every level of the search visits its candidates in (a stable sort, so the same on every
    machine; the compiled search sorts by the same rule)."""
    return np.argsort(-values, kind="stable")


def _scores(table: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Mean likelihood per (rotation, offset): ``cells`` (R, N) flat cells of the rotated points,
    ``offsets`` (T,) flat offsets; returns (R, T)."""
    return table.ravel().take(cells[:, :, None] + offsets[None, None, :]).mean(axis=1)


@dataclass
class _Search:
    """What every level of one search shares: the grid, the rotated points' flat cells (R, N),
    the yaw samples, the prior, the window (fine cells each side) and the steps per level.

    Exact caches (integer offsets, and values computed once instead of per candidate): each
    candidate's children, 2-D and flat, are the same at every yaw sample, so they are built once
    per (level, offset); the wrapped yaw of each sample once per search."""

    grid: LikelihoodGrid
    cells: np.ndarray
    thetas: np.ndarray
    prior: np.ndarray
    n_fine: int
    steps: list[int]
    p: CorrelativeParams
    evaluated: int = 0
    _children: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    _templates: dict[int, np.ndarray] = field(default_factory=dict)
    _yaws: list[float] = field(default_factory=list)
    _scored: dict[tuple[int, int, int, int], tuple[np.ndarray, float]] = field(default_factory=dict)
    _far: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    _turned: list[bool] = field(default_factory=list)

    def table(self, level: int) -> np.ndarray:
        step = self.steps[level]
        return self.grid.fine if step == 1 else self.grid.coarse(step)

    def child_scores(self, level: int, r: int, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """The children of ``offset`` (a candidate of level ``level``), their scores (T,) at yaw
        sample ``r`` and the largest of them, each set scored once per search (the second-peak
        search visits the same)."""
        child, flat = self.children(offset, level)
        self.evaluated += len(flat)
        key = (level, int(offset[0]), int(offset[1]), r)
        found = self._scored.get(key)
        if found is None:
            sc = _scores(self.table(level + 1), self.cells[r:r + 1], flat)[0]
            found = self._scored[key] = (sc, float(sc.max()))
        return child, found[0], found[1]

    def prefetch(self, level: int, candidates: list[tuple[int, np.ndarray]]) -> None:
        """Score the children of ``candidates`` ((yaw sample, offset) of level ``level``) not yet
        scored, in one gather for all of those with a full set of children. The same numbers as
        one at a time: each candidate's sums run over the points in the same order (a reduction
        over the middle axis; a single child, whose sums numpy would pair differently, is left to
        :meth:`child_scores`)."""
        full = (self.steps[level] // self.steps[level + 1]) ** 2
        keys, rows, flats = [], [], []
        for r, offset in candidates:
            key = (level, int(offset[0]), int(offset[1]), r)
            flat = self.children(offset, level)[1]
            if key not in self._scored and len(flat) == full > 1:
                keys.append(key)
                rows.append(r)
                flats.append(flat)
        if len(keys) > 1:
            table = self.table(level + 1).ravel()
            scored = table.take(self.cells[rows][:, :, None] + np.array(flats)[:, None, :]).mean(axis=1)
            self._scored.update(zip(keys, zip(scored, scored.max(axis=1).tolist())))

    def children(self, offset: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
        """The next level's offsets under ``offset`` (a candidate of level ``level``), in the window:
        (T, 2) cell offsets and their flat steps (T,)."""
        key = (level, int(offset[0]), int(offset[1]))
        found = self._children.get(key)
        if found is None:
            if level not in self._templates:
                n, child = self.steps[level] // self.steps[level + 1], self.steps[level + 1]
                self._templates[level] = np.array([(i, j) for j in range(n) for i in range(n)]) * child
            grid = self._templates[level] + offset
            grid = grid[(grid <= self.n_fine).all(axis=1)]
            found = self._children[key] = (grid, self.grid.flat_offsets(grid))
        return found

    def yaws(self) -> list[float]:
        """The yaw samples wrapped to [-π, π)."""
        if not self._yaws:
            self._yaws = np.asarray(wrap_angle(self.thetas)).tolist()  # elementwise: as one at a time
        return self._yaws

    def pose(self, r: int, offset: np.ndarray) -> np.ndarray:
        res = self.grid.resolution
        return np.array([self.prior[0] + offset[0] * res, self.prior[1] + offset[1] * res, self.yaws()[r]])

    def exclude(self, pose: np.ndarray) -> None:
        """Prepare the second-peak search around ``pose``: whether each yaw sample, and each fine
        offset in the window, lies on another peak than ``pose`` (:func:`_separate`'s two tests, the
        same arithmetic elementwise over the lattice instead of pose by pose)."""
        res, n = self.grid.resolution, self.n_fine
        steps = np.arange(-n, n + 1)
        along = np.hypot((self.prior[0] + steps * res)[None, :] - pose[0], (self.prior[1] + steps * res)[:, None] - pose[1])
        self._far = along > self.p.peak_separation  # (2n+1, 2n+1): rows y, columns x
        yaws = np.array(self.yaws())
        dyaw = np.abs((yaws - pose[2] + np.pi) % (2 * np.pi) - np.pi)
        self._turned = (dyaw > np.radians(self.p.peak_separation_deg)).tolist()

    def separate(self, r: int, offsets: np.ndarray) -> list[bool] | None:
        """Whether the poses of ``offsets`` (T, 2) at yaw sample ``r`` lie on another peak than the
        pose given to :meth:`exclude`; None where all do (the yaw alone separates them)."""
        if self._turned[r]:
            return None
        n = self.n_fine
        return self._far[offsets[:, 1] + n, offsets[:, 0] + n].tolist()


def _descend(s: _Search, level: int, r: int, offsets: np.ndarray, sc: np.ndarray, highest: float, best: float,
             best_at: tuple | None, exclude: np.ndarray | None) -> tuple[float, tuple | None]:
    """Best first through ``offsets`` of level ``level`` at yaw sample ``r``, scored ``sc`` (the
    largest ``highest``), pruning by the bound; at the finest level a pose not separate from
    ``exclude`` is skipped (the second-peak search). The scores are float32, and so is every bound
    they are compared with (a score, or the floors -1 and 0), so comparing them as Python floats
    decides as numpy would."""
    if highest <= best:  # the loop below would stop at its first score
        return best, best_at
    order = _descending(sc)
    finest = level == len(s.steps) - 1
    separate = s.separate(r, offsets) if finest and exclude is not None else None
    for i, score in zip(order.tolist(), sc[order].tolist()):
        if score <= best:
            break
        if finest:
            if separate is not None and not separate[i]:
                continue
            best, best_at = score, (r, offsets[i])
        else:
            child, child_sc, highest = s.child_scores(level, r, offsets[i])
            best, best_at = _descend(s, level + 1, r, child, child_sc, highest, best, best_at, exclude)
    return best, best_at


PREFETCH = 32  # top candidates whose children are scored in one gather (some may then be pruned unused)


def _search_from_top(s: _Search, upper: np.ndarray, order: np.ndarray, top: np.ndarray, floor: float,
                     exclude: np.ndarray | None) -> tuple[float, tuple | None]:
    """``order``: ``upper``'s flat indices, highest first (:func:`_descending` of the flattened array)."""
    best, best_at = floor, None
    n_top = upper.shape[1]
    flats, bounds = order.tolist(), upper.ravel()[order].tolist()
    for k, (flat, bound) in enumerate(zip(flats, bounds)):
        if bound <= best:
            break
        r, t = divmod(flat, n_top)
        if len(s.steps) == 1:
            if exclude is None or _separate(s.pose(r, top[t]), exclude, s.p):
                best, best_at = bound, (r, top[t])
            continue
        if k % PREFETCH == 0:
            ahead = [divmod(f, n_top) for f, b in zip(flats[k:k + PREFETCH], bounds[k:k + PREFETCH]) if b > best]
            s.prefetch(0, [(rr, top[tt]) for rr, tt in ahead])
        child, child_sc, highest = s.child_scores(0, r, top[t])
        best, best_at = _descend(s, 1, r, child, child_sc, highest, best, best_at, exclude)
    return best, best_at


def correlative_match(grid: LikelihoodGrid, source_xy: np.ndarray, prior: np.ndarray,
                      p: CorrelativeParams = CorrelativeParams(), with_second: bool = True) -> CorrelativeResult:
    """The pose within the window around ``prior`` that best fits ``source_xy`` to the grid's targets.

    ``grid``: :func:`grid_for` over the target points (target frame); ``source_xy`` (N, 2), m,
    in the source frame (at most ``max_points`` of them are used); ``prior`` (3,): the
    source-to-target pose the window is centred on (m, m, rad). Branch and bound over
    translations, ``levels`` levels of ``coarse_factor`` (module docstring); every yaw sample at
    every level. Then, with ``with_second``, the same search for the best pose separate from it (without:
    ``second_score`` 0, ``second_pose`` None, at about half the cost).
    """
    src = subsample(np.asarray(source_xy, float), p.max_points)
    prior = np.asarray(prior, float)
    thetas = _rotations(float(prior[2]), src, p)
    res, k = grid.resolution, max(int(p.coarse_factor), 1)
    c, sn = np.cos(thetas)[:, None], np.sin(thetas)[:, None]
    placed = np.stack([c * src[:, 0] - sn * src[:, 1] + prior[0], sn * src[:, 0] + c * src[:, 1] + prior[1]], -1)
    n_fine = int(np.ceil(p.linear_window / res))
    steps = [k**e for e in range(max(p.levels, 1) - 1, -1, -1)]
    s = _Search(grid, grid.flat_cells(placed), thetas, prior, n_fine, steps, p)
    module = compiled.core()
    if module is not None and len(src) <= MAX_COMPILED_POINTS:
        return _compiled_match(module, s, with_second)
    n_top = int(np.ceil((2 * n_fine + 1) / steps[0]))
    top = np.array([(i, j) for j in range(n_top) for i in range(n_top)]) * steps[0] - n_fine
    upper = _scores(s.table(0), s.cells, grid.flat_offsets(top))  # (R, T): bounds (scores if one level)
    s.evaluated += upper.size
    order = _descending(upper.ravel())  # the bounds, highest first: shared by both searches
    best, best_at = _search_from_top(s, upper, order, top, -1.0, None)
    assert best_at is not None
    pose = s.pose(*best_at)
    if not with_second:
        return CorrelativeResult(pose, best, 0.0, None, s.evaluated)
    s.exclude(pose)
    second, second_at = _search_from_top(s, upper, order, top, 0.0, pose)
    return CorrelativeResult(pose, best, second, None if second_at is None else s.pose(*second_at), s.evaluated)


def _separate(a: np.ndarray, b: np.ndarray, p: CorrelativeParams) -> np.ndarray:
    """Whether poses (..., 3) lie on another peak than pose ``b`` (3,)."""
    dyaw = np.abs((a[..., 2] - b[2] + np.pi) % (2 * np.pi) - np.pi)
    return (np.hypot(a[..., 0] - b[0], a[..., 1] - b[1]) > p.peak_separation) | (dyaw > np.radians(p.peak_separation_deg))


# numpy sums a set of one offset pairwise in blocks of its buffer (8,192 values): the compiled twin
# sums it pairwise whole, the same numbers up to that many points
MAX_COMPILED_POINTS = 8192


def _compiled_match(module, s: _Search, with_second: bool) -> CorrelativeResult:
    """:func:`correlative_match`'s searches in the compiled core (``src/core/correlative.cpp``): the
    same poses, scores and count as the numpy walk. The yaw samples' cells, the grids and the
    second-peak masks (:meth:`_Search.exclude`) come from here."""
    tables = [np.ascontiguousarray(s.table(level), np.float32).ravel() for level in range(len(s.steps))]

    def exclude(r: int, x: int, y: int) -> tuple[np.ndarray, np.ndarray]:
        s.exclude(s.pose(r, np.array([x, y])))
        return np.ascontiguousarray(s._far).ravel(), np.array(s._turned, bool)

    cells = np.ascontiguousarray(s.cells, np.int64)
    best, second, evaluated = module.correlative_search(tables, cells, list(s.steps), s.n_fine, s.grid.shape[1],
                                                        exclude if with_second else None)
    pose = s.pose(best[1], np.array(best[2:]))
    if not with_second:
        return CorrelativeResult(pose, best[0], 0.0, None, evaluated)
    found = second[1] >= 0
    return CorrelativeResult(pose, best[0], second[0], s.pose(second[1], np.array(second[2:])) if found else None,
                             evaluated)
