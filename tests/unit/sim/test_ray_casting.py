"""The simulator's ray caster against a brute-force one written here.

:class:`fmcwlog.sim.lidar.FmcwLidar` casts each wall, person and cart only against the beams
that can reach it (a bound on directions, ``_Beams.within``), several sweeps at once. Here every
beam is cast against every target, one sweep at a time, with the movers' positions computed
from their own definition (back and forth along a straight path at constant speed): the nearest
ranges and which returns are on movers must agree, in random worlds where walls and movers pass
close to the sensor, with a 360-degree field of view and a robot that turns fast.
"""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.sim.chassis import BodyState
from fmcwlog.sim.config import SensorConfig
from fmcwlog.sim.lidar import FmcwLidar
from fmcwlog.sim.movers import Mover

EXACT = {"range_sigma": 0.0, "range_resolution": 0.0, "doppler_sigma": 0.0, "doppler_resolution": 0.0,
         "dropout": 0.0, "max_range": 1000.0, "min_range": 0.0}


def _centre(m: Mover, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre (N, 2) and velocity (N, 2) of a mover on a straight two-point path at times t."""
    a, b = m.path
    length = np.linalg.norm(b - a)
    u = (b - a) / length
    cyc = np.mod(m.phase + m.speed * t, 2 * length)
    s = np.where(cyc > length, 2 * length - cyc, cyc)
    sign = np.where(cyc > length, -1.0, 1.0)
    return a + s[:, None] * u, (m.speed * sign)[:, None] * u


def _ray_segments(o, d, p, q):
    """Ranges (N, M) along rays o + r d (N, 2) to segments p -> q (N or 1, M, 2); inf where missed."""
    e, w, d = q - p, p - o[:, None], d[:, None]
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    den = cross(d, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        r, u = cross(w, e) / den, cross(w, d) / den
    return np.where((np.abs(den) > 1e-12) & (r > 0) & (u >= 0) & (u <= 1), r, np.inf)


def _brute_force(cfg: SensorConfig, walls: np.ndarray, movers: list[Mover], body: BodyState):
    """Nearest range (N,) of every beam and whether a mover gave it."""
    n = cfg.n_beams
    beam = -np.radians(cfg.fov_deg) / 2 + np.radians(cfg.resolution_deg) * np.arange(n)
    c, s = np.cos(body.yaw), np.sin(body.yaw)
    o = np.stack([body.x + c * cfg.mount_x - s * cfg.mount_y, body.y + s * cfg.mount_x + c * cfg.mount_y], -1)
    ang = body.yaw + np.radians(cfg.mount_yaw_deg) + beam
    d = np.stack([np.cos(ang), np.sin(ang)], -1)
    ranges = [_ray_segments(o, d, walls[None, :, :2], walls[None, :, 2:])]
    for m in movers:
        cen, vel = _centre(m, body.t)
        if m.kind == "person":
            f = o - cen
            b = (f * d).sum(1)
            disc = b * b - ((f * f).sum(1) - m.radius**2)
            with np.errstate(invalid="ignore"):
                r = -b - np.sqrt(disc)
            ranges.append(np.where((disc >= 0) & (r > 0), r, np.inf)[:, None])
        else:
            fwd = vel / np.linalg.norm(vel, axis=1, keepdims=True)
            side = np.stack([-fwd[:, 1], fwd[:, 0]], -1)
            a, w = m.length / 2, m.width / 2
            corners = [cen + a * fwd + w * side, cen - a * fwd + w * side, cen - a * fwd - w * side, cen + a * fwd - w * side]
            p = np.stack(corners, 1)
            ranges.append(_ray_segments(o, d, p, np.roll(p, -1, axis=1)))
    walls_r = ranges[0].min(1)
    movers_r = np.concatenate(ranges[1:], 1).min(1) if movers else np.full(n, np.inf)
    return np.minimum(walls_r, movers_r), movers_r < walls_r


def _world(rng: np.random.Generator, sensor_xy: np.ndarray):
    walls = rng.uniform(-15, 15, (20, 4))
    walls[:4, :2] = sensor_xy + rng.uniform(-0.5, 0.5, (4, 2))  # walls that start at the sensor's feet
    walls[:4, 2:] = walls[:4, :2] + rng.uniform(-0.6, 0.6, (4, 2))
    walls[4] = np.concatenate([sensor_xy - [0.6, 0.03], sensor_xy + [0.6, -0.03]])  # one the sensor grazes
    movers = []
    for i in range(14):
        a = sensor_xy + (rng.uniform(-6, 6, 2) if i % 3 else rng.uniform(-0.4, 0.4, 2))  # some pass over the sensor
        b = a + rng.uniform(-4, 4, 2)
        kind = "cart" if i % 4 == 3 else "person"
        movers.append(Mover(kind, [a, b], float(rng.uniform(0.3, 2.5)), phase=float(rng.uniform(0, 10)),
                            radius=float(rng.uniform(0.1, 0.5)), length=float(rng.uniform(0.5, 1.5)),
                            width=float(rng.uniform(0.3, 0.8))))
    return walls, movers


@pytest.mark.parametrize("seed", range(6))
def test_culled_casting_finds_the_nearest_surface_of_every_beam(seed):
    rng = np.random.default_rng(seed)
    cfg = SensorConfig(fov_deg=360.0 if seed % 2 else 270.0, resolution_deg=0.5, mount_x=0.35,
                       mount_y=float(rng.uniform(-0.2, 0.2)), mount_yaw_deg=float(rng.uniform(-180, 180)), **EXACT)
    xy0, yaw0 = rng.uniform(-3, 3, 2), rng.uniform(-50, 50)  # unwrapped yaw: many laps
    v, omega = rng.uniform(0, 3), rng.uniform(-3, 3)  # a fast turn
    walls, movers = _world(rng, xy0)
    lidar = FmcwLidar(cfg, walls, movers)
    count = 4
    t = (rng.uniform(0, 30) + np.arange(count)[:, None] / cfg.scan_rate + lidar.beam_time).ravel()
    tt = t - t[0]
    body = BodyState(t, xy0[0] + v * tt * np.cos(yaw0), xy0[1] + v * tt * np.sin(yaw0), yaw0 + omega * tt,
                     np.full_like(t, v), np.full_like(t, omega), v * tt)
    sweeps = lidar.sweeps(body, t, np.random.default_rng(0))
    n = cfg.n_beams
    for i, sweep in enumerate(sweeps):
        part = slice(i * n, (i + 1) * n)
        want_r, want_moving = _brute_force(cfg, walls, movers, BodyState(*(a[part] for a in (
            body.t, body.x, body.y, body.yaw, body.v, body.omega, body.s))))
        hit = np.isfinite(want_r)
        assert len(sweep.x) == hit.sum()
        np.testing.assert_allclose(np.hypot(sweep.x, sweep.y), want_r[hit], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(sweep.moving.astype(bool), want_moving[hit])
        assert want_moving.any() and (~want_moving & hit).any()  # both kinds of return are exercised


@pytest.mark.parametrize("mount", [(0.35, 0.0, 0.0), (-0.35, 0.0, 0.3), (0.35, 0.1, 0.0), (0.0, 0.0, 0.0)])
def test_sensor_motion_is_the_rotated_lever_arm_bit_for_bit(mount):
    """The sensor's origin and velocity, o = p + R(yaw)·l and v·(cos, sin) + ω × R(yaw)·l: written
    out for a mount on the x axis, they must be the bits of the matrix product (the logs' bytes)."""
    from fmcwlog.geometry import rot2

    rng = np.random.default_rng(11)
    n = 4000
    yaw = np.concatenate([[0.0, -0.0, np.pi, -np.pi / 2], rng.uniform(-40.0, 40.0, n - 4)])
    body = BodyState(np.zeros(n), rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), yaw, rng.normal(size=n),
                     rng.normal(size=n), np.zeros(n))
    lidar = FmcwLidar(SensorConfig(mount_x=mount[0], mount_y=mount[1], mount_yaw_deg=np.degrees(mount[2])),
                      np.array([[0.0, 0.0, 1.0, 0.0]]), [])
    origin, heading, vel = lidar.sensor_motion(body)
    lever = rot2(yaw) @ lidar.mount[:2]
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    want = (np.stack([body.x, body.y], -1) + lever, yaw + lidar.mount[2],
            body.v[:, None] * fwd + body.omega[:, None] * np.stack([-lever[:, 1], lever[:, 0]], -1))
    for got, expected in zip((origin, heading, vel), want):
        assert np.array_equal(got.view(np.int64), expected.view(np.int64))
