"""The simulator's multi-ring sensor (``sensor.rings`` > 1) against geometry and physics written here.

Each ring at elevation ``e`` travels a horizontal distance ``d`` to reach height ``d·tan e``: it hits
a wall (unbounded height), a mover whose top it passes below, or the floor ``mount_height`` below the
sensor; its radial velocity is ``−u₃·v_s`` for a static point, ``u₃`` the 3-D unit bearing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmcwlog.errors import ConfigError
from fmcwlog.sim import scenarios
from fmcwlog.sim.chassis import BodyState
from fmcwlog.sim.config import RING_KEYS, SensorConfig, SimConfig, apply_overrides
from fmcwlog.sim.lidar import CART_HEIGHT, FmcwLidar
from fmcwlog.sim.movers import Mover

EXACT = {"range_sigma": 0.0, "range_resolution": 0.0, "doppler_sigma": 0.0, "doppler_resolution": 0.0,
         "dropout": 0.0, "max_range": 1000.0, "min_range": 0.0}
RINGS = {"rings": 5, "ring_min_deg": -20.0, "ring_max_deg": 20.0, "mount_height": 0.5}  # -20, -10, 0, 10, 20 deg


def _sweep(cfg: SensorConfig, movers: list[Mover], v: float = 1.0):
    """One sweep from the origin (heading +x, moving at ``v`` m/s along x) towards a wall at x = 4 m."""
    lidar = FmcwLidar(cfg, np.array([[4.0, -50.0, 4.0, 50.0]]), movers)
    n = cfg.n_beams
    t = lidar.beam_time
    zero = np.zeros(n)
    body = BodyState(t, zero, zero, zero, np.full(n, v), zero, zero)
    return lidar, lidar.sweep(body, t, np.random.default_rng(0))


def test_rings_hit_the_wall_and_the_floor_where_geometry_says_with_the_doppler_of_their_3d_bearing():
    cfg = SensorConfig(**EXACT, **RINGS, fov_deg=60.0, resolution_deg=2.0, mount_x=0.0)
    lidar, s = _sweep(cfg, [])
    elev = np.radians([-20.0, -10.0, 0.0, 10.0, 20.0])
    assert np.allclose(cfg.ring_elevations, elev)
    assert len(s.x) == cfg.n_beams * 5 and s.z is not None and s.ring is not None
    assert s.ring.dtype == np.uint16
    assert np.array_equal(s.ring, np.tile(np.arange(5), cfg.n_beams))  # beam by beam, every ring at once
    assert np.array_equal(s.t, np.repeat(lidar.beam_time, 5))
    phi = np.repeat(lidar.beam_angle, 5)
    e = elev[s.ring]
    floor = e < 0  # the wall is 4 m ahead and more; the floor 0.5 m below, reached at 2.84 m (-10 deg) or nearer
    d = np.where(floor, 0.5 / np.tan(np.maximum(np.abs(e), 1e-3)), 4.0 / np.cos(phi))  # horizontal distance, m
    assert np.allclose(np.hypot(s.x, s.y), d)
    assert np.allclose(np.arctan2(s.y, s.x), phi)
    assert np.allclose(s.z, np.where(floor, -0.5, d * np.tan(e)))
    u3 = np.column_stack([np.cos(e) * np.cos(phi), np.cos(e) * np.sin(phi), np.sin(e)])
    assert np.allclose(s.velocity, -u3 @ np.array([1.0, 0.0, 0.0]))  # static world, sensor moving at 1 m/s along x
    assert not s.moving.any()


def test_a_ring_passes_over_a_mover_lower_than_it_and_meets_the_floor_before_one_beyond_it():
    """A cart (1 m tall, its near side 1.5 m ahead, the sensor 0.5 m up) moving away at 0.8 m/s: +20 deg
    passes over it to the wall, -20 deg meets the floor at 1.37 m first, the others hit the cart, with
    the cart's velocity in their Doppler."""
    cfg = SensorConfig(**EXACT, **RINGS, fov_deg=2.0, resolution_deg=2.0, mount_x=0.0)  # beams at -1, +1 deg
    cart = Mover("cart", [[2.0, 0.0], [30.0, 0.0]], speed=0.8, length=1.0, width=0.6)
    _, s = _sweep(cfg, [cart], v=0.0)
    assert (CART_HEIGHT, cfg.mount_height) == (1.0, 0.5)
    e = np.radians([-20.0, -10.0, 0.0, 10.0, 20.0])[s.ring]
    d = np.hypot(s.x, s.y)
    on_cart = (s.ring >= 1) & (s.ring <= 3)
    near_side = 1.5 + 0.8 * s.t  # the cart's rear side moves away during the sweep
    assert np.allclose(d[on_cart], near_side[on_cart] / np.cos(np.radians(1.0)), atol=1e-9)
    assert np.array_equal(s.moving, on_cart.astype(np.uint8))
    assert np.allclose(d[s.ring == 0], 0.5 / np.tan(np.radians(20.0)))
    assert np.allclose(s.z[s.ring == 4], d[s.ring == 4] * np.tan(np.radians(20.0)))
    assert np.allclose(d[s.ring == 4] * np.cos(np.radians(1.0)), 4.0)
    phi = np.arctan2(s.y, s.x)
    expected = np.cos(e) * np.cos(phi) * 0.8  # the cart moves away along x; the sensor stands
    assert np.allclose(s.velocity[on_cart], expected[on_cart])


def test_the_default_sensor_is_planar_and_its_record_is_what_it_was():
    cfg = SimConfig()
    assert cfg.sensor.rings == 1 and cfg.sensor.ring_elevations == (0.0,)
    recorded = cfg.recorded()
    assert not set(RING_KEYS) & set(recorded["sensor"])
    assert {k: v for k, v in cfg.as_dict()["sensor"].items() if k not in RING_KEYS} == recorded["sensor"]
    rings = apply_overrides(cfg, {"sensor": {"rings": 16}})
    assert rings.recorded()["sensor"]["rings"] == 16  # a multi-ring log records them
    world = scenarios.SCENARIOS["corridor"]()
    sweep = FmcwLidar(cfg.sensor, world.walls, world.movers).sweep(
        BodyState(*(np.full(cfg.sensor.n_beams, v) for v in (0.0, 2.0, 1.5, 0.0, 1.0, 0.0, 0.0))),
        np.zeros(cfg.sensor.n_beams), np.random.default_rng(0))
    assert sweep.z is None and sweep.ring is None


@pytest.mark.parametrize("sets, words", [
    ({"rings": 16, "ring_min_deg": 10.0, "ring_max_deg": 10.0}, "must be below sensor.ring_max_deg"),
    ({"rings": 128, "resolution_deg": 0.1}, "points a sweep"),
    ({"rings": 0}, "out of range"),
    ({"ring_max_deg": 75.0}, "out of range"),
])
def test_ring_parameters_out_of_range_are_refused_naming_them(sets, words):
    with pytest.raises(ConfigError, match=words):
        apply_overrides(SimConfig(), {"sensor": sets}).validate()


def test_sixteen_rings_span_the_configured_elevations():
    cfg = SensorConfig(rings=16)
    assert np.allclose(np.degrees(cfg.ring_elevations), np.arange(-15.0, 16.0, 2.0))
    assert math.isclose(max(np.degrees(cfg.ring_elevations)), 15.0)
