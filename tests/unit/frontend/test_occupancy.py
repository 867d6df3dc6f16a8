"""Occupancy grid: a wall seen from a point, ray traversal, ROS map_server export."""

import numpy as np
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.kernels.occupancy import OccupancyGrid, OccupancyParams, Scan

RES = 0.05


def _wall_scan(origin=(0.0, 0.0), wall_x=3.01, half_fov=np.deg2rad(30), n=400):
    """Hits on the wall x = wall_x from ``origin`` over ±half_fov (map frame)."""
    ang = np.linspace(-half_fov, half_fov, n)
    ox, oy = origin
    r = (wall_x - ox) / np.cos(ang)
    return np.stack([ox + r * np.cos(ang), oy + r * np.sin(ang)], -1)


def _value_at(grid, xy):
    """ROS int8 value of the cell holding world point xy, from the exported data only."""
    data = grid.to_ros_int8().reshape(grid.height, grid.width)
    ox, oy = grid.origin
    col = int(np.floor((xy[0] - ox) / grid.resolution))
    row = int(np.floor((xy[1] - oy) / grid.resolution))
    return int(data[row, col])


def test_single_wall_occupied_free_unknown():
    g = OccupancyGrid(OccupancyParams(resolution=RES))
    pts = _wall_scan()
    g.integrate(np.zeros(2), pts)
    # occupied along the wall line (|y| < tan30°·3.01 ≈ 1.74)
    for y in np.arange(-1.5, 1.5, 0.1):
        assert _value_at(g, (3.01, y)) >= 65, y
    # free between sensor and wall inside the field of view
    for x in np.arange(0.2, 2.9, 0.1):
        assert 0 <= _value_at(g, (x, 0.3 * x)) <= 25, x
    # unknown behind the wall and outside the field of view
    assert _value_at(g, (3.6, 0.0)) == -1
    assert _value_at(g, (-1.0, 0.0)) == -1
    assert _value_at(g, (1.0, 1.5)) == -1  # bearing 56° > 30°
    # the wall is exactly one cell thick: x = 3.01 lies in column floor(3.01/0.05) = 60
    assert _value_at(g, (2.97, 0.0)) <= 25 and _value_at(g, (3.06, 0.0)) == -1


def test_log_odds_clamped_and_origin_on_lattice():
    p = OccupancyParams(resolution=RES)
    g = OccupancyGrid(p)
    for _ in range(20):
        g.integrate(np.zeros(2), _wall_scan())
    assert g.log_odds.max() <= p.l_max + 1e-6 and g.log_odds.min() >= p.l_min - 1e-6
    assert np.isclose(g.log_odds.max(), p.l_max) and np.isclose(g.log_odds.min(), p.l_min)
    np.testing.assert_allclose(g.origin / RES, np.round(g.origin / RES), atol=1e-9)


def test_ray_cells_match_a_fine_reference_traversal():
    # one long oblique ray; a 1/100-cell sampling is the reference set of crossed cells
    g = OccupancyGrid(OccupancyParams(resolution=RES, protect_hits=False))
    o, end = np.array([0.013, -0.021]), np.array([4.217, 2.633])
    g.integrate(o, end[None])
    s = np.linspace(0, 1, 200_000)[:, None]
    ref = {tuple(c) for c in np.floor((o + s * (end - o)) / RES).astype(int)}
    ref.discard(tuple(np.floor(end / RES).astype(int)))
    rows, cols = np.nonzero(g.observed & (g.log_odds < 0))
    got = {(c + g.ix0, r + g.iy0) for r, c in zip(rows, cols)}
    assert got <= ref  # every freed cell really is on the ray
    assert len(got) >= 0.85 * len(ref)  # only corner-clipped cells may be skipped
    assert g.log_odds[tuple(g.cell_of(end[None])[0])] > 0  # the end cell is occupied


def test_grid_grows_and_keeps_content():
    g = OccupancyGrid(OccupancyParams(resolution=RES, margin=0.5))
    g.integrate(np.zeros(2), _wall_scan())
    before = _value_at(g, (3.01, 0.0))
    g.integrate(np.array([20.0, -15.0]), _wall_scan(origin=(20.0, -15.0), wall_x=23.01))
    assert g.origin[0] <= -0.5 and g.origin[1] <= -15.5
    assert _value_at(g, (3.01, 0.0)) == before
    assert _value_at(g, (23.01, -15.0)) >= 65
    assert _value_at(g, (10.0, -7.0)) == -1


