"""The tracker's grid lookups (:mod:`fmcwlog.frontend.recent_grid`) against the plain formula they
replaced: each grid's cells found with :meth:`OccupancyGrid.cell_of` and read by (row, col), 0
outside, the sums over the recent grids taken point by point."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.occupancy import OccupancyGrid, OccupancyParams, Scan
from fmcwlog.frontend.recent_grid import RecentOccupancy, local_max_log_odds

AROUND = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)]


def _reference(grid: OccupancyGrid, map_xy: np.ndarray) -> np.ndarray:
    """(N, 9) log-odds (float32) of each point's cell and its 8 neighbours, 0 outside the grid."""
    out = np.zeros((len(map_xy), len(AROUND)), np.float32)
    height, width = grid.log_odds.shape
    for n, (row, col) in enumerate(grid.cell_of(map_xy)):
        for k, (dr, dc) in enumerate(AROUND):
            r, c = row + dr, col + dc
            if 0 <= r < height and 0 <= c < width:
                out[n, k] = grid.log_odds[r, c]
    return out


def _reference_seen_free(recent: RecentOccupancy, map_xy, candidates, threshold) -> np.ndarray:
    """The formula before: the summed log-odds of the own cell (float64, grid by grid), then the
    largest summed log-odds around the candidates that passed."""
    own = np.zeros(len(map_xy))
    around = np.zeros((len(map_xy), len(AROUND)))
    for grid in recent.grids:
        values = _reference(grid, map_xy)
        own += values[:, 4]
        around += values
    free = np.flatnonzero((own <= threshold) & candidates)
    out = np.zeros(len(map_xy), bool)
    out[free] = around[free].max(axis=1) <= threshold
    return out


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
def test_seen_free_and_local_max_are_the_plain_lookups(scans, resolution, window, margin, queries, threshold, seed):
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
    want = _reference_seen_free(recent, map_xy, candidates, threshold)
    np.testing.assert_array_equal(recent.seen_free(map_xy, candidates, threshold), want)
    got = local_max_log_odds(grid, map_xy)
    want_max = _reference(grid, map_xy).max(axis=1)
    assert got.dtype == want_max.dtype and got.tobytes() == want_max.tobytes()


def test_lookups_of_no_points_and_of_empty_grids():
    recent = RecentOccupancy(45.0, 0.05)
    assert recent.seen_free(np.zeros((0, 2)), np.zeros(0, bool), -1.2).shape == (0,)
    assert not recent.seen_free(np.ones((3, 2)), np.ones(3, bool), -1.2).any()  # no grid yet: nothing seen
    assert recent.seen_free(np.ones((3, 2)), np.ones(3, bool), 0.0).all()  # 0 everywhere, ≤ 0
    assert local_max_log_odds(OccupancyGrid(), np.ones((2, 2))).tolist() == [0.0, 0.0]
    assert local_max_log_odds(OccupancyGrid(), np.zeros((0, 2))).shape == (0,)
