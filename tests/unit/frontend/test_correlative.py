"""The correlative search's branch and bound against an exhaustive search of the same lattice.

The search (:mod:`fmcwlog.kernels.correlative`) prunes by bounds, caches children and scores
candidates in batches; none of that may change what it finds. The reference here scores every
pose of the lattice (every yaw sample, every fine offset in the window) straight from the fine
likelihood grid, by 2-D indexing of each rotated point's cell, and takes the best, and the best
separate from it."""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.geometry import inverse, transform_points, wrap_angle
from fmcwlog.kernels.correlative import CorrelativeParams, _rotations, correlative_match, grid_for, subsample


def _scene(rng: np.random.Generator) -> np.ndarray:
    """Walls of a room with a few boxes in it, points every 2 cm."""
    segs = [(-4, -3, 4, -3), (4, -3, 4, 3), (4, 3, -4, 3), (-4, 3, -4, -3), (1, 0, 1.4, 0), (1.4, 0, 1.4, 0.6),
            (-2, -1, -2, 0.5), (-2, 0.5, -1.2, 0.5), (2.5, 2, 3, 1.5)]
    out = []
    for x0, y0, x1, y1 in segs:
        n = max(int(np.hypot(x1 - x0, y1 - y0) / 0.02), 2)
        t = np.linspace(0, 1, n)[:, None]
        out.append(np.array([x0, y0]) * (1 - t) + np.array([x1, y1]) * t)
    return np.concatenate(out) + rng.normal(0, 0.005, (sum(len(o) for o in out), 2))


def _exhaustive(grid, source: np.ndarray, prior: np.ndarray, p: CorrelativeParams):
    """Every lattice pose's mean likelihood (R, 2n+1, 2n+1) and the poses (R, 2n+1, 2n+1, 3)."""
    src = subsample(source, p.max_points)
    thetas = _rotations(float(prior[2]), src, p)
    n = int(np.ceil(p.linear_window / p.resolution))
    steps = np.arange(-n, n + 1)
    scores = np.zeros((len(thetas), len(steps), len(steps)))
    poses = np.zeros((*scores.shape, 3))
    h, w = grid.fine.shape
    for r, th in enumerate(thetas):
        placed = transform_points(np.array([prior[0], prior[1], th]), src)
        for a, j in enumerate(steps):
            for b, i in enumerate(steps):
                ij = grid.cell(placed + np.array([i, j]) * p.resolution)
                inside = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
                values = np.zeros(len(src))
                values[inside] = grid.fine[ij[inside, 1], ij[inside, 0]]
                scores[r, a, b] = values.mean()
                poses[r, a, b] = prior[0] + i * p.resolution, prior[1] + j * p.resolution, wrap_angle(th)
    return scores, poses


@pytest.mark.parametrize("levels, window, seed", [(1, 0.3, 0), (2, 0.5, 1), (2, 0.45, 2), (3, 0.6, 3)])
def test_branch_and_bound_finds_the_exhaustive_best_and_second_peak(levels, window, seed):
    rng = np.random.default_rng(seed)
    scene = _scene(rng)
    truth = np.array([0.2, -0.15, np.radians(3.0)])
    source = transform_points(inverse(truth), scene[rng.permutation(len(scene))[:250]])
    p = CorrelativeParams(linear_window=window, angular_window_deg=6.0, levels=levels, max_rotations=31)
    grid = grid_for(scene, p)
    prior = np.array([0.05, 0.05, 0.0])
    found = correlative_match(grid, source, prior, p)
    scores, poses = _exhaustive(grid, source, prior, p)
    assert found.score == pytest.approx(scores.max(), abs=1e-6)
    at = np.unravel_index(np.argmax(scores), scores.shape)
    assert np.allclose(found.pose, poses[at], atol=1e-9) or scores.max() - np.sort(scores, axis=None)[-2] < 1e-6
    # the second peak: the best lattice pose on another peak than the best one
    dyaw = np.abs(wrap_angle(poses[..., 2] - found.pose[2]))
    far = (np.hypot(poses[..., 0] - found.pose[0], poses[..., 1] - found.pose[1]) > p.peak_separation) | (
        dyaw > np.radians(p.peak_separation_deg))
    assert found.second_score == pytest.approx(scores[far].max(initial=0.0), abs=1e-6)
    assert found.second_pose is not None
    assert found.second_score < found.score


@pytest.mark.parametrize("margin, reach", [(0.3, 12), (0.0, 3), (1.0, 0)])
def test_likelihood_grid_is_the_gaussian_of_the_distance_to_the_nearest_target_cell(margin, reach):
    """Every cell against a KD-tree's distance from its index to the nearest occupied cell's
    index (an independent nearest-neighbour search), in a frame of zeros ``2·reach + 1`` wide."""
    from scipy.spatial import cKDTree

    from fmcwlog.kernels.correlative import LikelihoodGrid

    rng = np.random.default_rng(7)
    targets = np.concatenate([_scene(rng)[::7], rng.uniform(-3, 3, (40, 2))])
    res, sigma = 0.05, 0.075
    grid = LikelihoodGrid(targets, res, sigma, margin, reach)
    h, w = grid.fine.shape
    occupied = grid.cell(targets)
    rows, cols = np.mgrid[0:h, 0:w]
    d, _ = cKDTree(occupied[:, ::-1].astype(float)).query(np.stack([rows.ravel(), cols.ravel()], 1).astype(float))
    expected = np.exp(-0.5 * (d.reshape(h, w) * res / sigma) ** 2).astype(np.float32)
    f = 2 * reach + 1
    expected[:f], expected[-f:], expected[:, :f], expected[:, -f:] = 0, 0, 0, 0
    np.testing.assert_allclose(grid.fine, expected, rtol=1e-6, atol=1e-7)
