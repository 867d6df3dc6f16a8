"""Feature lengths measured in a map, against maps of known geometry.

Two kinds of maps of the ``corridor`` floor (the paper's nine features):

- rasterised: the world's walls drawn cell by cell into a map_server pgm/yaml written
  here by hand (not by fmcwlog's writer), in a method frame rotated and moved away from
  the world's; every cell is where the geometry says, so lengths are known to a cell;
- scanned: a 270° scanner with 2 cm range noise and 8 m range, cast here against the
  walls (a ray caster of this file, not the simulator's) from poses along a path; the
  returns are placed with the poses a "method" reports and ray-cast into fmcwlog's own
  occupancy grid, as the front ends build their maps. A pose jump injected into those
  poses distorts the map by a known amount.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fmcwlog.errors import ReportError
from fmcwlog.evaluation.features import CORNER, WALL_END, end_shape, feature_lengths
from fmcwlog.evaluation.map_geometry import fit_wall
from fmcwlog.geometry import compose, inverse, transform_points
from fmcwlog.io.map_files import read_map_server
from fmcwlog.io.outputs import write_grid, write_tum
from fmcwlog.kernels.occupancy import OccupancyGrid
from fmcwlog.sim.scenarios import H, W, corridor

RES = 0.05
WORLD = corridor()
WALLS = WORLD.walls
FEATURES = [{"id": f.id, "name": f.name, "a": list(f.a), "b": list(f.b)} for f in WORLD.features]
TRUE = {f["id"]: float(np.hypot(*np.subtract(f["b"], f["a"]))) for f in FEATURES}
LAP = np.array([[1.5, 1.5], [W - 1.5, 1.5], [W - 1.5, H - 1.5], [1.5, H - 1.5], [1.5, 1.5]])


def _path(corners: np.ndarray, step: float) -> np.ndarray:
    """Poses (N, 3) every ``step`` m along a polyline, heading along it."""
    out = []
    for a, b in zip(corners[:-1], corners[1:]):
        n = max(int(np.hypot(*(b - a)) / step), 1)
        yaw = np.arctan2(*(b - a)[::-1])
        out += [[*(a + (b - a) * k / n), yaw] for k in range(n)]
    return np.array(out)


def _write_map(folder: Path, name: str, occupied: np.ndarray, origin: tuple[float, float]) -> None:
    """map_server files by hand: P5 pgm (0 occupied, 254 free, top row = highest y) and yaml."""
    img = np.where(occupied, 0, 254).astype(np.uint8)[::-1]
    h, w = img.shape
    (folder / f"{name}.pgm").write_bytes(f"P5\n# hand-made\n{w} {h}\n255\n".encode() + img.tobytes())
    (folder / f"{name}.yaml").write_text(f"image: {name}.pgm\nresolution: {RES}\norigin: [{origin[0]}, {origin[1]}, 0.0]\n"
                                         "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")


def _rasterised(folder: Path, walls: np.ndarray, frame: np.ndarray, poses: np.ndarray, name: str = "m") -> Path:
    """The walls (world) drawn into a map in the method frame ``frame`` (the world in that frame),
    with ``poses`` (world) written as the method's trajectory in it."""
    folder.mkdir(parents=True, exist_ok=True)
    pts = []
    for x0, y0, x1, y1 in walls:
        n = int(np.hypot(x1 - x0, y1 - y0) / (RES / 8)) + 2
        pts.append(np.column_stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)]))
    xy = transform_points(frame, np.vstack(pts))
    origin = np.floor(xy.min(axis=0)) - 1.0 + np.array([0.013, -0.021])  # cells off the walls' round numbers
    ij = np.floor((xy - origin) / RES).astype(int)
    occupied = np.zeros(ij.max(axis=0)[::-1] + 3, bool)
    occupied[ij[:, 1], ij[:, 0]] = True
    _write_map(folder, f"{name}_map", occupied, (float(origin[0]), float(origin[1])))
    write_tum(folder / f"{name}.tum", np.arange(len(poses)) * 250_000_000, compose(frame, poses))
    return folder


