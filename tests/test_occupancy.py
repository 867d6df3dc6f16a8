"""Occupancy grid: a wall seen from a point, ray traversal, ROS map_server export."""

import numpy as np
import yaml

from fmcwlog.frontend.occupancy import OccupancyGrid, OccupancyParams

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
