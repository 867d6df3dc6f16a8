"""The route's closed form: ``Route.at`` takes the trig of the heading only on arcs and of each
piece's start heading once; it must give, bit for bit, what the formulas give evaluated at every
sample (the recorder's logs are byte-identical to those made that way)."""

from __future__ import annotations

import numpy as np

from fmcwlog.sim import scenarios
from fmcwlog.sim.route import build_route


def _at_everywhere(route, s):
    """The closed form at every sample, both branches taken everywhere and chosen by ``np.where``."""
    total = route.total_length
    lap = np.floor(s / total) if route.loop else np.zeros_like(s)
    s_in = s - lap * total if route.loop else np.clip(s, 0.0, total)
    i = np.clip(np.searchsorted(route.start_s, s_in, side="right") - 1, 0, len(route.start_s) - 1)
    ds, k, h0 = s_in - route.start_s[i], route.curvature[i], route.start_heading[i]
    h = h0 + k * ds
    straight = np.abs(k) < 1e-12
    k_safe = np.where(straight, 1.0, k)
    dx = np.where(straight, ds * np.cos(h0), (np.sin(h) - np.sin(h0)) / k_safe)
    dy = np.where(straight, ds * np.sin(h0), (np.cos(h0) - np.cos(h)) / k_safe)
    return route.start_xy[i, 0] + dx, route.start_xy[i, 1] + dy, h + lap * route.turn_per_lap, k


def test_route_positions_are_the_closed_form_bit_for_bit():
    rng = np.random.default_rng(3)
    routes = [scenarios.SCENARIOS[name]().route.build() for name in ("corridor", "crowd", "long-corridor", "ring")]
    routes.append(build_route(np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 4.0], [9.0, 7.0]]), False, 1.0))  # open
    for route in routes:
        s = np.concatenate([rng.uniform(-1.0, 3.5 * route.total_length, 5000), route.start_s, [0.0]])
        for got, want in zip(route.at(s), _at_everywhere(route, s)):
            assert np.array_equal(np.asarray(got).view(np.int64), np.asarray(want).view(np.int64))
        x, y, _, _ = route.at(np.linspace(0.0, route.total_length, 20001))  # and continuous, as a path is
        assert np.hypot(np.diff(x), np.diff(y)).max() <= 1.0001 * route.total_length / 20000