def _gt(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.arange(len(poses), dtype=np.int64) * 250_000_000, poses


def _measure(folder: Path, poses: np.ndarray, name: str = "m") -> dict[int, dict]:
    rows = feature_lengths(folder, [name], FEATURES, WALLS, *_gt(poses))[name]
    return {r["id"]: r for r in rows}


# --------------------------------------------------------------------- what the truth says an end is


def test_the_world_says_which_ends_are_corners_and_which_are_wall_ends():
    kinds = {f["id"]: tuple(end_shape(np.array(f[k]), WALLS).kind for k in "ab") for f in FEATURES}
    assert kinds == {1: (CORNER, CORNER), 2: (CORNER, WALL_END), 3: (CORNER, WALL_END), 4: (WALL_END, WALL_END),
                     5: (CORNER, WALL_END), 6: (WALL_END, WALL_END), 7: (CORNER, WALL_END), 8: (CORNER, CORNER),
                     9: (CORNER, CORNER)}
    jamb = end_shape(np.array([9.775, 3.0]), WALLS)  # the hall's south wall stops here, going west
    assert np.allclose(jamb.arms[0][0], [-1, 0]) and jamb.arms[0][1] == pytest.approx(6.775)
    assert end_shape(np.array([5.0, 0.0]), WALLS).kind is None  # the middle of a straight wall
    assert "no wall" in end_shape(np.array([5.0, 5.0]), WALLS).reason  # the hall's empty floor


# --------------------------------------------------------------------- rasterised maps


FRAMES = {"world": np.zeros(3), "moved and turned": np.array([-4.2, 7.9, 0.7])}


@pytest.mark.parametrize("frame", FRAMES.values(), ids=FRAMES.keys())
def test_a_rasterised_floor_measures_every_feature_to_a_cell(tmp_path, frame):
    poses = _path(LAP, 0.25)
    rows = _measure(_rasterised(tmp_path, WALLS, frame, poses), poses)
    for fid, r in rows.items():
        assert r["measured_m"] is not None, r["reason"]
        assert abs(r["measured_m"] - TRUE[fid]) <= RES, (fid, r["measured_m"])
        # the ends are reported in the method's frame: where the frame puts the true ends
        f = FEATURES[fid - 1]
        for k in "ab":
            assert np.hypot(*np.subtract(r[f"end_{k}"]["xy"], transform_points(frame, np.array([f[k]]))[0])) <= RES


def _shift_east_of(walls: np.ndarray, x_cut: float, dx: float) -> np.ndarray:
    """The walls with everything east of ``x_cut`` moved ``dx`` east (walls across the cut are split)."""
    out = []
    for x0, y0, x1, y1 in walls:
        if min(x0, x1) < x_cut < max(x0, x1):
            y_cut = y0 + (y1 - y0) * (x_cut - x0) / (x1 - x0)
            out += [[x0, y0, x_cut, y_cut], [x_cut, y_cut, x1, y1]]
        else:
            out.append([x0, y0, x1, y1])
    out = np.array(out)
    east = out[:, [0, 2]].mean(axis=1) > x_cut
    out[east, 0] += dx
    out[east, 2] += dx
    return out


def test_a_map_with_its_east_part_drawn_30_cm_east_measures_30_cm_more_across_the_cut(tmp_path):
    poses = _path(LAP, 0.25)
    est = poses.copy()
    est[est[:, 0] > 12.0, 0] += 0.3  # the trajectory drew the east part 0.3 m east: so does its map
    folder = _rasterised(tmp_path, _shift_east_of(WALLS, 12.0, 0.3), np.zeros(3), est)
    rows = _measure(folder, poses)
    across = {1, 8}  # the niche (10 .. 12.344) and the south outer wall (0 .. 26.681) span x = 12
    for fid, r in rows.items():
        assert r["measured_m"] is not None, r["reason"]
        expected = TRUE[fid] + (0.3 if fid in across else 0.0)
        assert abs(r["measured_m"] - expected) <= RES, (fid, r["measured_m"], expected)


def test_a_feature_the_map_does_not_show_is_not_measured(tmp_path):
    poses = _path(LAP, 0.25)
    niche = [i for i, w in enumerate(WALLS) if max(w[1], w[3]) > H + 0.1]  # its sides and back
    walls = np.vstack([np.delete(WALLS, niche, axis=0), [[10.0, H, 12.344, H]]])  # a straight north wall instead
    rows = _measure(_rasterised(tmp_path / "no-niche", walls, np.zeros(3), poses), poses)
    assert rows[1]["measured_m"] is None and not rows[1]["measurable"]
    assert "end a: no wall evidence" in rows[1]["reason"] and "end b: no wall evidence" in rows[1]["reason"]
    # a wall with no cells has no residual: null, as report.json's every unknown (JSON has no NaN)
    assert [w["rms_m"] for w in rows[1]["end_a"]["walls"] if w["cells"] == 0] == [None]
    json.dumps(rows, allow_nan=False)
    assert all(rows[i]["measured_m"] is not None for i in range(2, 10))

    doubled = np.vstack([WALLS, [[W + 0.3, 0.0, W + 0.3, 6.0]]])  # the east outer wall drawn twice near (W, 0)
    rows = _measure(_rasterised(tmp_path / "doubled", doubled, np.zeros(3), poses), poses)
    assert rows[8]["measured_m"] is None and "drawn twice" in rows[8]["reason"]
    assert rows[9]["measured_m"] is not None

    gone = np.array([w for w in WALLS if not (w[1] == w[3] == 3.0 and max(w[0], w[2]) <= 9.775)])  # feature 2's wall
    rows = _measure(_rasterised(tmp_path / "gone", gone, np.zeros(3), poses), poses)
    assert rows[2]["measured_m"] is None and rows[4]["measured_m"] is None  # 4 ends on the same wall
    assert "end b" in rows[2]["reason"] and "end a" in rows[4]["reason"]


# --------------------------------------------------------------------- scanned maps, fmcwlog's occupancy grid


def _scan(pose: np.ndarray, rng: np.random.Generator, max_range: float = 8.0) -> np.ndarray:
    """Returns (N, 2) in the robot's frame of a 270° scanner (0.5° steps, 2 cm range noise)."""
    ang = pose[2] + np.radians(np.arange(-135.0, 135.0 + 1e-9, 0.5))
    d = np.column_stack([np.cos(ang), np.sin(ang)])
    p, e = WALLS[:, :2], WALLS[:, 2:] - WALLS[:, :2]
    w = p[None] - pose[:2]
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        s = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
    r = np.where((np.abs(den) > 1e-12) & (r > 0) & (s >= 0) & (s <= 1), r, np.inf).min(axis=1)
    hit = r < max_range
    r = r[hit] + rng.normal(0.0, 0.02, hit.sum())
    local = ang[hit] - pose[2]
    return np.column_stack([r * np.cos(local), r * np.sin(local)])


# From the west corridor south, the whole south corridor east, up the east corridor, and west along the
# north one to x = 8: with 8 m of range the west end of the south wall is seen only from the path's first part.
PATH = np.array([[1.5, 10.0], [1.5, 1.5], [W - 1.5, 1.5], [W - 1.5, H - 1.5], [8.0, H - 1.5]])


def _scanned(folder: Path, poses: np.ndarray, est: np.ndarray) -> Path:
    """Scans from the true ``poses``, placed with ``est`` into an occupancy grid (the method's map)."""
    rng = np.random.default_rng(7)
    grid = OccupancyGrid()
    for p, e in zip(poses, est):
        grid.integrate(e[:2], transform_points(e, _scan(p, rng)))
    folder.mkdir(parents=True)
    write_grid(folder, "m_map", grid)
    write_tum(folder / "m.tum", np.arange(len(est)) * 250_000_000, est)
    return folder


@pytest.fixture(scope="module")
def scanned(tmp_path_factory):
    poses = _path(PATH, 0.25)
    jumped = poses.copy()
    after = np.arange(len(poses)) >= np.argmax((poses[:, 0] >= 14.0) & (poses[:, 1] < 2.0))
    jumped[after, 0] += 0.3  # a 0.3 m jump along the south corridor, at x = 14: half the path after it
    root = tmp_path_factory.mktemp("scanned")
    return poses, {name: _measure(_scanned(root / name, poses, est), poses)
                   for name, est in (("perfect", poses), ("jump", jumped))}


def test_perfect_poses_measure_every_feature_the_path_sees_to_about_a_cell(scanned):
    _, maps = scanned
    rows = maps["perfect"]
    for fid in (1, 2, 4, 5, 6, 7, 8):
        assert rows[fid]["measured_m"] is not None, (fid, rows[fid]["reason"])
        assert abs(rows[fid]["measured_m"] - TRUE[fid]) <= 2 * RES, (fid, rows[fid]["measured_m"])  # measured: <= 5.3 cm
    for fid in (3, 9):  # never within 8 m of the scanner in front of it: no wall there in the map
        assert rows[fid]["measured_m"] is None and rows[fid]["reason"]


def test_a_pose_jump_along_the_corridor_lengthens_the_wall_it_splits_by_the_jump(scanned):
    _, maps = scanned
    perfect, jump = maps["perfect"], maps["jump"]
    # the south wall's west corner was mapped before the jump, its east corner after: 0.3 m longer
    assert jump[8]["measured_m"] - perfect[8]["measured_m"] == pytest.approx(0.3, abs=RES)
    assert jump[8]["measured_m"] - TRUE[8] == pytest.approx(0.3, abs=1.5 * RES)
    for fid in (1, 2, 4, 5, 6, 7):  # each mapped wholly before or wholly after the jump
        assert jump[fid]["measured_m"] == pytest.approx(perfect[fid]["measured_m"], abs=RES), fid


# --------------------------------------------------------------------- the wall fit alone, and the map reader


def test_a_wall_fit_ignores_clutter_and_finds_the_end():
    rng = np.random.default_rng(3)
    wall = np.column_stack([np.linspace(0.0, 3.0, 61), 0.01 * rng.standard_normal(61)])  # ends at x = 0
    clutter = rng.uniform([-1.0, -0.5], [2.0, 0.5], (25, 2))
    fit = fit_wall(np.vstack([wall, clutter]), np.array([0.1, 0.05]), np.array([1.0, 0.0]), 3.0)
    assert fit.trusted and abs(fit.direction[1]) < 0.01 and abs(fit.point[1]) < 0.01
    assert fit.near_end[0] == pytest.approx(0.0, abs=0.06)
    empty = fit_wall(clutter[:3], np.zeros(2), np.array([1.0, 0.0]), 3.0)
    assert not empty.trusted and "no wall evidence" in empty.reason


def test_unreadable_maps_are_reported_per_feature_not_raised(tmp_path):
    poses = _path(LAP, 0.25)
    folder = _rasterised(tmp_path, WALLS, np.zeros(3), poses)
    (folder / "m_map.pgm").write_bytes(b"P2\n2 2\n255\n0 0 0 0\n")
    with pytest.raises(ReportError, match="m_map.pgm"):
        read_map_server(folder / "m_map.yaml")
    rows = _measure(folder, poses)
    assert all(r["measured_m"] is None and "m_map.pgm" in r["reason"] for r in rows.values())
    (folder / "m_map.yaml").write_text("image: [\n")
    with pytest.raises(ReportError, match="m_map.yaml"):
        read_map_server(folder / "m_map.yaml")
    (folder / "m_map.yaml").unlink()
    assert all("no occupancy map" in r["reason"] for r in _measure(folder, poses).values())


def test_the_reader_places_cells_as_map_server_does(tmp_path):
    occupied = np.zeros((4, 6), bool)
    occupied[0, 0] = occupied[3, 5] = True  # row 0 = lowest y
    _write_map(tmp_path, "tiny", occupied, (1.0, -2.0))
    img = read_map_server(tmp_path / "tiny.yaml")
    assert img.occupied.sum() == 2 and img.free.sum() == 22
    assert np.allclose(sorted(img.occupied_centres().tolist()), [[1.025, -1.975], [1.275, -1.825]])
    inv = inverse(np.array([1.0, -2.0, 0.0]))
    assert np.allclose(transform_points(inv, img.occupied_centres()).min(axis=0), [0.025, 0.025])
    text = (tmp_path / "tiny.yaml").read_text().replace("origin: [1.0, -2.0, 0.0]", "origin: [1.0, -2.0, 1.5707963]")
    (tmp_path / "tiny.yaml").write_text(text)  # the image turned a quarter about its lower-left corner
    assert np.allclose(sorted(read_map_server(tmp_path / "tiny.yaml").occupied_centres().tolist()),
                       [[0.825, -1.725], [0.975, -1.975]])
