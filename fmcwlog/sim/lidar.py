"""A planar FMCW LiDAR: ray casting against walls and movers, range and Doppler.

Every beam has its own time within the sweep (a 270° sweep at 10 Hz takes
75 ms), so the sensor pose and the movers are evaluated per beam and the
sweep is motion-distorted, as a real one is. A return's radial velocity is
the rate of change of its range,

    ṙ = u · (v_target - v_sensor)        (positive when the range grows)

with ``u`` the beam's unit direction and ``v_sensor`` the velocity of the
sensor's origin, which includes the lever arm ``ω × l`` of its mounting; it is
reported with noise and quantised to the Doppler resolution (the paper's
0.1 m/s). Ranges get Gaussian noise (σ = 2 cm) and are quantised to the range
resolution (2 cm). The nearest surface wins, so movers occlude what is behind.

Speed, with the same arithmetic for every (beam, target) pair that is cast, so a seed's log is
byte for byte what casting every beam against every target gives: a wall, person or cart is cast
only against the beams whose direction lies within a bound that no beam outside it can hit
(its angle from the sweep's first origin, widened by what it and the sensor can move during the
sweep), each beam's nearest target is found over those pairs alone, and several sweeps
(``recorder.SWEEPS_AT_ONCE``) are cast in one numpy pass (``FmcwLidar.sweeps``). What does not
change between passes is computed once: the walls' directions and normals, the beams' fixed angles'
trig; and once a pass rather than once per kind of target, the beams' sorted directions. On
``crowd`` (20 walls, 28 people, 4 carts; ``fmcwlog record --scenario crowd``) ``record()`` takes
about 0.9 ms of CPU a sweep, writing included, against 8.4 ms casting every beam against every
target (docs/design/speed-experiments.md); ``tests/unit/sim/test_ray_casting.py`` checks the result
against a brute-force cast.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..geometry import rot2
from .chassis import BodyState
from .config import SensorConfig
from .movers import Mover, MoverGroup

_REFLECTIVITY = {"wall": 0.6, "person": 0.3, "cart": 0.85, "floor": 0.4}
# Movers are vertical cylinders and boxes standing on the floor; walls are of unbounded height (m).
PERSON_HEIGHT, CART_HEIGHT = 1.75, 1.0
# Slack in the test that rules out (beam, mover) pairs before casting (m, rad): far above rounding.
_CULL_MARGIN, _CULL_MARGIN_ANGLE = 0.01, 1e-6
_SWEEP_SPACING = 16.0 * np.pi  # rad between sweeps in the sorted key of _Beams.within


@dataclass(frozen=True)
class Sweep:
    """One sweep as the sensor reports it (frame ``lidar``), with per-point truth."""

    x: np.ndarray  # (N,) m
    y: np.ndarray
    intensity: np.ndarray  # (N,) unitless, 0..1
    velocity: np.ndarray  # (N,) m/s, radial, positive when the range grows
    t: np.ndarray  # (N,) s after the sweep's stamp
    moving: np.ndarray  # (N,) uint8, 1 where the return came from a mover
    z: np.ndarray | None = None  # (N,) m; None for the planar sensor (z = 0)
    ring: np.ndarray | None = None  # (N,) uint16, 0 the lowest ring; None for the planar sensor


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _ray_hits(ox, oy, dx, dy, px, py, ex, ey):
    """Ranges along rays o + r·d to segments from p to p + e (arrays that broadcast together); inf where missed."""
    wx, wy = px - ox, py - oy
    den = _cross(dx, dy, ex, ey)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = _cross(wx, wy, ex, ey) / den
        u = _cross(wx, wy, dx, dy) / den
    ok = (np.abs(den) > 1e-12) & (r > 0) & (u >= 0) & (u <= 1)
    return np.where(ok, r, np.inf)


def _hit_segments(ox, oy, dx, dy, px, py, qx, qy):
    """Ranges (N, M) along rays o + r·d to segments p→q (coordinates (M,) or (N, M)); inf where missed.
    Also the segments' direction components ``ex, ey`` (for their normals)."""
    ex, ey = qx - px, qy - py
    return _ray_hits(ox[:, None], oy[:, None], dx[:, None], dy[:, None], px, py, ex, ey), ex, ey


