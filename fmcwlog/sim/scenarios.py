"""Built-in worlds: ``corridor`` (the default), ``static``, ``crowd``, ``dense-crowd``, ``long-corridor``, ``ring``,
``warehouse``.

``corridor`` stands in for the paper's Figure 3: a floor of 26.681 m by
25.534 m, a ring corridor 3 m wide around a hall, with the nine labelled
features whose true lengths are those of the paper's Tables 2 and 3
(2.344, 6.775, 6.686, 1.064, 8.094, 1.029, 7.901, 26.681, 25.534 m), each
between corners or wall ends the scanner sees from the corridor.
"""

from __future__ import annotations

import numpy as np

from .movers import Mover
from .world import Feature, RouteSpec, World


def _polyline(*pts: tuple[float, float]) -> list[list[float]]:
    return [[*pts[i], *pts[i + 1]] for i in range(len(pts) - 1)]


def _box(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    return _polyline((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))


# The corridor floor: outer walls, inner hall, openings. Numbers are the features' ends.
W, H, C = 26.681, 25.534, 3.0  # floor width, height, corridor width
IX0, IY0, IX1, IY1 = C, C, W - C, H - C  # the hall inside the ring corridor


def corridor() -> World:
    walls: list[list[float]] = []
    # Outer walls, a 0.6 m deep niche of 2.344 m in the north wall (feature 1) and two door recesses.
    walls += _polyline((0, H), (0, 0), (W, 0), (W, H), (12.344, H), (12.344, H + 0.6), (10.0, H + 0.6), (10.0, H), (0, H))
    walls += _polyline((7.0, 0.0), (7.0, -0.3), (8.0, -0.3), (8.0, 0.0))  # door recess, south wall
    walls += _polyline((W, 17.0), (W + 0.3, 17.0), (W + 0.3, 18.0), (W, 18.0))  # door recess, east wall
    # The hall: four walls, each with one opening.
    walls += _polyline((IX0, IY0), (9.775, IY0))  # feature 2 = 6.775
    walls += _polyline((10.839, IY0), (IX1, IY0), (IX1, 11.094))  # opening 9.775..10.839 = feature 4 = 1.064; feature 5 = 8.094
    walls += _polyline((IX1, 12.123), (IX1, IY1), (15.780, IY1))  # opening = feature 6 = 1.029; feature 7 = 7.901
    walls += _polyline((14.580, IY1), (IX0, IY1), (IX0, 15.848))  # feature 3 = 6.686
    walls += _polyline((IX0, 14.648), (IX0, IY0))
    # Furniture in the hall, seen through the openings.
    walls += _box(8.0, 8.0, 9.0, 9.0) + _box(17.0, 15.0, 18.0, 16.0) + _box(12.0, 11.0, 14.0, 11.5)
    features = [
        Feature(1, "niche in the north outer wall (mouth)", (10.0, H), (12.344, H)),
        Feature(2, "hall south wall, west part", (IX0, IY0), (9.775, IY0)),
        Feature(3, "hall west wall, north part", (IX0, IY1), (IX0, 15.848)),
        Feature(4, "opening in the hall south wall (jamb to jamb)", (9.775, IY0), (10.839, IY0)),
        Feature(5, "hall east wall, south part", (IX1, IY0), (IX1, 11.094)),
        Feature(6, "opening in the hall east wall (jamb to jamb)", (IX1, 11.094), (IX1, 12.123)),
        Feature(7, "hall north wall, east part", (IX1, IY1), (15.780, IY1)),
        Feature(8, "south outer wall", (0.0, 0.0), (W, 0.0)),
        Feature(9, "west outer wall", (0.0, 0.0), (0.0, H)),
    ]
    route = RouteSpec(np.array([[1.5, 1.5], [W - 1.5, 1.5], [W - 1.5, H - 1.5], [1.5, H - 1.5]]), True, 1.2)
    movers = [
        Mover("person", [[4.0, 2.4], [22.0, 2.4]], 1.2, phase=6.0),
        Mover("person", [[W - 2.3, 4.0], [W - 2.3, 21.0]], 1.0, phase=20.0),
        Mover("person", [[22.0, H - 0.7], [5.0, H - 0.7]], 1.3, phase=10.0),
        Mover("person", [[6.0, 6.0], [20.0, 6.0]], 1.1, phase=3.0),
        Mover("cart", [[0.7, 4.0], [0.7, 21.0]], 0.8, phase=12.0),
    ]
    return World("corridor", np.array(walls, dtype=float), route, features, movers)


def static() -> World:
    return corridor().without_movers("static")


def crowd() -> World:
    """A 30 m x 20 m hall with pillars; a crowd walks along and across the robot's loop."""
    walls = _polyline((0, 0), (30, 0), (30, 8), (32, 8), (32, 12), (30, 12), (30, 20), (0, 20), (0, 0))  # exit bay east
    for x in (8.0, 15.0, 22.0):
        walls += _box(x - 0.3, 9.7, x + 0.3, 10.3)
    features = [
        Feature(1, "hall south wall", (0.0, 0.0), (30.0, 0.0)),
        Feature(2, "hall west wall", (0.0, 0.0), (0.0, 20.0)),
        Feature(3, "exit bay mouth", (30.0, 8.0), (30.0, 12.0)),
        Feature(4, "pillar 1 south face", (7.7, 9.7), (8.3, 9.7)),
        Feature(5, "pillar 1 to pillar 3 (south-west corners)", (7.7, 9.7), (21.7, 9.7)),
    ]
    route = RouteSpec(np.array([[4.0, 4.0], [26.0, 4.0], [26.0, 16.0], [4.0, 16.0]]), True, 2.0)
    rng = np.random.default_rng(2024)  # a fixed crowd: the scenario is data, not randomness
    movers: list[Mover] = []
    for i in range(18):  # walking along the loop's sides, both directions
        lane = rng.uniform(-1.6, 1.6)
        if i % 2:
            y = (4.0 if i % 4 == 1 else 16.0) + lane
            path = [[3.0, y], [27.0, y]]
        else:
            x = (4.0 if i % 4 == 0 else 26.0) + lane
            path = [[x, 3.0], [x, 17.0]]
        movers.append(Mover("person", path, rng.uniform(0.8, 1.5), phase=rng.uniform(0, 40)))
    for _ in range(10):  # crossing the hall
        x0, x1 = rng.uniform(2, 28, size=2)
        movers.append(Mover("person", [[x0, 1.0], [x1, 19.0]], rng.uniform(0.8, 1.4), phase=rng.uniform(0, 40)))
    for _ in range(4):
        y = rng.uniform(6.5, 13.5)
        movers.append(Mover("cart", [[5.0, y], [25.0, y]], rng.uniform(0.5, 1.0), phase=rng.uniform(0, 40)))
    return World("crowd", np.array(walls, dtype=float), route, features, movers)


DENSE_ALONG, DENSE_ACROSS, DENSE_CARTS = 12, 16, 3  # added to the ``crowd`` hall's 28 people and 4 carts


def dense_crowd() -> World:
    """The ``crowd`` hall packed: about half of all returns hit people and carts, and many of
    them walk across the robot's loop, so that they cross its beams broadside (``ε ≈ 0``)."""
    hall = crowd()
    rng = np.random.default_rng(2025)  # a fixed crowd: the scenario is data, not randomness
    movers: list[Mover] = list(hall.movers)
    for i in range(DENSE_ALONG):  # along the loop's sides, close to its line, both directions
        lane = rng.uniform(-1.2, 1.2)
        if i % 2:
            y = (4.0 if i % 4 == 1 else 16.0) + lane
            path = [[2.0, y], [28.0, y]]
        else:
            x = (4.0 if i % 4 == 0 else 26.0) + lane
            path = [[x, 2.0], [x, 18.0]]
        movers.append(Mover("person", path, rng.uniform(0.8, 1.5), phase=rng.uniform(0, 60)))
    for i in range(DENSE_ACROSS):  # short walks across one side of the loop
        side = i % 4
        if side < 2:  # across the south (y = 4) or north (y = 16) side
            x, y = rng.uniform(5.0, 25.0), 4.0 if side == 0 else 16.0
            path = [[x + rng.uniform(-1, 1), y - 3.0], [x + rng.uniform(-1, 1), y + 3.0]]
        else:  # across the west (x = 4) or east (x = 26) side
            x, y = 4.0 if side == 2 else 26.0, rng.uniform(5.0, 15.0)
            path = [[x - 3.0, y + rng.uniform(-1, 1)], [x + 3.0, y + rng.uniform(-1, 1)]]
        movers.append(Mover("person", path, rng.uniform(0.8, 1.5), phase=rng.uniform(0, 12)))
    for _ in range(DENSE_CARTS):  # carts across the loop too
        x = rng.uniform(6.0, 24.0)
        y = 4.0 if rng.random() < 0.5 else 16.0
        movers.append(Mover("cart", [[x, y - 3.5], [x, y + 3.5]], rng.uniform(0.5, 1.0), phase=rng.uniform(0, 14)))
    return World("dense-crowd", hall.walls, hall.route, hall.features, movers)



def long_corridor() -> World:
    """A 100 m corridor, 3 m wide, with a turning room at each end and bare walls between:
    geometry alone cannot tell where along its axis the robot is."""
    L, half, room = 100.0, 1.5, 8.0
    walls = _polyline((0, half), (0, room / 2), (-room, room / 2), (-room, -room / 2), (0, -room / 2), (0, -half))
    walls += _polyline((L, half), (L, room / 2), (L + room, room / 2), (L + room, -room / 2), (L, -room / 2), (L, -half))
    walls += [[0, half, L, half], [0, -half, L, -half]]
    features = [
        Feature(1, "west mouth of the corridor", (0.0, -half), (0.0, half)),
        Feature(2, "east mouth of the corridor", (L, -half), (L, half)),
        Feature(3, "west room, far wall", (-room, -room / 2), (-room, room / 2)),
        Feature(4, "east room, far wall", (L + room, -room / 2), (L + room, room / 2)),
    ]
    route = RouteSpec(
        np.array([[2.0, -0.6], [L - 2.0, -0.6], [L + 4.0, -2.5], [L + 4.0, 2.5], [L - 2.0, 0.6],
                  [2.0, 0.6], [-4.0, 2.5], [-4.0, -2.5]]),
        True,
        1.5,
    )
    movers = [Mover("person", [[10.0, 0.9], [90.0, 0.9]], 1.2, phase=30.0)]
    return World("long-corridor", np.array(walls, dtype=float), route, features, movers)


def ring() -> World:
    """A ring of corridors 2.5 m wide around a solid block, 30 m by 20 m outside, with door recesses
    at irregular spacing: from inside, nothing is seen across the block, so the drift of a lap
    (about 90 m, 95 s) is what a loop closure removes."""
    w, h, c = 30.0, 20.0, 2.5
    walls = _box(0.0, 0.0, w, h) + _box(c, c, w - c, h - c)  # outer walls, the inner block
    for x0 in (4.0, 11.5, 21.0):  # door recesses in the south and north outer walls, 1 m wide, 0.3 m deep
        walls += _polyline((x0, 0.0), (x0, -0.3), (x0 + 1.0, -0.3), (x0 + 1.0, 0.0))
    for x0 in (7.0, 16.5, 24.5):
        walls += _polyline((x0, h), (x0, h + 0.3), (x0 + 1.0, h + 0.3), (x0 + 1.0, h))
    for y0 in (5.0, 12.5):  # and in the east and west ones
        walls += _polyline((w, y0), (w + 0.3, y0), (w + 0.3, y0 + 1.0), (w, y0 + 1.0))
    walls += _polyline((0.0, 9.0), (-0.3, 9.0), (-0.3, 10.0), (0.0, 10.0))
    for x0 in (9.0, 19.0):  # pilasters on the block's south and north faces
        walls += _polyline((x0, c), (x0, c + 0.2), (x0 + 0.4, c + 0.2), (x0 + 0.4, c))
        walls += _polyline((x0 + 3.0, h - c), (x0 + 3.0, h - c - 0.2), (x0 + 3.4, h - c - 0.2), (x0 + 3.4, h - c))
    features = [
        Feature(1, "outer south wall", (0.0, 0.0), (w, 0.0)),
        Feature(2, "outer west wall", (0.0, 0.0), (0.0, h)),
        Feature(3, "block south face", (c, c), (w - c, c)),
        Feature(4, "block west face", (c, c), (c, h - c)),
    ]
    route = RouteSpec(np.array([[c / 2, c / 2], [w - c / 2, c / 2], [w - c / 2, h - c / 2], [c / 2, h - c / 2]]), True, 0.9)
    movers = [
        Mover("person", [[3.0, 1.6], [27.0, 1.6]], 1.1, phase=15.0),
        Mover("person", [[w - 0.8, 3.0], [w - 0.8, 17.0]], 1.0, phase=5.0),
        Mover("person", [[26.0, h - 1.7], [4.0, h - 1.7]], 1.2, phase=30.0),
    ]
    return World("ring", np.array(walls, dtype=float), route, features, movers)


# The warehouse: a 60 m x 30 m floor, six shelf rows 50 m long along x, aisles between them.
WH_W, WH_H = 60.0, 30.0  # floor, m
WH_SHELF_X = (5.0, 55.0)  # the rows' ends: cross-aisles 5 m wide at both ends
WH_SHELF_DEPTH = 1.2  # m, each row's depth (y)
WH_SHELF_Y0 = (3.0, 7.4, 11.8, 16.2, 20.6, 25.0)  # each row's south face, m


def warehouse_aisles() -> list[tuple[float, float]]:
    """The aisles along x as ``(y_low, y_high)`` bands of free space (m): south wall to the first
    row, between rows, last row to the north wall."""
    edges = [0.0] + [e for y0 in WH_SHELF_Y0 for e in (y0, y0 + WH_SHELF_DEPTH)] + [WH_H]
    return [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]


def warehouse() -> World:
    """Long aisles between six solid shelf rows (each 50 m x 1.2 m), forklifts and people in them.

    The route runs the first six aisles end to end, east, west, east..., turning through the
    cross-aisles: about 343 m, open (the robot stops at its end), never back in an aisle it has
    left, so nothing closes a loop. At ``--speed 3`` (m/s) it takes 120 s; at the
    default 1 m/s a 120 s log covers the first two aisles. Between the cross-aisles the scanner
    sees two parallel walls 50 m long: the aisle's axis is what geometry fixes worst.
    """
    walls = _box(0.0, 0.0, WH_W, WH_H)
    x0, x1 = WH_SHELF_X
    for y0 in WH_SHELF_Y0:
        walls += _box(x0, y0, x1, y0 + WH_SHELF_DEPTH)
    aisles = warehouse_aisles()
    mid = [0.5 * (lo + hi) for lo, hi in aisles]
    features = [
        Feature(1, "south outer wall", (0.0, 0.0), (WH_W, 0.0)),
        Feature(2, "west outer wall", (0.0, 0.0), (0.0, WH_H)),
        Feature(3, "shelf row 1, south face", (x0, WH_SHELF_Y0[0]), (x1, WH_SHELF_Y0[0])),
        Feature(4, "shelf row 1, west end", (x0, WH_SHELF_Y0[0]), (x0, WH_SHELF_Y0[0] + WH_SHELF_DEPTH)),
        Feature(5, "shelf rows 1 to 2, west ends (aisle width)", (x0, WH_SHELF_Y0[0] + WH_SHELF_DEPTH), (x0, WH_SHELF_Y0[1])),
    ]
    west, east = 2.5, WH_W - 2.5  # the route's lines in the cross-aisles
    pts: list[tuple[float, float]] = [(3.0, mid[0])]
    for i in range(6):
        far = east if i % 2 == 0 else west
        pts.append((far, mid[i]))
        if i < 5:
            pts.append((far, mid[i + 1]))
    pts[-1] = (3.0, mid[5])  # the sixth aisle run out to x = 3, where the first began
    route = RouteSpec(np.array(pts), False, 2.0)
    rng = np.random.default_rng(2026)  # a fixed fleet: the scenario is data, not randomness
    movers: list[Mover] = []
    for i, y in enumerate(mid):  # a forklift in every aisle, in a lane beside its centre line
        lane = 0.8 if i % 2 else -0.8
        path = [[7.0, y + lane], [53.0, y + lane]] if i % 2 else [[53.0, y + lane], [7.0, y + lane]]
        movers.append(Mover("cart", path, rng.uniform(1.5, 2.5), phase=rng.uniform(0, 92), length=2.4, width=0.8))
    for i, y in enumerate(mid[1:6]):  # a cart pushed along five of them, the other lane
        lane = -0.8 if i % 2 else 0.8
        movers.append(Mover("cart", [[10.0, y + lane], [50.0, y + lane]], rng.uniform(0.6, 1.0),
                            phase=rng.uniform(0, 80), length=1.2, width=0.7))
    for x in (1.0, 4.2, WH_W - 4.2, WH_W - 1.0):  # people walking the cross-aisles
        movers.append(Mover("person", [[x, 1.0], [x, WH_H - 1.0]], rng.uniform(0.9, 1.4), phase=rng.uniform(0, 56)))
    return World("warehouse", np.array(walls, dtype=float), route, features, movers)


SCENARIOS = {"corridor": corridor, "static": static, "crowd": crowd, "dense-crowd": dense_crowd,
             "long-corridor": long_corridor, "ring": ring, "warehouse": warehouse}
DEFAULT_SCENARIO = "corridor"


def scenario(name: str = DEFAULT_SCENARIO) -> World:
    """A built-in world by name (one of :data:`SCENARIOS`: ``corridor``, ``static``, ``crowd``,
    ``dense-crowd``, ``long-corridor``, ``ring``, ``warehouse``)."""
    return SCENARIOS[name]()
