"""Log-odds occupancy grid from static points by vectorised ray casting.

Frames and units: everything in the ``map`` frame, metres. Cell ``(ix, iy)``
covers ``[ix·res, (ix+1)·res) × [iy·res, (iy+1)·res)`` on a global lattice, so
grids built separately line up; the array is indexed ``[iy - iy0, ix - ix0]``
(row 0 = lowest y, as in ``nav_msgs/OccupancyGrid``). Feed only static points
(after segmentation): movers would leave ghost walls.

Per integrated scan and per ray: the cells the beam crosses get ``l_free`` once
(cells deduplicated per ray), the cell of the end point gets ``l_occ``; log-odds
are clamped to ``[l_min, l_max]``. Rays are sampled at ``resolution/2``: a cell
the beam only clips at a corner (chord < res/2) may be skipped — harmless for
mapping, and much cheaper than an exact supercover traversal in numpy.

Scans are cast when the grid is read, not when they arrive: :meth:`OccupancyGrid.integrate`
queues a scan (at most :data:`PENDING_SCANS` of them, then they are cast), and reading the
grid (its arrays, size, origin or any export) casts the queue in arrival order first, which
gives exactly the grid of casting each scan on arrival. A front end hands a scan over every
0.5 m (``grid_distance``) and ``process`` reads its grid every 5 s of log, so the ray casting (3-8 ms a scan)
leaves the per-sweep path, where it would set the p95 (corridor, 20 s: p95/median 3.2),
for the publishing of the map, and costs the same in all.

A scan given to several grids (the front end's grid and the tracker's recent grids,
:mod:`.recent_grid`) is one :class:`Scan`, cast once: :func:`cast` gives what the scan adds on
the global lattice (its cells and float32 increments, :class:`ScanUpdate`), computed when a
grid holding it is first read, and each grid adds those increments and clamps. The clamp is per
scan, so this is exactly casting into each grid. A grid applies, as the next scan arrives, the
queued scans another grid has already cast (no casting then), so a shared cast is not held
longer than that. The tracker reads its recent grids every sweep and the front end's grid for
its structure check: on the 20 s crowd log a run of both methods makes 123 casts, against 158
with each keyframe scan cast twice.

:func:`cast` makes few passes over the samples: ``min(s, length)`` on each ray's last sample
only (below it ``k·step < length``); a ray's extreme cells from its first and last samples (cells
are monotone along a ray); the per-ray deduplication kept with ``np.compress`` (4x boolean
indexing) on the float flat index, converted to int after; ``flatnonzero`` of a boolean mask (6x
of the int64 counts); no end-cell exclusion where every ray hits and ``protect_hits`` clears the
hit cells anyway. The grids, maps and outputs are bit-identical to a plain per-ray cast
(``tests/unit/frontend/test_occupancy.py`` checks the cast against a per-ray reference); in a whole ``process``
run of the 20 s crowd log (both methods), casting and applying take 0.75-0.90 s CPU against
1.81-2.09 s with the plain passes (docs/design/speed-experiments.md).

Where :func:`fmcwlog.kernels.compiled.core` selects them, the compiled kernels of
``src/core/occupancy.cpp`` cast, apply and export (:func:`cast`, :meth:`OccupancyGrid._apply`,
:meth:`OccupancyGrid.to_ros_int8`) with the same cells, float32 values and int8 values as the numpy
code here, bit for bit (``tests/unit/frontend/test_compiled_occupancy.py``); a cast of a crowd_30s
scan takes about a third of :func:`cast_numpy`'s time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import MapSizeError
from . import compiled

Cells = tuple[Any, Any, Any, Any]  # lattice cells (ix_lo, iy_lo, ix_hi, iy_hi): ints, or numpy int64 from numpy
PENDING_SCANS = 32  # scans queued at most before they are cast (about 1 MB of points)


@dataclass(frozen=True)
class OccupancyParams:
    """Grid parameters.

    resolution: cell size, m.
    l_occ, l_free: log-odds added for a hit / a traversal (p = 0.70 / 0.40).
    l_min, l_max: clamping bounds of the log-odds.
    max_range: beams longer than this (m) are cut there and give no hit; None = no limit.
    margin: extra room added around new content when the grid grows, m.
    protect_hits: cells hit in a scan get no free update from that scan (keeps
        walls seen at grazing incidence from being erased by neighbouring beams).
    step_fraction: ray sampling step as a fraction of the resolution.
    max_cells: the most cells the grid may hold. The arrays take 5 bytes a cell and the
        map images a few times that while written: 5e7 cells (a 350 m square at 5 cm)
        stay near 1 GB, where points thrown kilometres off by a bad pose or a 10 µm
        resolution would otherwise ask for terabytes.
    """

    resolution: float = 0.05
    l_occ: float = 0.85
    l_free: float = -0.4
    l_min: float = -2.0
    l_max: float = 3.5
    max_range: float | None = None
    margin: float = 2.0
    protect_hits: bool = True
    step_fraction: float = 0.5
    max_cells: int = 50_000_000


@dataclass(frozen=True)
class ScanUpdate:
    """What casting one scan adds to any grid with the same parameters, on the global lattice.

    The cells are given in the scan's window, whose first row and column are the lattice's
    ``y0`` and ``x0``: cell ``i`` is lattice cell ``(x0 + cols[i], y0 + rows[i])``, each once;
    it gets ``increment[i]`` (float32), then the clamp to ``[l_min, l_max]``, and is observed.
    """

    y0: int
    x0: int
    rows: np.ndarray  # (M,) int32
    cols: np.ndarray  # (M,) int32
    increment: np.ndarray  # (M,) float32


class Scan:
    """One scan (static points, ``map``, m) from a sensor at ``origin`` (m), to be cast into one
    grid or several (:meth:`OccupancyGrid.add`): its :class:`ScanUpdate` is computed once per set
    of parameters, when a grid holding it is first read, and shared by the others."""

    def __init__(self, sensor_origin_xy: np.ndarray, points_map_xy: np.ndarray):
        self.origin = np.array(sensor_origin_xy, float).reshape(2)
        self.points = np.array(points_map_xy, float).reshape(-1, 2)
        self._updates: dict[OccupancyParams, ScanUpdate] = {}
        self._cells: dict[tuple[float | None, float], Cells] = {}
        self._waiting = 0  # grids that hold the scan queued, not yet applied

    def queued(self) -> None:
        """A grid queued the scan."""
        self._waiting += 1

    def applied(self) -> None:
        """A grid applied the scan: the cast is let go once no grid waits for it (a flush of
        32 scans would otherwise hold 32 casts, ~1 MB each, to its end)."""
        self._waiting -= 1
        if self._waiting <= 0:
            self._updates.clear()

    def update(self, params: OccupancyParams) -> ScanUpdate:
        """The scan cast with ``params`` (computed on the first call, then kept)."""
        if params not in self._updates:
            self._updates[params] = cast(self.origin, self.points, params)
        return self._updates[params]

    def cells(self, params: OccupancyParams) -> Cells:
        """:func:`scan_cells` of the scan with ``params`` (computed on the first call, then kept)."""
        key = (params.max_range, params.resolution)
        found = self._cells.get(key)
        if found is None:
            found = self._cells[key] = scan_cells(self.origin, self.points, params)
        return found

    def cast_already(self, params: OccupancyParams) -> ScanUpdate | None:
        """The scan cast with ``params`` if some grid already had it computed, else None."""
        return self._updates.get(params)


def rays(o: np.ndarray, pts: np.ndarray, p: OccupancyParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each beam (N, 2) from ``o`` (cut at ``max_range``), its length (N,) and whether it ends in a hit (N,)."""
    d = pts - o
    length = np.hypot(d[:, 0], d[:, 1])
    hit = np.ones(len(pts), bool)
    if p.max_range is not None:
        far = length > p.max_range
        d[far] *= (p.max_range / length[far])[:, None]
        length[far] = p.max_range
        hit[far] = False
    return d, length, hit


