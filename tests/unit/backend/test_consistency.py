"""The revisit distances that decide whether the back end's trajectory replaces the front end's
(:mod:`fmcwlog.backend.consistency`), on a corridor loop of known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.backend.consistency import GAP_M, RevisitDistances, revisit_distances, worse
from fmcwlog.geometry import compose, inverse, transform_points


def _walls(segments, spacing: float = 0.03) -> np.ndarray:
    parts = []
    for x1, y1, x2, y2 in segments:
        n = max(int(np.hypot(x2 - x1, y2 - y1) / spacing), 2)
        s = np.linspace(0.0, 1.0, n)[:, None]
        parts.append(np.array([x1, y1]) + s * np.array([x2 - x1, y2 - y1]))
    return np.concatenate(parts)


# a corridor 2 m wide around a 16 m x 8 m block, with door recesses and a pillar so that no stretch repeats
SCENE = _walls([(0, 0, 20, 0), (20, 0, 20, 12), (20, 12, 0, 12), (0, 12, 0, 0),
                (2, 2, 18, 2), (18, 2, 18, 10), (18, 10, 2, 10), (2, 10, 2, 2),
                (6, 0, 6, -0.4), (6, -0.4, 7, -0.4), (7, -0.4, 7, 0), (20, 5, 20.4, 5), (20.4, 5, 20.4, 6),
                (13, 12, 13, 12.5), (13, 12.5, 14.5, 12.5), (14.5, 12.5, 14.5, 12), (0.8, 6, 1.2, 6), (1.2, 6, 1.2, 6.4)])


def _loop(laps: float = 1.3, step: float = 0.5) -> np.ndarray:
    """Poses every ``step`` m around the corridor's middle line (a 56 m lap), counter-clockwise."""
    corners = np.array([[1, 1], [19, 1], [19, 11], [1, 11]], float)
    out, travelled, total = [], 0.0, laps * 56.0
    while travelled < total:
        s = travelled % 56.0
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            side = float(np.hypot(*(b - a)))
            if s <= side:
                d = (b - a) / side
                out.append([*(a + s * d), np.arctan2(d[1], d[0])])
                break
            s -= side
        travelled += step
    return np.array(out)


def _points(poses: np.ndarray, rng: np.random.Generator, reach: float = 8.0) -> list[np.ndarray]:
    """What each node sees: the scene within ``reach`` m, in its frame, 1 cm noise, as float32."""
    out = []
    for p in poses:
        near = SCENE[np.hypot(*(SCENE - p[:2]).T) < reach]
        out.append((transform_points(inverse(p), near) + rng.normal(0, 0.01, near.shape)).astype(np.float32))
    return out


def _drifted(truth: np.ndarray, yaw_per_m: float) -> np.ndarray:
    """The same relative motions with a heading that drifts ``yaw_per_m`` rad per metre."""
    out = [truth[0]]
    for a, b in zip(truth[:-1], truth[1:]):
        rel = compose(inverse(a), b)
        rel[2] += yaw_per_m * np.hypot(rel[0], rel[1])
        out.append(compose(out[-1], rel))
    return np.array(out)


@pytest.fixture(scope="module")
def loop():
    truth = _loop()
    path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))])
    return truth, path, _points(truth, np.random.default_rng(0))


def test_a_drifted_loop_closed_right_draws_its_revisits_closer(loop):
    truth, path, points = loop
    front = _drifted(truth, np.radians(0.1))  # 0.1°/m: the second lap's walls some 20 cm off the first's
    r = revisit_distances(points, path, front, truth)
    assert r is not None and r.queries > 10
    assert r.optimised < 0.5 * r.frontend, r  # measured 4.2 against 22.4 cm
    assert not worse(r)


def test_a_wrong_bend_draws_the_revisits_apart_and_is_judged_worse(loop):
    """The front end right, the optimised trajectory bent by a wrong closure: from the 60th node on,
    every node 0.3 m along and turned 1° about the place it was bent."""
    truth, path, points = loop
    bent = truth.copy()
    bend = np.array([0.3, 0.0, np.radians(1.0)])
    bent[60:] = [compose(compose(truth[60], bend), compose(inverse(truth[60]), p)) for p in truth[60:]]
    r = revisit_distances(points, path, truth, bent)
    assert r is not None
    assert r.optimised > 2 * r.frontend, r  # measured 14.1 against 3.1 cm
    assert worse(r)


def test_no_revisit_no_verdict():
    """A path shorter than the gap has no earlier map to compare with: no verdict, whatever the trajectories."""
    truth = _loop(laps=GAP_M / 56.0 * 0.9)
    path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))])
    points = _points(truth, np.random.default_rng(1))
    assert revisit_distances(points, path, truth, _drifted(truth, 0.01)) is None


def test_a_difference_within_the_margins_keeps_the_back_end():
    assert not worse(RevisitDistances(0.050, 0.052, 1000, 50))  # 4 %: within 5 %
    assert not worse(RevisitDistances(0.010, 0.0115, 1000, 50))  # 15 %, but 1.5 mm
    assert worse(RevisitDistances(0.050, 0.056, 1000, 50))
