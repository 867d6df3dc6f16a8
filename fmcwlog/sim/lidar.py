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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import rot2
from .chassis import BodyState
from .config import SensorConfig
from .movers import Mover

_REFLECTIVITY = {"wall": 0.6, "person": 0.3, "cart": 0.85}


@dataclass(frozen=True)
class Sweep:
    """One sweep as the sensor reports it (frame ``lidar``), with per-point truth."""

    x: np.ndarray  # (N,) m
    y: np.ndarray
    intensity: np.ndarray  # (N,) unitless, 0..1
    velocity: np.ndarray  # (N,) m/s, radial, positive when the range grows
    t: np.ndarray  # (N,) s after the sweep's stamp
    moving: np.ndarray  # (N,) uint8, 1 where the return came from a mover


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _hit_segments(ox, oy, dx, dy, p, q):
    """Ranges (N, M) along rays o + r·d to segments p→q ((M, 2) or (N, M, 2)); inf where missed.
    Also the segments' unit normals."""
    ex, ey = q[..., 0] - p[..., 0], q[..., 1] - p[..., 1]
    wx, wy = p[..., 0] - ox[:, None], p[..., 1] - oy[:, None]
    den = _cross(dx[:, None], dy[:, None], ex, ey)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = _cross(wx, wy, ex, ey) / den
        u = _cross(wx, wy, dx[:, None], dy[:, None]) / den
    ok = (np.abs(den) > 1e-12) & (r > 0) & (u >= 0) & (u <= 1)
    norm = np.hypot(ex, ey)
    return np.where(ok, r, np.inf), -ey / norm, ex / norm