def scan_cells(o: np.ndarray, pts: np.ndarray, p: OccupancyParams) -> Cells:
    """The lattice cells ``(ix_lo, iy_lo, ix_hi, iy_hi)`` of the corners of the box that holds the sensor
    ``o`` (2,) and every beam's end (:func:`rays`, cut at ``max_range``) of ``pts`` (N, 2) (both ``map``,
    m): the cells a grid must hold to take the scan.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call, the same
    cells), else :func:`scan_cells_numpy`; numpy too for a scan the kernel declines (a coordinate not
    finite, a cell beyond ±2^62)."""
    core = compiled.core()
    if core is not None:
        ox, oy = o.tolist() if type(o) is np.ndarray and o.shape == (2,) else np.asarray(o, float).reshape(2).tolist()
        found = core.occupancy_scan_cells(np.ascontiguousarray(pts, dtype=float), ox, oy, p.max_range is not None,
                                          0.0 if p.max_range is None else p.max_range, p.resolution)
        if found is not None:
            return found
    return scan_cells_numpy(o, pts, p)


def scan_cells_numpy(o: np.ndarray, pts: np.ndarray, p: OccupancyParams) -> Cells:
    """:func:`scan_cells` in numpy: the reference the compiled kernel is tested against."""
    d, _, _ = rays(o, pts, p)
    end = o + d
    lo, hi = np.minimum(end.min(axis=0), o), np.maximum(end.max(axis=0), o)
    lo_c = np.floor(lo / p.resolution).astype(np.int64)
    hi_c = np.floor(hi / p.resolution).astype(np.int64)
    return lo_c[0], lo_c[1], hi_c[0], hi_c[1]  # int64 (a non-finite corner's cells wrap in int64 as they did)


