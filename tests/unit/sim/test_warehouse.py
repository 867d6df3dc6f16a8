"""The ``warehouse`` scenario is the world it claims to be, measured from its walls, route and
movers rather than from the numbers that built it: a 60 m x 30 m floor; six shelf rows 50 m long
with aisles at least 3 m wide between them; a route of about 340 m that stays clear of every wall,
drives each aisle once (nothing to close a loop on) and takes about 120 s at the scenario's speed;
forklifts and people whose bodies stay in free space over a whole cycle of their paths."""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.sim import scenarios
from fmcwlog.sim.config import RobotConfig, SimConfig, apply_overrides
from fmcwlog.sim.route import SpeedProfile

SPEED = 3.0  # m/s: the speed the scenario is documented to be driven at (record --speed 3)
LONG = 40.0  # m: a horizontal wall this long inside the floor is a shelf row's face


@pytest.fixture(scope="module")
def world():
    return scenarios.SCENARIOS["warehouse"]()


def _shelves(walls: np.ndarray) -> list[tuple[float, float, float, float]]:
    """Shelf rows as boxes (x0, y0, x1, y1): pairs of long horizontal walls strictly inside the floor."""
    horizontal = np.isclose(walls[:, 1], walls[:, 3]) & (np.abs(walls[:, 2] - walls[:, 0]) >= LONG)
    ymax = walls[:, [1, 3]].max()
    inside = horizontal & (walls[:, 1] > 1e-9) & (walls[:, 1] < ymax - 1e-9)
    faces = sorted({round(float(y), 9) for y in walls[inside, 1]})
    assert len(faces) % 2 == 0
    x0 = float(walls[inside][:, [0, 2]].min())
    x1 = float(walls[inside][:, [0, 2]].max())
    return [(x0, faces[i], x1, faces[i + 1]) for i in range(0, len(faces), 2)]


def _distance_to_walls(p: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """(N,) distance (m) from each point (N, 2) to the nearest wall segment."""
    a, b = walls[:, :2], walls[:, 2:]
    ab = b - a
    u = np.clip(np.einsum("nmk,mk->nm", p[:, None] - a, ab) / np.einsum("mk,mk->m", ab, ab), 0.0, 1.0)
    return np.linalg.norm(p[:, None] - (a + u[..., None] * ab), axis=2).min(axis=1)


def _segments_cross(p: np.ndarray, q: np.ndarray, walls: np.ndarray) -> bool:
    """Whether any segment p[i]-q[i] (N, 2) properly crosses or touches any wall."""
    a, b = walls[None, :, :2], walls[None, :, 2:]
    p, q = p[:, None], q[:, None]

    def cross(o, u, v):
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0])

    return bool(np.any((cross(a, b, p) * cross(a, b, q) <= 0) & (cross(p, q, a) * cross(p, q, b) <= 0)))


def test_floor_and_shelf_rows(world):
    w = world.walls
    assert w[:, [0, 2]].min() == 0.0 and w[:, [0, 2]].max() == pytest.approx(60.0)
    assert w[:, [1, 3]].min() == 0.0 and w[:, [1, 3]].max() == pytest.approx(30.0)
    rows = _shelves(w)
    assert len(rows) == 6
    for x0, y0, x1, y1 in rows:
        assert x1 - x0 == pytest.approx(50.0)
        assert 0.5 <= y1 - y0 <= 2.0  # a rack's depth
        assert x0 >= 3.0 and x1 <= 57.0  # cross-aisles at both ends
    bands = [0.0] + [y for r in rows for y in (r[1], r[3])] + [30.0]
    aisles = np.diff(bands)[::2]  # free space: south wall to row 1, between rows, row 6 to north wall
    assert len(aisles) == 7 and aisles.min() >= 3.0