class FmcwLidar:
    """Casts one sweep's beams into a world at the times each beam is fired."""

    def __init__(self, cfg: SensorConfig, walls: np.ndarray, movers: list[Mover]):
        self.cfg = cfg
        self.walls_p = walls[:, 0:2].copy()
        self.walls_q = walls[:, 2:4].copy()
        self.people = [m for m in movers if m.kind == "person"]
        self.carts = [m for m in movers if m.kind == "cart"]
        n = cfg.n_beams
        half = np.radians(cfg.fov_deg) / 2.0
        self.beam_angle = -half + np.radians(cfg.resolution_deg) * np.arange(n)  # rad, in ``lidar``
        self.beam_time = cfg.sweep_duration * np.arange(n) / max(n - 1, 1)  # s after the stamp
        self.mount = np.array(cfg.mount)

    def sensor_motion(self, body: BodyState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Origin (N, 2), heading (N,) and origin velocity (N, 2) of ``lidar`` in ``map``."""
        lever = (rot2(body.yaw) @ self.mount[:2])  # (N, 2): R(yaw)·l
        origin = np.stack([body.x, body.y], -1) + lever
        heading = body.yaw + self.mount[2]
        fwd = np.stack([np.cos(body.yaw), np.sin(body.yaw)], -1)
        vel = body.v[:, None] * fwd + body.omega[:, None] * np.stack([-lever[:, 1], lever[:, 0]], -1)
        return origin, heading, vel

    def sweep(self, body: BodyState, t_movers: np.ndarray, rng: np.random.Generator) -> Sweep:
        """Simulate one sweep. ``body`` holds the robot state at each beam's time and
        ``t_movers`` the same times on the movers' clock (s since the log start)."""
        cfg = self.cfg
        origin, heading, v_sensor = self.sensor_motion(body)
        ang = heading + self.beam_angle
        dx, dy = np.cos(ang), np.sin(ang)
        ox, oy = origin[:, 0], origin[:, 1]
        n = len(ang)

        # Walls: static.
        r_w, nx_w, ny_w = _hit_segments(ox, oy, dx, dy, self.walls_p, self.walls_q)
        j = np.argmin(r_w, axis=1)
        best = r_w[np.arange(n), j]
        nx, ny = nx_w[j], ny_w[j]
        vtx, vty = np.zeros(n), np.zeros(n)
        kind = np.zeros(n, dtype=np.int8)  # 0 wall, 1 person, 2 cart

        # People: circles whose centre moves beam by beam.
        if self.people:
            c, vel = zip(*(m.state(t_movers) for m in self.people))
            c, vel = np.stack(c, 1), np.stack(vel, 1)  # (N, P, 2)
            radius = np.array([m.radius for m in self.people])
            fx, fy = ox[:, None] - c[..., 0], oy[:, None] - c[..., 1]
            b = fx * dx[:, None] + fy * dy[:, None]
            disc = b * b - (fx * fx + fy * fy - radius**2)
            with np.errstate(invalid="ignore"):
                r_p = -b - np.sqrt(disc)
            r_p = np.where((disc >= 0) & (r_p > 0), r_p, np.inf)
            k = np.argmin(r_p, axis=1)
            rk = r_p[np.arange(n), k]
            closer = rk < best
            with np.errstate(invalid="ignore"):
                hx = ox + rk * dx - c[np.arange(n), k, 0]
                hy = oy + rk * dy - c[np.arange(n), k, 1]
                nx = np.where(closer, hx / radius[k], nx)
                ny = np.where(closer, hy / radius[k], ny)
            vtx = np.where(closer, vel[np.arange(n), k, 0], vtx)
            vty = np.where(closer, vel[np.arange(n), k, 1], vty)
            kind = np.where(closer, 1, kind)
            best = np.minimum(best, rk)

        # Carts: rectangles (4 segments each) oriented along their travel.
        if self.carts:
            ps, qs, vs = [], [], []
            for m in self.carts:
                cen, vel = m.state(t_movers)
                spd = np.linalg.norm(vel, axis=1, keepdims=True)
                fwd = np.where(spd > 0, vel / np.where(spd > 0, spd, 1.0), [1.0, 0.0])
                side = np.stack([-fwd[:, 1], fwd[:, 0]], -1)
                a, w = 0.5 * m.length, 0.5 * m.width
                corners = [cen + a * fwd + w * side, cen - a * fwd + w * side, cen - a * fwd - w * side, cen + a * fwd - w * side]
                for i in range(4):
                    ps.append(corners[i])
                    qs.append(corners[(i + 1) % 4])
                    vs.append(vel)
            p, q, vel = np.stack(ps, 1), np.stack(qs, 1), np.stack(vs, 1)  # (N, 4C, 2)
            r_c, nx_c, ny_c = _hit_segments(ox, oy, dx, dy, p, q)
            k = np.argmin(r_c, axis=1)
            idx = np.arange(n)
            rk = r_c[idx, k]
            closer = rk < best
            nx = np.where(closer, nx_c[idx, k], nx)
            ny = np.where(closer, ny_c[idx, k], ny)
            vtx = np.where(closer, vel[idx, k, 0], vtx)
            vty = np.where(closer, vel[idx, k, 1], vty)
            kind = np.where(closer, 2, kind)
            best = np.minimum(best, rk)

        # What the sensor reports.
        rate = dx * (vtx - v_sensor[:, 0]) + dy * (vty - v_sensor[:, 1])  # true range rate, m/s
        r_noisy = best + cfg.range_sigma * rng.standard_normal(n)
        v_noisy = rate + cfg.doppler_sigma * rng.standard_normal(n)
        keep = np.isfinite(best) & (best <= cfg.max_range) & (rng.random(n) >= cfg.dropout)
        if cfg.range_resolution > 0:
            r_noisy = np.round(r_noisy / cfg.range_resolution) * cfg.range_resolution
        if cfg.doppler_resolution > 0:
            v_noisy = np.round(v_noisy / cfg.doppler_resolution) * cfg.doppler_resolution
        keep &= r_noisy >= cfg.min_range
        incidence = np.abs(dx * nx + dy * ny)
        reflect = np.array([_REFLECTIVITY["wall"], _REFLECTIVITY["person"], _REFLECTIVITY["cart"]])[kind]
        intensity = reflect * (0.2 + 0.8 * incidence) * np.exp(-np.where(np.isfinite(best), best, 0.0) / 60.0)

        phi = self.beam_angle[keep]
        r = r_noisy[keep]
        return Sweep(
            x=r * np.cos(phi),
            y=r * np.sin(phi),
            intensity=intensity[keep],
            velocity=v_noisy[keep],
            t=self.beam_time[keep],
            moving=(kind[keep] > 0).astype(np.uint8),
        )
