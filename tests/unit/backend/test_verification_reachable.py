"""The correlative search of a closure on a grid over the submap's reachable points alone scores
every pose as on the whole submap's."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fmcwlog.backend.params import BackendParams
from fmcwlog.backend.verification import reachable
from fmcwlog.geometry import inverse, transform_points
from fmcwlog.kernels.correlative import correlative_match, grid_for


def _walls(rng: np.random.Generator, length: float) -> np.ndarray:
    """A corridor 2 m wide along x over ``length`` m, with a few posts, sampled every 5 cm."""
    x = np.arange(0.0, length, 0.05)
    walls = [np.c_[x, np.full_like(x, -1.0)], np.c_[x, np.full_like(x, 1.0)]]
    posts = rng.uniform([0.0, -0.9], [length, 0.9], (6, 2))
    walls += [p + 0.05 * np.c_[np.cos(a), np.sin(a)] for p in posts for a in [np.linspace(0, 2 * np.pi, 8)]]
    return np.concatenate(walls) + rng.normal(0.0, 0.005, (sum(len(w) for w in walls), 2))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("window", [(1.5, 15.0), (0.5, 5.0)])
def test_a_grid_over_the_reachable_points_finds_what_the_whole_submap_finds(seed, window):
    rng = np.random.default_rng(seed)
    submap = _walls(rng, 40.0) - [20.0, 0.0]
    truth = np.array([rng.uniform(-3, 3), rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.1)])
    near = np.hypot(*(submap - truth[:2]).T) < 6.0  # the query sees 6 m around it
    query = transform_points(inverse(truth), submap[near])  # in the query's own frame
    prior = truth + [0.2, -0.1, 0.02]
    search = dataclasses.replace(BackendParams().search, linear_window=window[0], angular_window_deg=window[1])
    kept = reachable(submap, query, prior, search)
    assert len(kept) < len(submap)
    whole = correlative_match(grid_for(submap, search), query, prior, search)
    cropped = correlative_match(grid_for(kept, search), query, prior, search)
    np.testing.assert_array_equal(cropped.pose, whole.pose)
    assert (cropped.score, cropped.second_score) == (whole.score, whole.second_score)
    assert (cropped.second_pose is None) == (whole.second_pose is None)
