"""The compiled ``TargetGrid``'s nearest point against a brute-force search and ``cKDTree``.

Every answer must be exact: the index of the nearest target point closer than the radius (ties,
equal squared distances, to the lowest index), its distance to the bit (that of
``cKDTree.query(q, distance_upper_bound=radius)``), and none (-1, inf) where no point is closer than
the radius, for queries anywhere: on the map, far from it, not finite. Maps: random clouds, many
duplicates on a lattice (exact ties across cells), collinear walls, points exactly at the radius,
maps far from the origin and maps so wide that the grid widens its cells.
"""

import numpy as np
import pytest
from helpers import CORE, needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree


def grid_nearest(points: np.ndarray, queries: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The grid's index (-1: none) and distance (inf: none) of each query (identity pose)."""
    grid = CORE.TargetGrid(np.ascontiguousarray(points, dtype=float).reshape(-1, 2), radius)
    q = np.ascontiguousarray(queries, dtype=float)
    n = len(q)
    moved, index, dist = np.empty((n, 2)), np.empty(n, np.int64), np.empty(n)
    CORE.nearest(grid, q, 0.0, 0.0, 0.0, moved, index, dist)
    finite = np.isfinite(q).all(axis=1)
    np.testing.assert_array_equal(moved[finite], q[finite])  # the identity pose moves nothing
    return index, dist


def brute_nearest(points: np.ndarray, queries: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The lowest index of the least squared distance (dx² + dy², the KD-tree's arithmetic), and
    its root, where that root is below the radius; else -1 and inf."""
    index, dist = np.full(len(queries), -1, np.int64), np.full(len(queries), np.inf)
    for k, (qx, qy) in enumerate(queries):
        if not (np.isfinite(qx) and np.isfinite(qy)) or len(points) == 0:
            continue
        dx, dy = points[:, 0] - qx, points[:, 1] - qy
        with np.errstate(over="ignore", invalid="ignore"):
            d2 = dx * dx + dy * dy
        d2[np.isnan(d2)] = np.inf  # a point not finite is never the nearest
        j = int(np.argmin(d2))  # the first of the least
        d = np.sqrt(d2[j])
        if d < radius:
            index[k], dist[k] = j, d
    return index, dist


def assert_exact(points: np.ndarray, queries: np.ndarray, radius: float) -> None:
    """The grid equals the brute force bit for bit, and cKDTree's distances (its index where no tie)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    queries = np.asarray(queries, dtype=float).reshape(-1, 2)
    index, dist = grid_nearest(points, queries, radius)
    ref_index, ref_dist = brute_nearest(points, queries, radius)
    np.testing.assert_array_equal(index, ref_index)
    assert dist.tobytes() == ref_dist.tobytes()
    if len(points) == 0 or not np.isfinite(points).all():  # cKDTree takes finite points only
        return
    finite = np.isfinite(queries).all(axis=1)
    kd_dist, kd_index = cKDTree(points).query(queries[finite], distance_upper_bound=radius)
    assert kd_dist.tobytes() == dist[finite].tobytes()
    found = kd_index < len(points)
    np.testing.assert_array_equal(found, index[finite] >= 0)
    kd_pts, ours = points[kd_index[found]], points[index[finite][found]]
    q = queries[finite][found]
    d2 = lambda p: (p[:, 0] - q[:, 0]) ** 2 + (p[:, 1] - q[:, 1]) ** 2  # noqa: E731
    assert d2(kd_pts).tobytes() == d2(ours).tobytes()  # a tie at most
    assert (index[finite][found] <= kd_index[found]).all()  # ours the lowest of a tie


def _queries(rng: np.random.Generator, points: np.ndarray, n: int, spread: float) -> np.ndarray:
    """Queries near points (on them, a little off), anywhere around the map, and far away."""
    lo, hi = points.min(axis=0) - spread, points.max(axis=0) + spread
    near = points[rng.integers(0, len(points), n)] + rng.normal(0.0, spread / 10, (n, 2))
    on = points[rng.integers(0, len(points), n // 4)]
    around = rng.uniform(lo, hi, (n, 2))
    far = rng.uniform(-1.0, 1.0, (n // 4, 2)) * 1e4
    return np.concatenate([near, on, around, far])


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 400), extent=st.sampled_from([0.3, 2.0, 20.0]),
       radius=st.sampled_from([0.05, 0.1, 0.5, 1.0, 3.0]))
def test_random_clouds(seed, m, extent, radius):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-extent, extent, (m, 2))
    assert_exact(points, _queries(rng, points, 200, radius), radius)


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 300), step=st.sampled_from([0.125, 0.1, 0.25, 0.03]),
       radius=st.sampled_from([0.1, 0.25, 0.5]))
def test_lattice_duplicates_and_ties(seed, m, step, radius):
    """Points on a small lattice, many repeated; queries on the lattice and half-way between
    lattice points, so that several points, in several cells, are exactly as near."""
    rng = np.random.default_rng(seed)
    points = rng.integers(-6, 7, (m, 2)) * step
    points = np.concatenate([points, points[rng.integers(0, m, m // 2)]])  # duplicates, later indices
    rng.shuffle(points)
    half = rng.integers(-14, 15, (300, 2)) * (step / 2)
    assert_exact(points, np.concatenate([half, points[:50]]), radius)


@needs_core
@pytest.mark.parametrize("radius", [0.1, 0.5, 2.0])
def test_collinear_walls(radius):
    """Walls of evenly spaced points (the maps a 2-D LiDAR makes), queries on both sides and along them."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 12.0, 0.03)
    walls = [np.stack([t, np.zeros_like(t)], 1), np.stack([np.full_like(t, 4.0), t - 2.0], 1),
             np.stack([t * 0.6, 1.0 + t * 0.8], 1)]
    points = np.concatenate(walls)
    queries = np.concatenate([points + rng.normal(0.0, 0.05, points.shape),
                              points + rng.normal(0.0, radius, points.shape),
                              np.stack([t, np.full_like(t, radius)], 1),  # exactly the radius off the first wall
                              np.stack([t + 0.015, np.zeros_like(t)], 1)])  # half-way between two wall points
    assert_exact(points, queries, radius)


@needs_core
def test_points_at_the_radius():
    """A point exactly the radius away is not within it; one an ulp nearer is."""
    r = 0.5
    points = np.array([[r, 0.0], [0.0, -r], [-r, 0.0], [0.0, r], [3.0, 3.0]])
    queries = np.array([[0.0, 0.0], [np.nextafter(0.0, 1.0), 0.0], [1e-9, 0.0], [3.0 - r, 3.0], [3.0, 3.0 + r]])
    assert_exact(points, queries, r)
    index, dist = grid_nearest(points, queries[:1], r)
    assert index[0] == -1 and dist[0] == np.inf
    index, dist = grid_nearest(points, np.array([[1e-9, 0.0]]), r)
    assert index[0] == 0 and dist[0] < r


@needs_core
def test_queries_not_finite_and_far():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    queries = np.array([[np.nan, 0.0], [0.0, np.nan], [np.inf, 0.0], [-np.inf, np.inf], [1e300, 0.0],
                        [-1e12, 3.0], [0.2, 0.1]])
    index, dist = grid_nearest(points, queries, 0.5)
    np.testing.assert_array_equal(index, [-1, -1, -1, -1, -1, -1, 0])
    assert (dist[:6] == np.inf).all()
    assert_exact(points, queries[4:], 0.5)


@needs_core
def test_points_not_finite():
    """Points with a NaN or infinite coordinate are never an answer, and leave the others' cells alone."""
    rng = np.random.default_rng(5)
    points = rng.uniform(-3.0, 3.0, (200, 2))
    points[::7, 0] = np.nan
    points[3::11, 1] = np.inf
    points[5::13] = -np.inf
    queries = _queries(rng, points[np.isfinite(points).all(axis=1)], 300, 0.5)
    assert_exact(points, queries, 0.5)
    index, _ = grid_nearest(np.full((4, 2), np.nan), queries[:20], 0.5)
    assert (index == -1).all()


@needs_core
def test_empty_and_single_point_maps():
    queries = np.array([[0.0, 0.0], [0.3, 0.0], [5.0, 5.0]])
    index, dist = grid_nearest(np.empty((0, 2)), queries, 0.5)
    assert (index == -1).all() and (dist == np.inf).all()
    assert_exact(np.array([[0.1, -0.2]]), queries, 0.5)


@needs_core
@pytest.mark.parametrize("offset", [0.0, 5e5, -3e6])
def test_wide_and_far_maps(offset):
    """Maps too wide for cells half the radius (the grid widens them) and maps far from the origin
    (the cells' boxes must still hold every point the rounding puts in them)."""
    rng = np.random.default_rng(11)
    clusters = rng.uniform(-2500.0, 2500.0, (40, 2))
    points = (clusters[rng.integers(0, 40, 3000)] + rng.normal(0.0, 0.4, (3000, 2))) + offset
    queries = _queries(rng, points, 1500, 0.5)
    for radius in (0.05, 0.5, 4.0):
        assert_exact(points, queries, radius)
