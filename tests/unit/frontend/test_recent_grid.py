"""The tracker's grid lookups (:mod:`fmcwlog.frontend.recent_grid`) against the same quantities
computed another way: every grid laid onto one dense canvas of the shared lattice (cells outside a
grid hold 0), the recent grids summed there, and the largest value around each cell taken by
``scipy.ndimage.maximum_filter`` over the whole canvas, not by looking up each point's 9 cells."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.ndimage import maximum_filter

from fmcwlog.frontend.recent_grid import RecentOccupancy, local_max_log_odds
from fmcwlog.kernels.occupancy import OccupancyGrid, OccupancyParams, Scan


def _canvas(grids, resolution: float, map_xy: np.ndarray, dtype):
    """The grids' log-odds summed (in the grids' order) on one array of the lattice that holds them
    all and every point with a cell to spare; and each point's (row, col) on it."""
    cells = np.floor(map_xy / resolution).astype(np.int64)  # (ix, iy) on the lattice every grid shares
    lo = np.min([cells.min(0), *((g.ix0, g.iy0) for g in grids)], axis=0) - 1
    hi = np.max([cells.max(0), *((g.ix0 + g.width - 1, g.iy0 + g.height - 1) for g in grids)], axis=0) + 1
    canvas = np.zeros((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), dtype)
    for g in grids:
        canvas[g.iy0 - lo[1]:g.iy0 - lo[1] + g.height, g.ix0 - lo[0]:g.ix0 - lo[0] + g.width] += g.log_odds
    return canvas, cells[:, 1] - lo[1], cells[:, 0] - lo[0]


def _seen_free(recent: RecentOccupancy, map_xy, candidates, threshold) -> np.ndarray:
    """Candidates whose cell and each of its 8 neighbours sum to at most ``threshold`` over the grids."""
    canvas, row, col = _canvas(recent.grids, recent.resolution, map_xy, np.float64)
    around = maximum_filter(canvas, size=3, mode="constant", cval=0.0)
    return candidates & (canvas[row, col] <= threshold) & (around[row, col] <= threshold)


def _local_max(grid: OccupancyGrid, map_xy) -> np.ndarray:
    """The largest float32 log-odds among each point's cell and its 8 neighbours (0 outside the grid)."""
    canvas, row, col = _canvas([grid], grid.resolution, map_xy, np.float32)
    return maximum_filter(canvas, size=3, mode="constant", cval=0.0)[row, col]


def _borders(grid: OccupancyGrid) -> np.ndarray:
    """Points in the cells along the grid's four edges and in those just outside them."""
    res = grid.resolution
    (x0, y0), width, height = grid.origin, grid.width, grid.height
    xs = x0 + (np.arange(-1, width + 1) + 0.5) * res
    ys = y0 + (np.arange(-1, height + 1) + 0.5) * res
    rows = [np.column_stack([xs, np.full(xs.size, y)]) for y in (ys[0], ys[1], ys[-2], ys[-1])]
    cols = [np.column_stack([np.full(ys.size, x), ys]) for x in (xs[0], xs[1], xs[-2], xs[-1])]
    return np.concatenate(rows + cols)


_scans = st.lists(
    st.tuples(st.floats(-4, 4), st.floats(-4, 4),  # the sensor, m
              st.lists(st.tuples(st.floats(0.2, 6), st.floats(-np.pi, np.pi)), min_size=1, max_size=30),
              st.floats(0, 20)),  # path travelled before this scan, m
    min_size=1, max_size=6)


@settings(max_examples=60, deadline=None)
@given(scans=_scans, resolution=st.sampled_from([0.05, 0.1, 0.037]), window=st.sampled_from([5.0, 30.0]),
       margin=st.sampled_from([0.0, 2.0]), queries=st.lists(st.tuples(st.floats(-12, 12), st.floats(-12, 12)),
                                                            max_size=40),
       threshold=st.sampled_from([-1.2, -0.4, 0.0, 0.85]), seed=st.integers(0, 3))
def test_seen_free_and_local_max_are_the_canvas_maxima(scans, resolution, window, margin, queries, threshold, seed):
    """Points inside, at the edge of and outside the grids (margin 0: content on the edge), several
    recent grids or one, any threshold: the same verdicts and the same float32 maxima."""
    recent = RecentOccupancy(window, resolution)
    grid = OccupancyGrid(OccupancyParams(resolution=resolution, margin=margin))
    points = []
    path = 0.0
    for ox, oy, beams, travelled in scans:
        origin = np.array([ox, oy])
        hits = origin + np.array([[r * np.cos(a), r * np.sin(a)] for r, a in beams])
        points.append(hits)
        path += travelled
        scan = Scan(origin, hits)
        grid.add(scan)
        recent.integrate(scan, path)
    hits = np.concatenate(points)
    rng = np.random.default_rng(seed)
    map_xy = np.concatenate([hits, hits + rng.normal(0, 2 * resolution, hits.shape),
                             np.array(queries, float).reshape(-1, 2),
                             *(_borders(g) for g in [grid, *recent.grids])])
    candidates = rng.random(len(map_xy)) < 0.8
    want = _seen_free(recent, map_xy, candidates, threshold)
    np.testing.assert_array_equal(recent.seen_free(map_xy, candidates, threshold), want)
    got = local_max_log_odds(grid, map_xy)
    want_max = _local_max(grid, map_xy)
    assert got.dtype == want_max.dtype and got.tobytes() == want_max.tobytes()


def test_lookups_of_no_points_and_of_empty_grids():
    recent = RecentOccupancy(45.0, 0.05)
    assert recent.seen_free(np.zeros((0, 2)), np.zeros(0, bool), -1.2).shape == (0,)
    assert not recent.seen_free(np.ones((3, 2)), np.ones(3, bool), -1.2).any()  # no grid yet: nothing seen
    assert recent.seen_free(np.ones((3, 2)), np.ones(3, bool), 0.0).all()  # 0 everywhere, ≤ 0
    assert local_max_log_odds(OccupancyGrid(), np.ones((2, 2))).tolist() == [0.0, 0.0]
    assert local_max_log_odds(OccupancyGrid(), np.zeros((0, 2))).shape == (0,)
