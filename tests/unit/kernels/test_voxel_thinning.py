"""Voxel centroids (fmcwlog.kernels.voxel.voxel_centroids): what they are, and the compiled kernel
against its numpy reference (the same floats: the sums run in the same order).

Where the module is not built the comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it.
"""

from dataclasses import replace

import numpy as np
import pytest
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.keyframe_map import KeyframeMap
from fmcwlog.frontend.params import FrontEndParams
from fmcwlog.frontend.robust_icp import register
from fmcwlog.kernels import voxel as vx


def room_sweep(pose, half_length=6.0, half_width=1.0, beams=1440, sigma=0.0, seed=0, fov_deg=360.0):
    """A sweep of ``fov_deg`` centred on the sensor's x axis (beams counter-clockwise, in beam order;
    a full turn from -π) of a closed rectangular room
    ``2 half_length`` x ``2 half_width`` m centred on the origin, from ``pose`` (x, y, θ): points in
    the sensor frame (m), with Gaussian range noise ``sigma`` (m)."""
    x0, y0, th = pose
    a = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, beams, endpoint=fov_deg < 360.0))
    d = np.stack([np.cos(a + th), np.sin(a + th)], axis=1)
    r = np.full(beams, np.inf)
    for axis, bound in ((1, half_width), (1, -half_width), (0, half_length), (0, -half_length)):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (bound - (x0, y0)[axis]) / d[:, axis]
        r = np.where((t > 0) & (t < r), t, r)
    r = r + np.random.default_rng(seed).normal(0.0, sigma, beams)
    return np.ascontiguousarray(r[:, None] * np.stack([np.cos(a), np.sin(a)], axis=1))


def test_centroids_are_each_voxels_mean_in_first_point_order():
    xy = np.array([[0.01, 0.01], [0.52, 0.0], [0.03, 0.05], [-0.01, 0.02], [0.55, 0.04]])
    out = vx.voxel_centroids_numpy(xy, 0.1)
    np.testing.assert_allclose(out, [[0.02, 0.03], [0.535, 0.02], [-0.01, 0.02]], rtol=0, atol=1e-15)


def test_centroids_do_not_depend_on_the_order_given():
    """The property the first-point thinning lacks: the answer is the same whichever point comes first
    (as a set; the order of the rows follows the first points)."""
    xy = room_sweep((0.3, 0.1, 0.2), sigma=0.02)
    flipped = vx.voxel_centroids_numpy(xy[::-1].copy(), 0.1)
    forward = vx.voxel_centroids_numpy(xy, 0.1)
    assert len(flipped) == len(forward)
    np.testing.assert_allclose(np.unique(np.round(flipped, 9), axis=0), np.unique(np.round(forward, 9), axis=0),
                               rtol=0, atol=1e-9)
    first = vx.voxel_downsample_numpy(xy, 0.1)
    assert len(first) == len(forward)
    assert np.abs(np.sort(vx.voxel_downsample_numpy(xy[::-1].copy(), 0.1), axis=0) - np.sort(first, axis=0)).max() > 0.01


def test_a_centroid_lies_in_its_voxel_and_on_its_wall():
    xy = room_sweep((0.0, 0.0, 0.0), beams=2880)
    out = vx.voxel_centroids_numpy(xy, 0.1)
    assert set(vx.voxel_keys(out, 0.1)) == set(vx.voxel_keys(xy, 0.1))
    on_long_wall = np.abs(np.abs(out[:, 1]) - 1.0) < 1e-9
    assert on_long_wall.sum() > 100  # straight wall runs: their centroids stay on the wall


def test_nothing_to_thin():
    empty = np.empty((0, 2))
    assert vx.voxel_centroids(empty, 0.1) is empty
    xy = np.ones((3, 2))
    assert vx.voxel_centroids(xy, 0.0) is xy


@needs_core
@pytest.mark.parametrize("size", [0.05, 0.1, 0.5])
def test_compiled_centroids_match_numpy_on_room_sweeps(use, size):
    use("compiled")
    for k, pose in enumerate([(0.0, 0.0, 0.0), (1.3, -0.4, 0.7), (-4.0, 0.5, -2.5)]):
        xy = room_sweep(pose, sigma=0.02, seed=k)
        np.testing.assert_array_equal(vx.voxel_centroids(xy, size), vx.voxel_centroids_numpy(xy, size))


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), spread=st.sampled_from([0.05, 1.0, 50.0]),
       size=st.sampled_from([0.01, 0.1, 0.7]))
def test_compiled_centroids_match_numpy_generated(use, seed, n, spread, size):
    use("compiled")
    rng = np.random.default_rng(seed)
    xy = rng.normal(0.0, spread, (n, 2))
    xy[rng.random(n) < 0.2] = xy[0]  # repeated points
    np.testing.assert_array_equal(vx.voxel_centroids(xy, size), vx.voxel_centroids_numpy(xy, size))


def translation_headings(thin, beams=1081, half_width=1.0, keyframes=np.arange(-3.0, 0.01, 0.5),
                         steps=np.linspace(0.02, 0.48, 6), residual=None):
    """The registered heading (deg) of sweeps taken after pure translations along a closed room
    (270° of beams, counter-clockwise, no noise), each thinned by ``thin`` to the front end's
    ``source_voxel`` and registered by the robust ICP, from the true pose, against a keyframe map
    of sweeps taken along the same line (the front end's map and parameters; ``residual``: the
    ICP's, where not the default). The truth is 0."""
    p = FrontEndParams()
    icp = p.icp if residual is None else replace(p.icp, residual=residual)

    def sweep(x):
        return room_sweep((x, 0.0, 0.0), half_width=half_width, beams=beams, fov_deg=270.0)

    m = KeyframeMap(p.voxel_size, p.local_map)
    for x in keyframes:
        m.add(sweep(x) + (x, 0.0), 3.0 + x)
    return np.array([np.degrees(register(thin(sweep(dx), p.source_voxel), m.tree, m.points,
                                         np.array([dx, 0.0, 0.0]), icp).pose[2]) for dx in steps])


@pytest.mark.parametrize("beams,half_width", [(721, 1.0), (1081, 2.0)])
def test_the_front_ends_thinning_registers_a_translation_without_turning(beams, half_width):
    """The source thinned as the map is (the first point in beam order of each voxel: the default
    ``source_thinning``) is registered within 0.03° of the true heading (measured: at most 0.026°)."""
    headings = translation_headings(vx.voxel_downsample, beams=beams, half_width=half_width)
    assert np.abs(headings).max() < 0.03


def test_centroids_against_the_first_point_map_turn_the_heading():
    """With point-to-point residuals, centroids against a map that keeps the first point of each voxel
    are registered turned counter-clockwise (measured: 0.05° on average over these translations, up
    to 0.12°), several times the first-point source's error: why ``source_thinning`` defaults to
    ``first``. Point-to-line residuals (the default) do not see where along a wall a sample sits:
    the centroids' turn is gone (measured: at most 0.008°)."""
    first = translation_headings(vx.voxel_downsample, beams=1081, half_width=2.0, residual="point_to_point")
    centroid = translation_headings(vx.voxel_centroids, beams=1081, half_width=2.0, residual="point_to_point")
    assert centroid.mean() > 0.03 and np.abs(centroid).mean() > 3 * np.abs(first).mean()
    assert np.abs(translation_headings(vx.voxel_centroids, beams=1081, half_width=2.0)).max() < 0.02
