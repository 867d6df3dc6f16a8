"""A planar world: walls, labelled features, movers and the robot's route.

World files (``fmcwlog record --world FILE``) are YAML or JSON::

    name: my-floor                       # optional
    walls:                               # line segments [x1, y1, x2, y2], m, in map
      - [0, 0, 20, 0]
      - [20, 0, 20, 3]
    features:                            # optional: lengths to check in the built map
      - {id: 1, name: "corridor wall", a: [0, 0], b: [20, 0]}
    route:                               # the path of base_link
      waypoints: [[2, 1.5], [18, 1.5]]   # m
      loop: false                        # open: the robot stops at the end
      corner_radius: 1.0                 # m, arcs that round the corners
    movers:                              # optional
      - {kind: person, path: [[3, 2], [15, 2]], speed: 1.2, phase: 0, radius: 0.25}
      - {kind: cart, path: [[15, 1], [3, 1]], speed: 0.8, length: 1.0, width: 0.6}

Every wall is seen from both sides. A feature's ends should be corners or wall
ends that the scanner sees, so that its length can be measured in a map.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import read_structured_file
from ..errors import WorldError
from .movers import Mover
from .route import Route, build_route


@dataclass(frozen=True)
class Feature:
    """A length in the world, from corner ``a`` to corner ``b`` (m, map frame)."""

    id: int
    name: str
    a: tuple[float, float]
    b: tuple[float, float]

    @property
    def length(self) -> float:
        """The true length, m."""
        return float(np.hypot(self.b[0] - self.a[0], self.b[1] - self.a[1]))


@dataclass(frozen=True)
class RouteSpec:
    """The route of base_link as the world file gives it: waypoints (K, 2) in ``map`` (m), whether
    it loops, and the radius (m) of the arcs that round its corners."""

    waypoints: np.ndarray
    loop: bool = True
    corner_radius: float = 1.0

    def build(self) -> Route:
        """The route itself (:func:`.route.build_route`)."""
        return build_route(self.waypoints, self.loop, self.corner_radius)


@dataclass(frozen=True)
class World:
    """A floor: its walls (``map``, m), the robot's route, the labelled features and the movers."""

    name: str
    walls: np.ndarray  # (M, 4) segments x1, y1, x2, y2
    route: RouteSpec
    features: list[Feature] = field(default_factory=list)
    movers: list[Mover] = field(default_factory=list)

    def metadata(self) -> dict[str, str]:
        """The ``fmcwlog.world`` metadata record: ``features``, a JSON list of ``{id, name, a, b}``
        (ends in ``map``, m), and ``walls``, a JSON list of ``[x1, y1, x2, y2]`` (m); see the log
        format, docs/log-format.md."""
        return {
            "features": json.dumps(
                [{"id": f.id, "name": f.name, "a": list(f.a), "b": list(f.b)} for f in self.features]
            ),
            "walls": json.dumps([[float(v) for v in w] for w in self.walls]),
        }

    def without_movers(self, name: str | None = None) -> World:
        """The same floor with nothing moving (renamed ``name`` if given)."""
        return World(name or self.name, self.walls, self.route, self.features, [])


# Coordinates within 100 km of the origin: float64 still resolves micrometres there, and no
# floor is larger. Sizes and speeds: what people and carts can be.
MAX_COORDINATE = 1e5  # m