def test_max_range_cuts_beams_without_hits():
    g = OccupancyGrid(OccupancyParams(resolution=RES, max_range=2.0))
    g.integrate(np.zeros(2), _wall_scan())
    assert _value_at(g, (1.5, 0.0)) <= 25
    assert _value_at(g, (3.01, 0.0)) == -1  # beyond range: no hit recorded
    assert _value_at(g, (2.5, 0.0)) == -1


def test_pgm_and_yaml_follow_map_server_conventions():
    g = OccupancyGrid(OccupancyParams(resolution=RES))
    g.integrate(np.array([0.4, -0.7]), _wall_scan(origin=(0.4, -0.7)))
    pgm = g.to_pgm_bytes()
    # parse the PGM independently: magic, optional comment lines, size, maxval
    lines = pgm.split(b"\n")
    assert lines[0] == b"P5"
    i = 1
    while lines[i].startswith(b"#"):
        i += 1
    w, h = map(int, lines[i].split())
    assert lines[i + 1] == b"255"
    header_len = len(b"\n".join(lines[: i + 2])) + 1
    img = np.frombuffer(pgm[header_len:], np.uint8)
    assert img.size == w * h and (w, h) == (g.width, g.height)
    img = img.reshape(h, w)
    assert set(np.unique(img)) <= {0, 205, 254}

    meta = yaml.safe_load(g.map_server_yaml("map.pgm"))
    assert meta["image"] == "map.pgm" and meta["negate"] == 0
    assert meta["occupied_thresh"] == 0.65 and meta["free_thresh"] == 0.196
    assert meta["resolution"] == RES

    def pixel(x, y):  # map_server: origin = lower-left pixel corner, top row = max y
        col = int(np.floor((x - meta["origin"][0]) / meta["resolution"]))
        row = h - 1 - int(np.floor((y - meta["origin"][1]) / meta["resolution"]))
        return int(img[row, col])

    def occ(v):  # map_server's interpretation with negate 0
        return (255 - v) / 255.0

    assert occ(pixel(3.01, -0.7)) > meta["occupied_thresh"]
    assert occ(pixel(1.5, -0.7)) < meta["free_thresh"]
    wall_dist_unknown = occ(pixel(3.5, -0.7))
    assert meta["free_thresh"] < wall_dist_unknown < meta["occupied_thresh"]


def test_empty_scan_is_a_no_op():
    g = OccupancyGrid()
    g.integrate(np.zeros(2), np.zeros((0, 2)))
    assert g.to_ros_int8().size == 0


# ----------------------------------------------------------------------------- the cast, shared or not


def _reference_grid(scans, p: OccupancyParams) -> dict[tuple[int, int], tuple[np.float32, bool]]:
    """The module docstring's rules, one ray at a time in plain Python (a second implementation):
    per scan, a ray frees each lattice cell its samples ``min(k·step, length)`` fall in once,
    never its own end cell, and hits its end cell unless cut at ``max_range``; a hit cell gets no
    free update from its scan with ``protect_hits``; the scan's float32 increments are added and
    clamped. Returns ``{(ix, iy): (log-odds, observed)}`` of the cells any scan reached."""
    res, step = p.resolution, p.step_fraction * p.resolution
    grid: dict[tuple[int, int], np.float32] = {}
    for origin, points in scans:
        free: dict[tuple[int, int], int] = {}
        hits: dict[tuple[int, int], int] = {}
        for point in points:
            d = point - origin
            length = float(np.hypot(d[0], d[1]))
            hit = p.max_range is None or length <= p.max_range
            if not hit:
                d = d * (p.max_range / length)
                length = p.max_range
            end = origin + d
            end_cell = (int(np.floor(end[0] / res)), int(np.floor(end[1] / res)))
            u = d / length if length > 0 else np.zeros(2)
            if hit:
                hits[end_cell] = hits.get(end_cell, 0) + 1
            seen = set()
            for k in range(int(np.floor(length / step)) + 1):
                s = min(k * step, length)
                cell = (int(np.floor((origin[0] + u[0] * s) / res)), int(np.floor((origin[1] + u[1] * s) / res)))
                if cell != end_cell and cell not in seen:
                    seen.add(cell)
                    free[cell] = free.get(cell, 0) + 1
        for cell in set(free) | set(hits):
            n_free = 0 if (p.protect_hits and cell in hits) else free.get(cell, 0)
            inc = np.float32(p.l_free * n_free + p.l_occ * hits[cell]) if cell in hits else np.float32(p.l_free * n_free)
            if cell in grid or inc != 0 or cell in hits or n_free:
                value = grid.get(cell, np.float32(0)) + inc
                grid[cell] = np.float32(min(max(value, np.float32(p.l_min)), np.float32(p.l_max)))
    return {cell: (value, True) for cell, value in grid.items()}


