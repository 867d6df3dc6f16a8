"""The route's closed form (``Route.at``) against the geometry of a path parameterised by its arc
length, not against a copy of its formulas: the polyline with its corners cut by circular arcs has
the length fillet geometry gives; the position moves along the heading at unit speed; the heading
turns at the curvature (0 on straights, 1/radius on arcs); straights lie on the waypoints' segments;
a loop repeats after one length, its heading turned by ±2π (a simple closed curve); an open route
runs from its first waypoint to its last and stays there."""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.sim import scenarios
from fmcwlog.sim.route import build_route

OPEN = (np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 4.0], [9.0, 7.0]]), False, 1.0)  # a left turn, then a right one


def _cases():
    for name in ("corridor", "crowd", "long-corridor", "ring", "warehouse"):
        spec = scenarios.SCENARIOS[name]().route
        yield name, np.asarray(spec.waypoints, float), spec.loop, spec.corner_radius
    yield "open", *OPEN


def _segments(waypoints, loop):
    ends = np.roll(waypoints, -1, axis=0) if loop else waypoints[1:]
    return (waypoints if loop else waypoints[:-1]), ends


def _turns(waypoints, loop):
    """The signed turn (rad) at each corner where the path changes direction."""
    a, b = _segments(waypoints, loop)
    d = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
    turns = np.angle(np.exp(1j * (np.roll(d, -1) - d))) if loop else np.angle(np.exp(1j * np.diff(d)))
    return turns[np.abs(turns) > 1e-9]


def _distance_to_polyline(p, waypoints, loop):
    a, b = _segments(waypoints, loop)
    ab = b - a
    u = np.clip(np.einsum("nmk,mk->nm", p[:, None] - a, ab) / np.einsum("mk,mk->m", ab, ab), 0.0, 1.0)
    return np.linalg.norm(p[:, None] - (a + u[..., None] * ab), axis=2).min(axis=1)


@pytest.mark.parametrize("name, waypoints, loop, radius", list(_cases()), ids=[c[0] for c in _cases()])
def test_route_is_the_polyline_with_its_corners_cut_by_arcs(name, waypoints, loop, radius):
    route = build_route(waypoints, loop, radius)
    turns = _turns(waypoints, loop)
    a, b = _segments(waypoints, loop)
    seg = np.linalg.norm(b - a, axis=1)
    assert radius * np.tan(np.abs(turns) / 2).max() <= seg.min() / 2  # no corner shrunk: the plain fillet formula holds
    # the length: each corner cuts 2 r tan(φ/2) of polyline and adds an arc r |φ|
    assert route.total_length == pytest.approx(seg.sum() - np.sum(2 * radius * np.tan(np.abs(turns) / 2) - radius * np.abs(turns)),
                                               rel=1e-12)

    total, h = route.total_length, 1e-4
    rng = np.random.default_rng(3)
    s = rng.uniform(h, total - h, 5000)
    x, y, heading, k = route.at(s)
    xp, yp, hp, kp = route.at(s + h)
    xm, ym, hm, km = route.at(s - h)
    # unit speed along the heading (a central difference: chord vs arc costs (k h)²/6 at most)
    np.testing.assert_allclose((xp - xm) / (2 * h), np.cos(heading), atol=1e-7)
    np.testing.assert_allclose((yp - ym) / (2 * h), np.sin(heading), atol=1e-7)
    # the heading turns at the curvature, within a piece; curvature 0 or ±1/radius
    within = (kp == k) & (km == k)
    assert within.mean() > 0.99
    np.testing.assert_allclose(((hp - hm) / (2 * h))[within], k[within], atol=1e-7)
    assert np.all((k == 0.0) | np.isclose(np.abs(k), 1.0 / radius, rtol=1e-12))
    # straights lie on the waypoints' segments, arcs inside the corners they cut
    p = np.column_stack([x, y])
    assert _distance_to_polyline(p[k == 0.0], waypoints, loop).max() < 1e-9
    cut = radius * (1 / np.cos(np.abs(turns).max() / 2) - 1)  # how far the middle of the sharpest arc is from its corner
    assert _distance_to_polyline(p, waypoints, loop).max() <= cut + 1e-9
    # and continuous, as a path is
    x, y, _, _ = route.at(np.linspace(0.0, total, 20001))
    assert np.hypot(np.diff(x), np.diff(y)).max() <= 1.0001 * total / 20000

    if loop:  # one lap later: the same place, the heading turned once around
        assert abs(route.turn_per_lap) == pytest.approx(2 * np.pi, abs=1e-12)
        x2, y2, h2, k2 = route.at(s + 2 * total)
        np.testing.assert_allclose(np.column_stack([x2, y2]), p, atol=1e-9)
        np.testing.assert_allclose(h2 - heading, 2 * route.turn_per_lap, atol=1e-9)
    else:  # from the first waypoint to the last, and held at both ends
        ends = np.column_stack(route.at(np.array([-3.0, 0.0, total, total + 3.0]))[:2])
        np.testing.assert_allclose(ends, waypoints[[0, 0, -1, -1]], atol=1e-12)