def _num_list(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    if isinstance(value, str | bytes | dict):
        raise WorldError(f"{where} must be a list of numbers")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise WorldError(f"{where} must be numbers") from None
    if arr.ndim != len(shape) or any(s != -1 and s != n for s, n in zip(shape, arr.shape)):
        want = " x ".join("N" if s == -1 else str(s) for s in shape)
        raise WorldError(f"{where} must be a list of shape {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise WorldError(f"{where} has a value that is not finite")
    if np.any(np.abs(arr) > MAX_COORDINATE):
        raise WorldError(f"{where} has a coordinate beyond {MAX_COORDINATE:g} m of the origin")
    return arr


def _number(value: Any, where: str, lo: float, hi: float, lo_open: bool = False, unit: str = "") -> float:
    """A finite number in ``[lo, hi]`` (``(lo, hi]`` if ``lo_open``) or a one-line :class:`WorldError`."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise WorldError(f"{where} must be a number, got {value!r:.40}")
    x = float(value)
    if not np.isfinite(x) or x > hi or x < lo or (lo_open and x == lo):
        raise WorldError(f"{where} = {value!r:.40} is out of range: {'(' if lo_open else '['}{lo:g}, {hi:g}] {unit}".rstrip())
    return x


def world_from_dict(data: Any, source: str = "world") -> World:
    """Validate a parsed world description (metres, ``map``); a bad one raises
    :class:`~fmcwlog.errors.WorldError` naming ``source`` and the bad entry, as does a route that
    crosses a wall."""
    if not isinstance(data, dict):
        raise WorldError(f"{source}: expected a mapping with walls, route (and optionally features, movers)")
    unknown = set(data) - {"name", "walls", "features", "movers", "route"}
    if unknown:
        raise WorldError(f"{source}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    if "walls" not in data or "route" not in data:
        raise WorldError(f"{source}: needs 'walls' and 'route'")
    walls = _num_list(data["walls"], (-1, 4), f"{source}: walls")
    if len(walls) == 0:
        raise WorldError(f"{source}: walls is empty")
    short = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]) < 1e-6
    if short.any():
        raise WorldError(f"{source}: walls[{int(np.argmax(short))}] has zero length")
    if not isinstance(data.get("name", ""), str):
        raise WorldError(f"{source}: name must be a string")
    for key in ("features", "movers"):
        if not isinstance(data.get(key) or [], list):
            raise WorldError(f"{source}: {key} must be a list")

    route = _route(data["route"], source)
    crossing = route_crossing(walls, route.build())
    if crossing is not None:
        j, (x, y) = crossing
        raise WorldError(f"{source}: the route crosses walls[{j}] at ({x:.2f}, {y:.2f}): the robot would drive "
                         f"through it (leave an opening there, or move the waypoints)")
    features = _features(data.get("features") or [], source)
    movers = [_mover(m, f"{source}: movers[{i}]") for i, m in enumerate(data.get("movers") or [])]
    return World(str(data.get("name", source)), walls, route, features, movers)


def route_crossing(walls: np.ndarray, route: Route, step: float = 0.05) -> tuple[int, tuple[float, float]] | None:
    """The first wall (index) the path of ``base_link`` crosses, and where (m, map frame); None if none.

    The route is sampled every ``step`` metres over one lap (or its one pass) and each short chord
    tested against every wall segment (passing exactly through a wall's end is not a crossing).
    """
    s = np.linspace(0.0, route.total_length, max(int(np.ceil(route.total_length / step)), 1) + 1)
    x, y, _, _ = route.at(s)
    p, q = np.stack([x[:-1], y[:-1]], 1)[:, None, :], np.stack([x[1:], y[1:]], 1)[:, None, :]  # (N, 1, 2)
    a, b = walls[None, :, :2], walls[None, :, 2:]  # (1, M, 2)

    def cross(o, u, v):  # z of (u - o) x (v - o)
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0])

    d1, d2, d3, d4 = cross(a, b, p), cross(a, b, q), cross(p, q, a), cross(p, q, b)
    # a chord ending on the wall's line counts (samples can fall exactly on it); one along it does not
    hits = (d1 * d2 <= 0) & ((d1 != 0) | (d2 != 0)) & (d3 * d4 < 0)
    if not hits.any():
        return None
    i, j = np.argwhere(hits)[0]
    f = d1[i, j] / (d1[i, j] - d2[i, j])  # where along the chord it meets the wall's line
    return int(j), (float(x[i] + f * (x[i + 1] - x[i])), float(y[i] + f * (y[i + 1] - y[i])))


def _route(r: Any, source: str) -> RouteSpec:
    if not isinstance(r, dict) or "waypoints" not in r:
        raise WorldError(f"{source}: route needs 'waypoints'")
    unknown = set(r) - {"waypoints", "loop", "corner_radius"}
    if unknown:
        raise WorldError(f"{source}: route: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    if not isinstance(r.get("loop", True), bool):
        raise WorldError(f"{source}: route.loop must be true or false")
    route = RouteSpec(
        waypoints=_num_list(r["waypoints"], (-1, 2), f"{source}: route.waypoints"),
        loop=r.get("loop", True),
        corner_radius=_number(r.get("corner_radius", 1.0), f"{source}: route.corner_radius", 0.0, 1e4, True, "m"),
    )
    try:
        route.build()
    except ValueError as exc:
        raise WorldError(f"{source}: route: {exc}") from None
    return route


def _features(entries: list, source: str) -> list[Feature]:
    features = []
    for i, f in enumerate(entries):
        where = f"{source}: features[{i}]"
        if not isinstance(f, dict) or not {"a", "b"} <= set(f):
            raise WorldError(f"{where} needs 'a' and 'b'")
        a = _num_list(f["a"], (2,), f"{where}.a")
        b = _num_list(f["b"], (2,), f"{where}.b")
        fid = f.get("id", i + 1)
        if isinstance(fid, bool) or not isinstance(fid, int) or abs(fid) > 2**53:
            raise WorldError(f"{where}.id must be a whole number, got {fid!r:.40}")
        name = f.get("name", f"feature {i + 1}")
        if not isinstance(name, str):
            raise WorldError(f"{where}.name must be a string")
        if not math.hypot(float(b[0]) - float(a[0]), float(b[1]) - float(a[1])) > 0:
            raise WorldError(f"{where}: a and b are the same point (a feature's length must be positive)")
        features.append(Feature(fid, name, (float(a[0]), float(a[1])), (float(b[0]), float(b[1]))))
    if len({f.id for f in features}) != len(features):
        raise WorldError(f"{source}: feature ids must be unique")
    return features


def _mover(m: Any, where: str) -> Mover:
    if not isinstance(m, dict) or "path" not in m:
        raise WorldError(f"{where} needs 'path'")
    kind = m.get("kind", "person")
    if kind not in ("person", "cart"):
        raise WorldError(f"{where}.kind must be 'person' or 'cart', got {kind!r}")
    unknown = set(m) - {"kind", "path", "speed", "phase", "radius", "length", "width"}
    if unknown:
        raise WorldError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    path = _num_list(m["path"], (-1, 2), f"{where}.path")
    if len(path) == 0:
        raise WorldError(f"{where}.path is empty")
    return Mover(
        kind=kind,
        path=path,
        speed=_number(m.get("speed", 1.2 if kind == "person" else 0.8), f"{where}.speed", 0.0, 20.0, unit="m/s"),
        phase=_number(m.get("phase", 0.0), f"{where}.phase", -MAX_COORDINATE, MAX_COORDINATE, unit="m"),
        radius=_number(m.get("radius", 0.25), f"{where}.radius", 0.0, 10.0, True, "m"),
        length=_number(m.get("length", 1.0), f"{where}.length", 0.0, 20.0, True, "m"),
        width=_number(m.get("width", 0.6), f"{where}.width", 0.0, 20.0, True, "m"),
    )


def load_world(path: str | Path) -> World:
    """Read a YAML (.yaml/.yml, or any other suffix) or JSON (.json) world file (metres, ``map``).

    A file that cannot be read or parsed, or a description that :func:`world_from_dict` refuses,
    raises :class:`~fmcwlog.errors.WorldError` naming the file and the entry at fault."""
    return world_from_dict(read_structured_file(path, WorldError, default_format="yaml"), str(path))