def _cells(g: OccupancyGrid) -> dict[tuple[int, int], tuple[np.float32, bool]]:
    rows, cols = np.nonzero(g.observed)
    return {(int(c) + g.ix0, int(r) + g.iy0): (g.log_odds[r, c], True) for r, c in zip(rows, cols)}


_scan_sets = st.lists(
    st.tuples(st.floats(-3, 3), st.floats(-3, 3),  # the sensor, m
              st.lists(st.tuples(st.floats(0, 7), st.floats(-np.pi, np.pi)), min_size=1, max_size=25),
              st.integers(0, 3)),  # how often the scan's first point is repeated (hits pile up)
    min_size=1, max_size=4)


@settings(max_examples=60, deadline=None)
@given(scans=_scan_sets, resolution=st.sampled_from([0.05, 0.1, 0.037]),
       max_range=st.sampled_from([None, 4.0]), protect_hits=st.booleans(), step_fraction=st.sampled_from([0.5, 0.3]))
def test_cast_equals_a_per_ray_reference_bit_for_bit(scans, resolution, max_range, protect_hits, step_fraction):
    """Whatever the scans (zero-length beams, beams cut at max_range, repeated points, cells
    clamped), the vectorised cast gives the per-ray reference's float32 log-odds exactly, and
    marks observed exactly the cells the reference reached."""
    p = OccupancyParams(resolution=resolution, max_range=max_range, protect_hits=protect_hits,
                        step_fraction=step_fraction, l_max=1.0, margin=0.2)
    built = []
    for ox, oy, beams, repeats in scans:
        origin = np.array([ox, oy])
        points = origin + np.array([[r * np.cos(a), r * np.sin(a)] for r, a in beams])
        built.append((origin, np.concatenate([points, np.repeat(points[:1], repeats, axis=0)])))
    g = OccupancyGrid(p)
    for origin, points in built:
        g.integrate(origin, points)
    got, want = _cells(g), _reference_grid(built, p)
    assert got.keys() == want.keys()
    assert all(got[c][0].tobytes() == want[c][0].tobytes() for c in want)


def test_a_scan_shared_by_two_grids_is_cast_once_and_gives_each_its_own_cast(monkeypatch):
    """The recent grid and the method's grid get the same Scan objects: each grid ends as it
    would casting every scan for itself (in its own extent, with its own earlier content and
    clamping), and each scan is ray-cast once, whichever grid is read first."""
    import fmcwlog.kernels.occupancy as occupancy

    rng = np.random.default_rng(3)
    scans = []
    for k in range(12):
        origin = np.array([0.4 * k, 0.1 * np.sin(k)])
        scans.append((origin, _wall_scan(origin=tuple(origin), wall_x=origin[0] + 2.0 + rng.random(), n=200)))
    p = OccupancyParams(resolution=RES)
    alone_a, alone_b, shared_a, shared_b = (OccupancyGrid(p) for _ in range(4))
    for g in (alone_b, shared_b):  # b holds content a does not
        for origin, points in scans[:3]:
            g.integrate(origin + [0.0, 3.0], points + [0.0, 3.0])
        g.flush()
    for origin, points in scans:
        alone_a.integrate(origin, points)
        alone_b.integrate(origin, points)
    alone_a.flush(), alone_b.flush()
    casts = []
    real_cast = occupancy.cast
    monkeypatch.setattr(occupancy, "cast", lambda *args: casts.append(1) or real_cast(*args))
    for k, (origin, points) in enumerate(scans):
        scan = Scan(origin, points)
        shared_a.add(scan)
        shared_b.add(scan)
        if k % 3 == 0:
            _ = shared_a.log_odds  # a is read as the tracker reads it; b is left queued
        if k == 7:
            _ = shared_b.log_odds  # then b first
    for shared, alone in ((shared_a, alone_a), (shared_b, alone_b)):
        assert (shared.ix0, shared.iy0) == (alone.ix0, alone.iy0)
        assert shared.log_odds.tobytes() == alone.log_odds.tobytes()
        assert np.array_equal(shared.observed, alone.observed)
    assert len(casts) == len(scans)
    assert scan.cast_already(p) is None  # let go once both grids applied it