def _normal(ex, ey):
    """Unit normal (-ey, ex)/|e| of a segment with direction components ``ex, ey``."""
    norm = np.hypot(ex, ey)
    return -ey / norm, ex / norm


@dataclass(frozen=True)
class _Beams:
    """The beams of ``count`` consecutive sweeps of ``n`` beams each, in ``map``, sweep after sweep:
    origins (count·n, 2) m, directions ``ang`` (count·n,) rad (unwrapped), unit vectors ``dx, dy``,
    times ``t`` (count·n,) s; ``drift`` (count,): how far (m) the origin gets from its first
    position during each sweep."""

    origin: np.ndarray
    ang: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    t: np.ndarray
    drift: np.ndarray
    n: int

    @property
    def count(self) -> int:
        return len(self.drift)

    @cached_property
    def first(self) -> np.ndarray:
        """Index (count,) of each sweep's first beam."""
        return self.n * np.arange(self.count)

    @cached_property
    def ox(self) -> np.ndarray:
        """The origins' x (count·n,), contiguous: gathered per (beam, target) pair."""
        return np.ascontiguousarray(self.origin[:, 0])

    @cached_property
    def oy(self) -> np.ndarray:
        return np.ascontiguousarray(self.origin[:, 1])

    @cached_property
    def _key(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Each sweep's middle direction (count, 1) and one sorted key for all beams (count·n,):
        each sweep's directions about its middle beam, sweeps 16π apart, farther than any window
        of :meth:`within` reaches; None when a sweep's directions are not in order (a yaw rate
        beyond any robot's). The same for walls, people and carts: computed once."""
        count, n = self.count, self.n
        ang = self.ang.reshape(count, n)
        if not np.all(np.diff(ang, axis=1) > 0):
            return None
        mid = ang[:, n // 2, None]
        return mid, (ang - mid + _SWEEP_SPACING * np.arange(count)[:, None]).ravel()

    def within(self, lo: np.ndarray, width: np.ndarray, everywhere: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Beam and target indices (K,) of the beams of sweep ``s`` whose direction lies in
        ``[lo[s, i], lo[s, i] + width[s, i]]`` (rad, modulo 2π; width < 2π) for target ``i``, or
        anywhere in the sweep where ``everywhere[s, i]``; arguments (count, M)."""
        count, n, m = self.count, self.n, lo.shape[1]
        if self._key is None:  # not in order (a yaw rate beyond any robot's): every pair
            return np.repeat(np.arange(count * n), m), np.tile(np.arange(m), count * n)
        # Rounding moves a key by ~1e-13 rad, far inside the windows' margin (_CULL_MARGIN_ANGLE).
        mid, key = self._key
        lo = lo - mid
        lo = lo + 2.0 * np.pi * np.round((-lo - 0.5 * width) / (2.0 * np.pi))  # centred within π of it
        shifts = 2.0 * np.pi * np.arange(-2, 3)[:, None, None]  # a window may wrap round the field of view
        lo = lo + _SWEEP_SPACING * np.arange(count)[:, None] + shifts  # (5, count, M)
        start = np.searchsorted(key, lo.ravel(), "left")
        stop = np.searchsorted(key, (lo + width).ravel(), "right")
        everywhere = np.broadcast_to(everywhere, lo.shape).ravel()
        first = np.broadcast_to(self.first[:, None], lo.shape).ravel()
        unshifted = np.broadcast_to((shifts == 0), lo.shape).ravel()
        start = np.where(everywhere, first, start)
        stop = np.where(everywhere, np.where(unshifted, first + n, first), stop)
        count_ = np.maximum(stop - start, 0)
        beams = np.arange(int(count_.sum())) + np.repeat(start - (np.cumsum(count_) - count_), count_)
        targets = np.broadcast_to(np.arange(m), lo.shape).ravel()
        return beams, np.repeat(targets, count_)


def _nearest(n: int, m: int, beam: np.ndarray, target: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``n`` beams, the candidate pair (index into ``beam``/``target``/``r``, (K,)) of the
    nearest of its targets (indices below ``m``) and its range (inf, and pair 0, where none is hit).
    Ties go to the lowest target index, as ``argmin`` over every target would. (``ufunc.at`` over
    the pairs: 0.75 ms for 10 sweeps of ``crowd``'s people, against 14 ms for an argmin over a
    dense beams x targets array.)"""
    rk = np.full(n, np.inf)
    np.minimum.at(rk, beam, r)
    win = r == rk[beam]  # the nearest of its beam (ties: every one of them)
    lowest = np.full(n, m)
    np.minimum.at(lowest, beam[win], target[win])
    win &= target == lowest[beam]
    pair = np.zeros(n, dtype=np.intp)
    pair[beam[win]] = np.flatnonzero(win)
    return pair, rk


class FmcwLidar:
    """Casts one sweep's beams into a world at the times each beam is fired."""

    def __init__(self, cfg: SensorConfig, walls: np.ndarray, movers: list[Mover]):
        self.cfg = cfg
        self._walls = tuple(np.ascontiguousarray(c) for c in walls.T)  # px, py, qx, qy (M,)
        # each wall as its start and direction (px, py, ex, ey), what a ray is cast against: static
        self._wall_rays = (*self._walls[:2], self._walls[2] - self._walls[0], self._walls[3] - self._walls[1])
        self._walls_normal = _normal(*self._wall_rays[2:])
        self.people = MoverGroup([m for m in movers if m.kind == "person"])
        self.carts = MoverGroup([m for m in movers if m.kind == "cart"])
        self._radius = np.array([m.radius for m in self.people.movers])  # m
        self._half_length = np.array([0.5 * m.length for m in self.carts.movers])  # m
        self._half_width = np.array([0.5 * m.width for m in self.carts.movers])  # m
        n = cfg.n_beams
        half = np.radians(cfg.fov_deg) / 2.0
        self.beam_angle = -half + np.radians(cfg.resolution_deg) * np.arange(n)  # rad, in ``lidar``
        self.beam_time = cfg.sweep_duration * np.arange(n) / max(n - 1, 1)  # s after the stamp
        self._beam_cos, self._beam_sin = np.cos(self.beam_angle), np.sin(self.beam_angle)  # the same every sweep
        self.mount = np.array(cfg.mount)

    def sensor_motion(self, body: BodyState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Origin (N, 2), heading (N,) and origin velocity (N, 2) of ``lidar`` in ``map``."""
        mx, my = self.mount[:2].tolist()
        cos, sin = np.cos(body.yaw), np.sin(body.yaw)
        lever = np.empty((len(cos), 2))  # R(yaw)·l
        if my == 0.0 and mx != 0.0:  # a mount on the x axis (the default): the products by 0 are exact, so
            lever[:, 0] = cos * mx + -sin * my  # this is what BLAS's dot product gives, with or without FMA,
            lever[:, 1] = sin * mx + cos * my  # at a tenth of the cost of a matmul per beam
        else:  # elsewhere BLAS's rounding (FMA) is what the logs hold
            lever[:] = rot2(body.yaw) @ self.mount[:2]
        origin = np.empty_like(lever)
        origin[:, 0], origin[:, 1] = body.x + lever[:, 0], body.y + lever[:, 1]
        heading = body.yaw + self.mount[2]
        vel = np.empty_like(lever)
        vel[:, 0] = body.v * cos + body.omega * -lever[:, 1]
        vel[:, 1] = body.v * sin + body.omega * lever[:, 0]
        return origin, heading, vel

    def _cart_sides(self, cx, cy, vx, vy, which):
        """The 4 sides of carts ``which`` (K,) with centres and velocities (K,) (m, m/s), as segments
        p→q with coordinates (K, 4): corners front-left, rear-left, rear-right, front-right."""
        spd = np.sqrt(vx * vx + vy * vy)
        moving = spd > 0
        safe = np.where(moving, spd, 1.0)
        fx = np.where(moving, vx / safe, 1.0)  # unit forward; +x for a cart at rest
        fy = np.where(moving, vy / safe, 0.0)
        sx, sy = -fy, fx  # unit left
        a, w = self._half_length[which], self._half_width[which]
        front_x, front_y, rear_x, rear_y = cx + a * fx, cy + a * fy, cx - a * fx, cy - a * fy
        corner_x = np.stack([front_x + w * sx, rear_x + w * sx, rear_x - w * sx, front_x - w * sx], -1)
        corner_y = np.stack([front_y + w * sy, rear_y + w * sy, rear_y - w * sy, front_y - w * sy], -1)
        nxt = [1, 2, 3, 0]
        return corner_x, corner_y, corner_x[:, nxt], corner_y[:, nxt]

    def _candidates(self, group: MoverGroup, reach: np.ndarray, g: _Beams) -> tuple[np.ndarray, np.ndarray]:
        """Beam and mover indices (K,) of the pairs where the beam could hit the mover; the others miss.

        A beam whose ray hits a mover passes within ``reach`` (m) of its centre. Over a sweep the
        centre moves at most ``speed · duration`` from where it was at the first beam, and the sensor's
        origin at most ``g.drift`` from its first position; so the ray from the first origin passes
        within ``R = reach + speed · duration + drift`` of the first centre, i.e. the beam's direction
        is within ``asin(R / ρ)`` of the first centre's bearing (ρ its distance), or ρ ≤ R.
        """
        first = g.first
        cx, cy = group.state(g.t[first])[:2]  # (count, M)
        duration = g.t[first + g.n - 1] - g.t[first]
        big_r = reach + group.speed * duration[:, None] + g.drift[:, None] + _CULL_MARGIN
        ox, oy = g.origin[first, 0, None], g.origin[first, 1, None]
        rho = np.hypot(cx - ox, cy - oy)
        bearing = np.arctan2(cy - oy, cx - ox)
        half = np.arcsin(np.minimum(big_r / np.maximum(rho, 1e-12), 1.0)) + _CULL_MARGIN_ANGLE
        return g.within(bearing - half, 2.0 * half, rho <= big_r)

    def _wall_candidates(self, g: _Beams) -> tuple[np.ndarray, np.ndarray]:
        """Beam and wall indices (K,) of the pairs where the beam could hit the wall; the others miss.

        From a point within ``g.drift`` of a sweep's first origin ``o``, a wall is seen in directions
        within ``asin((drift + margin) / d)`` of the angle it subtends from ``o`` (``d``: its distance
        from ``o``); every beam is a candidate when ``d`` is within the drift."""
        px, py, qx, qy = self._walls
        first = g.first
        ox, oy = g.origin[first, 0, None], g.origin[first, 1, None]
        ax, ay, bx, by = px - ox, py - oy, qx - ox, qy - oy  # (count, M)
        ex, ey = bx - ax, by - ay
        along = np.clip(-(ax * ex + ay * ey) / np.maximum(ex * ex + ey * ey, 1e-300), 0.0, 1.0)
        dist = np.hypot(ax + along * ex, ay + along * ey)  # from o to the wall's nearest point
        slack = g.drift[:, None] + _CULL_MARGIN
        span = np.arctan2(ax * by - ay * bx, ax * bx + ay * by)  # signed, from a to b: |span| < π
        grow = np.arcsin(np.minimum(slack / np.maximum(dist, 1e-12), 1.0)) + _CULL_MARGIN_ANGLE
        lo = np.arctan2(ay, ax) + np.minimum(span, 0.0) - grow
        return g.within(lo, np.abs(span) + 2.0 * grow, dist <= slack)

    def _hit_walls(self, g: _Beams) -> tuple[np.ndarray, ...]:
        """Per beam (N,): the nearest wall's normal x, y, its velocity x, y (0), kind (0) and range (inf: none)."""
        n = len(g.ang)
        beam, which = self._wall_candidates(g)
        r = _ray_hits(*(np.take(c, beam) for c in (g.ox, g.oy, g.dx, g.dy)),
                      *(np.take(c, which) for c in self._wall_rays))  # (K,): one wall per pair
        pair, best = _nearest(n, len(self._walls[0]), beam, which, r)
        j = which[pair] if len(beam) else np.zeros(n, dtype=np.intp)
        return (self._walls_normal[0][j], self._walls_normal[1][j], np.zeros(n), np.zeros(n),
                np.zeros(n, dtype=np.int8), best)

    def _hit_people(self, g: _Beams, nearest):
        """``nearest`` (normal x, y, target velocity x, y, kind, range; each (N,)) updated where a
        person is nearer along the beam."""
        nx, ny, vtx, vty, kind, best = nearest
        beam, who = self._candidates(self.people, self._radius, g)
        if len(beam) == 0:
            return nearest
        ox, oy = g.ox, g.oy
        cx, cy, vx, vy = self.people.state(g.t[beam], who)  # (K,) per pair
        radius = self._radius[who]
        fx, fy = ox[beam] - cx, oy[beam] - cy
        b = fx * g.dx[beam] + fy * g.dy[beam]
        disc = b * b - (fx * fx + fy * fy - radius**2)
        with np.errstate(invalid="ignore"):
            r = -b - np.sqrt(disc)
        pair, rk = _nearest(len(g.ang), len(self.people), beam, who, np.where((disc >= 0) & (r > 0), r, np.inf))
        closer = rk < best
        radius = radius[pair]
        with np.errstate(invalid="ignore"):
            hx = ox + rk * g.dx - cx[pair]
            hy = oy + rk * g.dy - cy[pair]
            nx = np.where(closer, hx / radius, nx)
            ny = np.where(closer, hy / radius, ny)
        vtx = np.where(closer, vx[pair], vtx)
        vty = np.where(closer, vy[pair], vty)
        kind = np.where(closer, 1, kind)
        return nx, ny, vtx, vty, kind, np.minimum(best, rk)

    def _hit_carts(self, g: _Beams, nearest):
        """As :meth:`_hit_people`, for the carts' sides."""
        nx, ny, vtx, vty, kind, best = nearest
        reach = np.hypot(self._half_length, self._half_width)  # a corner's distance from the centre
        beam, who = self._candidates(self.carts, reach, g)
        if len(beam) == 0:
            return nearest
        cx, cy, vx, vy = self.carts.state(g.t[beam], who)
        px, py, qx, qy = self._cart_sides(cx, cy, vx, vy, who)  # (K, 4)
        r, ex, ey = _hit_segments(g.ox[beam], g.oy[beam], g.dx[beam], g.dy[beam], px, py, qx, qy)
        side = np.arange(4)
        flat, rk = _nearest(len(g.ang), 4 * len(self.carts), np.repeat(beam, 4), (4 * who[:, None] + side).ravel(),
                            r.ravel())
        closer = rk < best
        pair, side = flat // 4, flat % 4
        with np.errstate(divide="ignore", invalid="ignore"):
            nx_c, ny_c = _normal(ex[pair, side], ey[pair, side])
        nx = np.where(closer, nx_c, nx)
        ny = np.where(closer, ny_c, ny)
        vtx = np.where(closer, vx[pair], vtx)
        vty = np.where(closer, vy[pair], vty)
        kind = np.where(closer, 2, kind)
        return nx, ny, vtx, vty, kind, np.minimum(best, rk)

    def sweep(self, body: BodyState, t_movers: np.ndarray, rng: np.random.Generator) -> Sweep:
        """Simulate one sweep. ``body`` holds the robot state at each beam's time and
        ``t_movers`` the same times on the movers' clock (s since the log start)."""
        return self.sweeps(body, t_movers, rng)[0]

    def sweeps(self, body: BodyState, t_movers: np.ndarray, rng: np.random.Generator) -> list[Sweep]:
        """Simulate consecutive sweeps at once (one numpy pass over all their beams: the per-call
        overhead of a sweep's hundred-odd array operations is shared). ``body`` and ``t_movers``
        hold every beam's state and time, sweep after sweep (count · n_beams,). The random draws
        are made sweep by sweep in the same order as one sweep at a time, so the results are the
        same bytes."""
        cfg = self.cfg
        n = len(self.beam_angle)
        count = len(t_movers) // n
        origin, heading, v_sensor = self.sensor_motion(body)
        ang = heading + np.tile(self.beam_angle, count)
        dx, dy = np.cos(ang), np.sin(ang)
        rel = origin.reshape(count, n, 2) - origin[::n, None, :]
        drift = np.sqrt(rel[..., 0]**2 + rel[..., 1]**2).max(axis=1)  # a sum over an axis of 2 is a slow reduce; same bits
        g = _Beams(origin, ang, dx, dy, np.asarray(t_movers, dtype=float), drift, n)
        # Each target is cast only against the beams that can reach it (``_Beams.within``); the
        # nearest surface wins. Kind: 0 wall, 1 person, 2 cart.
        nearest = self._hit_walls(g)  # static
        if cfg.rings > 1:
            return self._ring_sweeps(g, nearest, v_sensor, rng)
        if len(self.people):  # circles whose centre moves beam by beam
            nearest = self._hit_people(g, nearest)
        if len(self.carts):  # rectangles (4 segments each) oriented along their travel
            nearest = self._hit_carts(g, nearest)
        nx, ny, vtx, vty, kind, best = nearest

        # What the sensor reports.
        draws = [(rng.standard_normal(n), rng.standard_normal(n), rng.random(n)) for _ in range(count)]
        noise_r, noise_v, dropout = (np.concatenate(d) for d in zip(*draws))
        rate = dx * (vtx - v_sensor[:, 0]) + dy * (vty - v_sensor[:, 1])  # true range rate, m/s
        r_noisy, v_noisy, keep = _measured(best, rate, noise_r, noise_v, dropout, cfg)
        incidence = np.abs(dx * nx + dy * ny)
        reflect = np.array([_REFLECTIVITY["wall"], _REFLECTIVITY["person"], _REFLECTIVITY["cart"]])[kind]
        intensity = reflect * (0.2 + 0.8 * incidence) * np.exp(-np.where(np.isfinite(best), best, 0.0) / 60.0)

        out = []
        for i in range(count):
            part = slice(i * n, (i + 1) * n)
            k = keep[part]
            r = r_noisy[part][k]
            out.append(Sweep(
                x=r * self._beam_cos[k],
                y=r * self._beam_sin[k],
                intensity=intensity[part][k],
                velocity=v_noisy[part][k],
                t=self.beam_time[k],
                moving=(kind[part][k] > 0).astype(np.uint8),
            ))
        return out

    def _ring_sweeps(self, g: _Beams, walls: tuple[np.ndarray, ...], v_sensor: np.ndarray,
                     rng: np.random.Generator) -> list[Sweep]:
        """The sweeps of the multi-ring sensor: each beam direction of ``g`` fires every ring at once.

        A ring at elevation ``e`` travels ``d`` horizontally to reach height ``d·tan e``: it hits the
        nearest of the wall, person and cart the planar cast finds along its direction (each the
        nearest of its kind: a ray that passes over the nearest person passes over the farther
        ones too, and one that goes down meets the floor first) whose top it passes below, or the
        floor ``mount_height`` below the sensor, at ``d = mount_height / tan(−e)``. Its range is
        ``d / cos e`` and its radial velocity ``u₃ · (v_target − v_sensor)`` with the 3-D bearing
        ``u₃ = (cos e·dx, cos e·dy, sin e)``: every velocity here is horizontal, so that is
        ``cos e`` times the planar range rate.
        """
        cfg, n, count = self.cfg, g.n, g.count
        size = len(g.ang)
        nothing = (np.zeros(size), np.zeros(size), np.zeros(size), np.zeros(size), np.zeros(size, dtype=np.int8),
                   np.full(size, np.inf))
        people = self._hit_people(g, nothing) if len(self.people) else nothing
        carts = self._hit_carts(g, nothing) if len(self.carts) else nothing
        elev = np.asarray(cfg.ring_elevations)
        rings = len(elev)
        cos_e, sin_e, tan_e = np.cos(elev), np.sin(elev), np.tan(elev)
        with np.errstate(divide="ignore"):
            floor = np.where(tan_e < 0.0, cfg.mount_height / np.where(tan_e < 0.0, -tan_e, 1.0), np.inf)
        reach = np.broadcast_to(floor, (size, rings)).copy()  # horizontal distance to the surface hit, m
        which = np.full((size, rings), 3, dtype=np.intp)  # 0 wall, 1 person, 2 cart, 3 floor
        tops = (np.inf, PERSON_HEIGHT - cfg.mount_height, CART_HEIGHT - cfg.mount_height)
        for k, (group, top) in enumerate(zip((walls, people, carts), tops)):
            d = group[5][:, None]
            with np.errstate(invalid="ignore"):
                hit = (d < reach) & (d * tan_e <= top)
            reach = np.where(hit, d, reach)
            which = np.where(hit, k, which)
        beam = np.arange(size)[:, None]

        def pick(i: int) -> np.ndarray:  # a quantity of the surface each ring hit (the floor's: 0), (size, rings)
            return np.stack([walls[i], people[i], carts[i], np.zeros(size)])[which, beam]

        vtx, vty = pick(2), pick(3)
        dx, dy = g.dx[:, None], g.dy[:, None]
        rate = cos_e * (dx * (vtx - v_sensor[:, 0, None]) + dy * (vty - v_sensor[:, 1, None]))  # m/s
        best = reach / cos_e  # 3-D range, m
        incidence = np.where(which == 3, np.abs(sin_e), cos_e * np.abs(dx * pick(0) + dy * pick(1)))
        reflect = np.array([_REFLECTIVITY[k] for k in ("wall", "person", "cart", "floor")])[which]
        intensity = reflect * (0.2 + 0.8 * incidence) * np.exp(-np.where(np.isfinite(best), best, 0.0) / 60.0)

        m = n * rings
        draws = [(rng.standard_normal(m), rng.standard_normal(m), rng.random(m)) for _ in range(count)]
        noise_r, noise_v, dropout = (np.concatenate(d).reshape(size, rings) for d in zip(*draws))
        r_noisy, v_noisy, keep = _measured(best, rate, noise_r, noise_v, dropout, cfg)
        flat = r_noisy * cos_e  # the range's horizontal part, m
        x, y = flat * np.tile(self._beam_cos, count)[:, None], flat * np.tile(self._beam_sin, count)[:, None]
        z = r_noisy * sin_e
        t = np.broadcast_to(np.tile(self.beam_time, count)[:, None], (size, rings))
        ring = np.broadcast_to(np.arange(rings, dtype=np.uint16), (size, rings))
        moving = ((which == 1) | (which == 2)).astype(np.uint8)
        out = []
        for i in range(count):
            part = slice(i * n, (i + 1) * n)
            k = keep[part]
            out.append(Sweep(x=x[part][k], y=y[part][k], intensity=intensity[part][k], velocity=v_noisy[part][k],
                             t=t[part][k], moving=moving[part][k], z=z[part][k], ring=ring[part][k]))
        return out


def _measured(best: np.ndarray, rate: np.ndarray, noise_r: np.ndarray, noise_v: np.ndarray, dropout: np.ndarray,
              cfg: SensorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the sensor reports of true ranges ``best`` (m) and range rates ``rate`` (m/s): each with its
    Gaussian noise and quantisation, and which returns it keeps (in range, not dropped, beyond
    ``min_range``). ``noise_r``, ``noise_v``: standard normal draws; ``dropout``: uniform draws."""
    r_noisy = best + cfg.range_sigma * noise_r
    v_noisy = rate + cfg.doppler_sigma * noise_v
    keep = np.isfinite(best) & (best <= cfg.max_range) & (dropout >= cfg.dropout)
    if cfg.range_resolution > 0:
        r_noisy = np.round(r_noisy / cfg.range_resolution) * cfg.range_resolution
    if cfg.doppler_resolution > 0:
        v_noisy = np.round(v_noisy / cfg.doppler_resolution) * cfg.doppler_resolution
    keep &= r_noisy >= cfg.min_range
    return r_noisy, v_noisy, keep