def cast(o: np.ndarray, pts: np.ndarray, p: OccupancyParams) -> ScanUpdate:
    """Ray-cast one scan, ``pts`` (N ≥ 1, 2) seen from ``o`` (2,) (both ``map``, m), on the lattice.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call; the same
    cells and float32 increments, bit for bit), else :func:`cast_numpy`; numpy too for a scan the
    kernel declines (a coordinate not finite, a window of the lattice over ``max_cells``)."""
    core = compiled.core()
    if core is not None:
        ox, oy = np.asarray(o, float).reshape(2).tolist()
        found = core.occupancy_cast(
            np.ascontiguousarray(pts, dtype=float), ox, oy, p.resolution, p.step_fraction, p.l_occ, p.l_free,
            p.max_range is not None, 0.0 if p.max_range is None else p.max_range, p.protect_hits, p.max_cells)
        if found is not None:
            return ScanUpdate(*found)
    return cast_numpy(o, pts, p)


def cast_numpy(o: np.ndarray, pts: np.ndarray, p: OccupancyParams) -> ScanUpdate:
    """:func:`cast` in numpy: the reference the compiled kernel is tested against."""
    d, length, hit = rays(o, pts, p)
    end = o + d
    res = p.resolution
    ex = np.floor(end[:, 0] / res).astype(np.int64)  # global lattice indices
    ey = np.floor(end[:, 1] / res).astype(np.int64)

    # samples along every ray at sub-cell spacing, all rays at once
    step = p.step_fraction * res
    n = np.floor(length / step).astype(np.int64) + 1  # s = 0, step, ... ≤ length
    first = np.cumsum(n) - n  # each ray's first sample
    last = first + n - 1
    k = np.arange(int(n.sum()), dtype=np.int32)
    k -= np.repeat(first.astype(np.int32), n)
    s = k * step
    del k
    # min(s, length) changes only a ray's last sample: below it k·step ≤ (n - 2)·step < length
    s[last] = np.minimum(s[last], length)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, d / length[:, None], 0.0)
    sx, sy = np.repeat(u[:, 0], n), np.repeat(u[:, 1], n)
    for c, origin in ((sx, o[0]), (sy, o[1])):  # floor((o + u s) / res), in place
        c *= s
        c += origin
        c /= res
        np.floor(c, out=c)
    del s

    # work in the scan's bounding window of the lattice (cost independent of map size). The cell
    # indices along a ray are monotone in s, so a ray's extreme cells are those of its first and
    # last samples.
    ends = np.concatenate([first, last])
    x0, x1 = int(min(sx[ends].min(), ex.min())), int(max(sx[ends].max(), ex.max())) + 1
    y0, y1 = int(min(sy[ends].min(), ey.min())), int(max(sy[ends].max(), ey.max())) + 1
    ww, size = x1 - x0, (y1 - y0) * (x1 - x0)
    flat = sy  # flat index (sy - y0) * ww + (sx - x0), in place: whole numbers, exact in float64
    flat -= y0
    flat *= ww
    flat += sx
    flat -= x0
    del sx, sy
    end_flat = (ey - y0) * ww + (ex - x0)
    hit_cells, hit_counts = np.unique(end_flat[hit], return_counts=True)

    # one free update per (ray, cell): a cell's samples on a ray are consecutive (monotone), so
    # a ray counts a cell at its first sample there, unless that is the ray's own end cell
    new = np.empty(flat.size, bool)
    new[0] = True
    np.not_equal(flat[1:], flat[:-1], out=new[1:])
    new[first] = True  # a ray's first sample (its cell may repeat the last ray's)
    if not (p.protect_hits and hit.all()):  # else every end cell is a hit cell, zeroed below
        new &= flat != np.repeat(end_flat, n)
    # np.compress is 4x faster than flat[new]; then only the kept ~55 % converted to int
    cells = np.compress(new, flat).astype(np.intp)
    del flat, new
    free_counts = np.bincount(cells, minlength=size)
    if p.protect_hits:  # no free update where this scan hit
        free_counts[hit_cells] = 0
    # only the cells this scan reached change (the rest would get + 0 and a clip that keeps them)
    hit_inc = p.l_free * free_counts[hit_cells] + p.l_occ * hit_counts
    free_counts[hit_cells] = 0
    free_cells = np.flatnonzero(free_counts != 0)  # 6x faster than on the int64 counts
    touched = np.concatenate([free_cells, hit_cells])
    increment = np.concatenate([p.l_free * free_counts[free_cells], hit_inc]).astype(np.float32)
    rows, cols = np.divmod(touched, ww)
    return ScanUpdate(y0, x0, rows.astype(np.int32), cols.astype(np.int32), increment)


