"""The path the robot's ``base_link`` follows and its speed along it.

A route is a polyline of waypoints whose corners are rounded by circular arcs
(a car-like robot cannot turn on the spot), either a closed loop driven lap
after lap or an open path at whose end the robot stops. Position, heading and
curvature are closed-form functions of the arc length ``s``; ``s`` is a
closed-form function of time (accelerate, cruise, and for an open route
brake to a stop). Heading is returned unwrapped, so wheel travel can be
integrated exactly: a rear wheel at lateral offset ``±b/2`` rolls
``s ∓ (b/2)·(θ(s) - θ(0))``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Route:
    """Pieces (straight: curvature 0, or arc) laid end to end; lengths in metres."""

    start_s: np.ndarray  # (P,) arc length where each piece starts
    length: np.ndarray  # (P,)
    start_xy: np.ndarray  # (P, 2)
    start_heading: np.ndarray  # (P,) unwrapped, rad
    curvature: np.ndarray  # (P,) 1/m, positive turning left
    loop: bool

    @property
    def total_length(self) -> float:
        return float(self.start_s[-1] + self.length[-1])

    @property
    def turn_per_lap(self) -> float:
        """Heading change over the whole route (±2π for a simple loop)."""
        return float(self.start_heading[-1] + self.curvature[-1] * self.length[-1] - self.start_heading[0])

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(x, y, heading, curvature)`` at arc lengths ``s`` (heading unwrapped across laps)."""
        s = np.asarray(s, dtype=float)
        total = self.total_length
        if self.loop:
            lap = np.floor(s / total)
            s_in = s - lap * total
        else:
            lap = np.zeros_like(s)
            s_in = np.clip(s, 0.0, total)
        i = np.clip(np.searchsorted(self.start_s, s_in, side="right") - 1, 0, len(self.start_s) - 1)
        ds = s_in - self.start_s[i]
        k = self.curvature[i]
        h0 = self.start_heading[i]
        h = h0 + k * ds
        cos0, sin0 = self._start_trig
        dx, dy = ds * cos0[i], ds * sin0[i]  # on a straight piece
        arc = np.abs(k) >= 1e-12
        if arc.any():  # the trig of h only where it is used (the same values, elementwise, as over every s)
            ha, ka, ia = h[arc], k[arc], i[arc]
            dx[arc] = (np.sin(ha) - sin0[ia]) / ka
            dy[arc] = (cos0[ia] - np.cos(ha)) / ka
        x = self.start_xy[i, 0] + dx
        y = self.start_xy[i, 1] + dy
        return x, y, h + lap * self.turn_per_lap, k

    @cached_property
    def _start_trig(self) -> tuple[np.ndarray, np.ndarray]:
        """Cosine and sine of each piece's start heading (P,): computed once, not once per ``s``."""
        return np.cos(self.start_heading), np.sin(self.start_heading)


def _waypoints(waypoints: np.ndarray, loop: bool) -> np.ndarray:
    pts = np.asarray(waypoints, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError("a route needs at least two [x, y] waypoints")
    if loop and len(pts) < 3:
        raise ValueError("a looped route needs at least three waypoints")
    if loop and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    return pts


def _corners(seg_dir: np.ndarray, seg_len: np.ndarray, n: int, loop: bool,
             corner_radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per waypoint: the turn (rad), the arc's radius and its tangent length (m); 0 where straight."""
    seg_count = len(seg_dir)
    tangent, turn, radius = np.zeros(n), np.zeros(n), np.zeros(n)
    for v in range(n) if loop else range(1, n - 1):
        a, b = seg_dir[(v - 1) % seg_count], seg_dir[v % seg_count]
        ang = float(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b))
        if abs(ang) < 1e-9:
            continue
        if abs(abs(ang) - np.pi) < 1e-6:
            raise ValueError("a route must not turn back on itself")
        half = 0.5 * min(seg_len[(v - 1) % seg_count], seg_len[v % seg_count])
        r = min(corner_radius, half / np.tan(abs(ang) / 2.0))
        turn[v], radius[v], tangent[v] = ang, r, r * np.tan(abs(ang) / 2.0)
    return turn, radius, tangent


def build_route(waypoints: np.ndarray, loop: bool, corner_radius: float) -> Route:
    """Round each corner of the polyline with an arc of ``corner_radius`` (shrunk where
    the adjacent segments are too short) and lay the pieces end to end."""
    pts = _waypoints(waypoints, loop)
    n = len(pts)
    seg_count = n if loop else n - 1
    seg_vec = np.array([pts[(i + 1) % n] - pts[i] for i in range(seg_count)])
    seg_len = np.linalg.norm(seg_vec, axis=1)
    if np.any(seg_len < 1e-9):
        raise ValueError("route waypoints must not repeat")
    seg_dir = seg_vec / seg_len[:, None]
    turn, radius, tangent = _corners(seg_dir, seg_len, n, loop, corner_radius)

    start_s, length, start_xy, heading, curvature = [], [], [], [], []
    s = 0.0
    h = float(np.arctan2(seg_dir[0, 1], seg_dir[0, 0]))

    def add(xy, L, k):
        nonlocal s, h
        start_s.append(s)
        length.append(L)
        start_xy.append(xy)
        heading.append(h)
        curvature.append(k)
        s += L
        h += k * L

    for i in range(seg_count):
        v0, v1 = i, (i + 1) % n
        a = pts[v0] + seg_dir[i] * tangent[v0]
        L = seg_len[i] - tangent[v0] - tangent[v1]
        if L > 1e-9:
            add(a, L, 0.0)
        if (loop or v1 != n - 1) and turn[v1] != 0.0:
            add(pts[v1] - seg_dir[i] * tangent[v1], radius[v1] * abs(turn[v1]), np.sign(turn[v1]) / radius[v1])
    return Route(*(np.asarray(x, dtype=float) for x in (start_s, length, start_xy, heading, curvature)), loop=loop)


@dataclass(frozen=True)
class SpeedProfile:
    """Trapezoidal speed: accelerate from rest at ``acceleration`` to ``speed``; if the
    route is open (``stop_at`` finite) brake to rest exactly at ``s = stop_at``."""

    speed: float
    acceleration: float
    stop_at: float = np.inf

    def _phases(self) -> tuple[float, float, float]:
        v, a = self.speed, self.acceleration
        if np.isfinite(self.stop_at) and v * v / a > self.stop_at:  # never reaches cruise speed
            v = float(np.sqrt(self.stop_at * a))
        t_acc = v / a
        cruise = (self.stop_at - v * v / a) / v if np.isfinite(self.stop_at) else np.inf
        return v, t_acc, cruise

    def distance_speed_accel(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arc length (m), speed (m/s) and acceleration (m/s^2) at times ``t`` (s, from start)."""
        t = np.asarray(t, dtype=float)
        v, t_acc, cruise = self._phases()
        a = self.acceleration
        t_brake = t_acc + cruise
        s = np.where(t < t_acc, 0.5 * a * t**2, 0.5 * v * t_acc + v * (t - t_acc))
        spd = np.where(t < t_acc, a * t, v)
        acc = np.where(t < t_acc, a, 0.0)
        if np.isfinite(cruise):
            tb = np.clip(t - t_brake, 0.0, t_acc)
            braking = t >= t_brake
            s_b = 0.5 * v * t_acc + v * cruise + v * tb - 0.5 * a * tb**2
            s = np.where(braking, s_b, s)
            spd = np.where(braking, v - a * tb, spd)
            acc = np.where(braking & (t - t_brake < t_acc), -a, np.where(braking, 0.0, acc))
        return s, spd, acc