def test_route_stays_in_free_space_and_takes_120_s(world):
    route = world.route.build()
    assert not world.route.loop
    assert 330.0 <= route.total_length <= 350.0
    s = np.linspace(0.0, route.total_length, 20000)
    x, y, _, _ = route.at(s)
    p = np.stack([x, y], -1)
    assert _distance_to_walls(p, world.walls).min() >= 1.0
    for x0, y0, x1, y1 in _shelves(world.walls):  # never inside a rack
        assert not np.any((x > x0) & (x < x1) & (y > y0) & (y < y1))
    robot = apply_overrides(SimConfig(), {"robot": {"speed": SPEED}}).robot
    profile = SpeedProfile(robot.speed, robot.acceleration, route.total_length)
    t = np.arange(0.0, 130.0, 0.01)
    dist, speed, _ = profile.distance_speed_accel(t)
    t_end = t[np.argmax(dist >= route.total_length - 1e-6)]
    assert 115.0 <= t_end <= 125.0
    assert robot.speed > RobotConfig().speed  # faster than the default robot: that is the scenario's point


def test_each_aisle_is_driven_once_and_no_place_is_revisited(world):
    route = world.route.build()
    s = np.linspace(0.0, route.total_length, 2500)  # ~14 cm apart
    x, y, _, _ = route.at(s)
    rows = _shelves(world.walls)
    x0, x1 = rows[0][0], rows[0][2]
    bands = [0.0] + [v for r in rows for v in (r[1], r[3])] + [30.0]
    driven = 0
    for lo, hi in zip(bands[::2], bands[1::2]):
        inside = (x > x0) & (x < x1) & (y > lo) & (y < hi)
        if inside.any():
            driven += 1
            idx = np.flatnonzero(inside)
            assert np.all(np.diff(idx) == 1)  # one pass, never back
            assert x[idx].max() - x[idx].min() >= 49.0  # end to end
    assert driven == 6
    p = np.stack([x, y], -1)
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    apart = np.abs(s[:, None] - s[None]) > 20.0  # far along the path...
    assert d[apart].min() >= 4.0  # ...never near: the nearest is the next aisle over, behind a rack


def _footprint(kind: str, c: np.ndarray, v: np.ndarray, mover) -> np.ndarray:
    """(K, 2) corners of a cart (long side along v) or points round a person's circle."""
    if kind == "person":
        a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        return c + mover.radius * np.stack([np.cos(a), np.sin(a)], -1)
    d = v / np.linalg.norm(v)
    n = np.array([-d[1], d[0]])
    hl, hw = mover.length / 2, mover.width / 2
    return np.array([c + sx * hl * d + sy * hw * n for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))])


def test_movers_stay_in_free_space_on_aisle_paths(world):
    rows = _shelves(world.walls)
    forklifts = [m for m in world.movers if m.kind == "cart" and m.length >= 2.0]
    assert len(forklifts) >= 6
    bands = [0.0] + [v for r in rows for v in (r[1], r[3])] + [30.0]
    for m in forklifts:  # along an aisle: parallel to the rows, inside one band
        assert np.allclose(m.path[:, 1], m.path[0, 1])
        assert any(lo < m.path[0, 1] < hi for lo, hi in zip(bands[::2], bands[1::2]))
    for m in world.movers:
        period = 2 * m.path_length / m.speed
        t = np.linspace(0.0, period, 400)
        centre, vel = m.state(t)
        on_path = _distance_to_walls(centre, np.hstack([m.path[:-1], m.path[1:]]))
        assert on_path.max() < 1e-9  # the centre walks its path
        for c, v in zip(centre, vel):
            body = _footprint(m.kind, c, v, m)
            assert np.all((body > 0) & (body < [60.0, 30.0]))
            closed = np.roll(body, -1, axis=0)
            assert not _segments_cross(body, closed, world.walls), (m, c)
            for x0, y0, x1, y1 in rows:
                assert not np.any((body[:, 0] > x0) & (body[:, 0] < x1) & (body[:, 1] > y0) & (body[:, 1] < y1))