def lattice_cells(xy: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The global lattice column and row (N,) int64 of map points ``xy`` (N, 2) at ``resolution``
    (m): the cells every grid of that resolution shares, before a grid's origin is taken off."""
    ij = np.floor(np.asarray(xy, float) / resolution).astype(np.int64)
    return ij[:, 0], ij[:, 1]


class OccupancyGrid:
    """A growing log-odds occupancy grid (see module docstring for conventions)."""

    # ROS map_server / map_saver conventions (trinary mode, negate 0)
    OCCUPIED_THRESH = 0.65
    FREE_THRESH = 0.196
    SAVER_FREE = 25  # map_saver: int8 value ≤ 25 -> free pixel 254
    SAVER_OCCUPIED = 65  # map_saver: int8 value ≥ 65 -> occupied pixel 0

    def __init__(self, params: OccupancyParams = OccupancyParams()) -> None:
        self.params = params
        self._ix0 = 0
        self._iy0 = 0
        self._log_odds: np.ndarray = np.zeros((0, 0), np.float32)
        self._observed: np.ndarray = np.zeros((0, 0), bool)
        self._pending: list[Scan] = []

    # --- the grid, with every scan handed over cast into it --------------------------
    def flush(self) -> None:
        """Cast the queued scans, in the order they came."""
        pending, self._pending = self._pending, []
        for scan in pending:
            self._apply(scan.update(self.params))
            scan.applied()

    @property
    def log_odds(self) -> np.ndarray:
        """Log-odds (H, W), float32."""
        self.flush()
        return self._log_odds

    @property
    def observed(self) -> np.ndarray:
        """Cells any scan reached (H, W)."""
        self.flush()
        return self._observed

    def lattice_view(self) -> tuple[np.ndarray, int, int]:
        """``(log_odds, ix0, iy0)`` read together (the queued scans cast first, once)."""
        self.flush()
        return self._log_odds, self._ix0, self._iy0

    @property
    def ix0(self) -> int:
        """Global lattice column of array column 0."""
        self.flush()
        return self._ix0

    @property
    def iy0(self) -> int:
        """Global lattice row of array row 0."""
        self.flush()
        return self._iy0

    # --- geometry -----------------------------------------------------------------
    @property
    def resolution(self) -> float:
        """Cell size, m."""
        return self.params.resolution

    @property
    def width(self) -> int:
        """Cells along x (the queued scans cast first)."""
        return self.log_odds.shape[1]

    @property
    def height(self) -> int:
        """Cells along y (the queued scans cast first)."""
        return self.log_odds.shape[0]

    @property
    def origin(self) -> np.ndarray:
        """Map-frame (x, y) of the lower-left corner of cell [0, 0], m."""
        return np.array([self.ix0, self.iy0], float) * self.resolution

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """Array indices (N, 2) as (row, col) of map points (N, 2); may be out of bounds."""
        ix, iy = lattice_cells(xy, self.resolution)
        return np.stack([iy - self.iy0, ix - self.ix0], -1)

    def _ensure(self, lo_x: Any, lo_y: Any, hi_x: Any, hi_y: Any) -> None:
        """Grow the arrays (keeping content) so that the lattice cells [lo, hi] are inside."""
        res = self.resolution
        lo_c, hi_c = (lo_x, lo_y), (hi_x, hi_y)
        ix0, iy0 = self._ix0, self._iy0
        height, width = self._log_odds.shape
        if width and (
            lo_c[0] >= ix0 and lo_c[1] >= iy0 and hi_c[0] < ix0 + width and hi_c[1] < iy0 + height
        ):
            return
        m = int(np.ceil(self.params.margin / res))
        nx0, ny0 = lo_c[0] - m, lo_c[1] - m
        nx1, ny1 = hi_c[0] + m + 1, hi_c[1] + m + 1
        if width:
            nx0, ny0 = min(nx0, ix0), min(ny0, iy0)
            nx1, ny1 = max(nx1, ix0 + width), max(ny1, iy0 + height)
        self._check_size(int(nx1 - nx0), int(ny1 - ny0))
        lo_new = np.zeros((ny1 - ny0, nx1 - nx0), np.float32)
        ob_new = np.zeros(lo_new.shape, bool)
        if width:
            r0, c0 = iy0 - ny0, ix0 - nx0
            lo_new[r0 : r0 + height, c0 : c0 + width] = self._log_odds
            ob_new[r0 : r0 + height, c0 : c0 + width] = self._observed
        self._ix0, self._iy0 = int(nx0), int(ny0)
        self._log_odds, self._observed = lo_new, ob_new

    def _check_size(self, width: int, height: int) -> None:
        if width * height > self.params.max_cells:
            res = self.resolution
            raise MapSizeError(
                f"the occupancy grid would grow to {width} x {height} cells ({width * res:.4g} m x "
                f"{height * res:.4g} m at {res:g} m), over its budget of {self.params.max_cells:.3g} cells: "
                "points lie far beyond a floor's size, or the map resolution is too fine for the area")

    # --- update -------------------------------------------------------------------
    def integrate(self, sensor_origin_xy: np.ndarray, points_map_xy: np.ndarray) -> None:
        """Ray-cast one scan: free along each beam from the sensor, occupied at its end.

        ``sensor_origin_xy`` (2,) and ``points_map_xy`` (N, 2) in the map frame (m). The
        grid grows to hold the scan now: a map outgrowing ``max_cells`` raises
        :class:`~fmcwlog.errors.MapSizeError` here; the rays are cast when the grid is next read
        (module docstring).
        """
        self.add(Scan(sensor_origin_xy, points_map_xy))

    def add(self, scan: Scan) -> None:
        """:meth:`integrate` for a scan that other grids may receive too: they share its cast
        (raises :class:`~fmcwlog.errors.MapSizeError` as it does)."""
        if len(scan.points) == 0:
            return
        self._ensure(*scan.cells(self.params))
        self._settle()
        self._pending.append(scan)
        scan.queued()
        if len(self._pending) >= PENDING_SCANS:
            self.flush()

    def _settle(self) -> None:
        """Apply the queued scans, in order, as far as another grid has already cast them: no
        ray casting here, and their shared casts are not kept waiting for this grid's next read."""
        done = 0
        for scan in self._pending:
            update = scan.cast_already(self.params)
            if update is None:
                break
            self._apply(update)
            scan.applied()
            done += 1
        del self._pending[:done]

    def _apply(self, update: ScanUpdate) -> None:
        """Add a scan's increments to its cells, clamped (the arrays already hold them): the
        compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (the same float32
        values), else :meth:`_apply_numpy`."""
        core = compiled.core()
        if core is None:
            self._apply_numpy(update)
            return
        p = self.params
        core.occupancy_apply(
            self._log_odds, self._observed, update.y0 - self._iy0, update.x0 - self._ix0, update.rows, update.cols,
            update.increment, p.l_min, p.l_max)

    def _apply_numpy(self, update: ScanUpdate) -> None:
        """:meth:`_apply` in numpy: the reference the compiled kernel is tested against."""
        p = self.params
        width = self._log_odds.shape[1]
        at = update.rows.astype(np.intp)  # window -> flat array indices, in place
        at += update.y0 - self._iy0
        at *= width
        at += update.cols
        at += update.x0 - self._ix0
        log_odds = self._log_odds.reshape(-1)  # views of the contiguous arrays
        value = log_odds[at]
        value += update.increment
        np.clip(value, p.l_min, p.l_max, out=value)
        log_odds[at] = value
        self._observed.reshape(-1)[at] = True

    # --- export -------------------------------------------------------------------
    def probability(self) -> np.ndarray:
        """Occupancy probability (H, W), NaN where never observed."""
        prob = 1.0 / (1.0 + np.exp(-self.log_odds.astype(float)))
        return np.where(self.observed, prob, np.nan)

    def to_ros_int8(self) -> np.ndarray:
        """``nav_msgs/OccupancyGrid.data`` (H·W,) int8: -1 unknown, else round(100·p).

        Row-major starting at cell (0, 0) = ``origin`` (lowest y row first). The compiled kernel
        where :func:`fmcwlog.kernels.compiled.core` selects it (one pass, the same values: where
        its exp could round 100·p the other way than numpy's, numpy decides), else
        :meth:`to_ros_int8_numpy`.
        """
        core = compiled.core()
        if core is None:
            return self.to_ros_int8_numpy()
        log_odds, observed = self.log_odds, self.observed
        out = np.empty(log_odds.size, np.int8)
        unsure = core.occupancy_ros_int8(log_odds, observed, out)
        if unsure.size:
            prob = 1.0 / (1.0 + np.exp(-log_odds.reshape(-1)[unsure].astype(float)))
            out[unsure] = np.rint(100.0 * prob).astype(np.int8)
        return out

    def to_ros_int8_numpy(self) -> np.ndarray:
        """:meth:`to_ros_int8` in numpy: the reference the compiled kernel is tested against."""
        prob = self.probability()
        out = np.full(prob.shape, -1, np.int8)
        seen = self.observed
        out[seen] = np.rint(100.0 * prob[seen]).astype(np.int8)
        return out.reshape(-1)

    def to_pgm_bytes(self) -> bytes:
        """Binary PGM (P5) as map_saver writes it: 0 occupied, 254 free, 205 unknown.

        Thresholds on the int8 values as map_saver (≥ 65 occupied, ≤ 25 free);
        the image's top row is the grid's max-y row.
        """
        data = self.to_ros_int8().reshape(self.height, self.width)
        img = np.full(data.shape, 205, np.uint8)
        img[(data >= 0) & (data <= self.SAVER_FREE)] = 254
        img[data >= self.SAVER_OCCUPIED] = 0
        header = (
            f"P5\n# CREATOR: fmcwlog {self.resolution:.3f} m/pix\n"
            f"{self.width} {self.height}\n255\n"
        ).encode("ascii")
        return header + np.flipud(img).tobytes()

    def map_server_yaml(self, image_name: str) -> str:
        """map_server YAML for :meth:`to_pgm_bytes` saved as ``image_name``.

        ``origin`` is the map-frame pose of the lower-left pixel's corner (yaw 0).
        """
        ox, oy = self.origin
        return (
            f"image: {image_name}\n"
            "mode: trinary\n"
            f"resolution: {self.resolution:.6f}\n"
            f"origin: [{ox:.6f}, {oy:.6f}, 0.000000]\n"
            "negate: 0\n"
            f"occupied_thresh: {self.OCCUPIED_THRESH}\n"
            f"free_thresh: {self.FREE_THRESH}\n"
        )
