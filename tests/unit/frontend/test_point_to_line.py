"""Point-to-line residuals in the robust ICP, and the map's line normals they use.

Against known geometry: the normals of points on a line are the line's normal, a blob has none; a
scan of two perpendicular walls, sampled elsewhere along them than the map was, recovers a known
shift; in a corridor whose walls the map sampled on a 5 cm lattice and the scan 2 cm off it,
point-to-line leaves no bias along the walls, point-to-point (the ablation) is pulled toward the
map's samples. The normals' compiled kernel against its numpy reference: bit for bit equal.
"""

from dataclasses import replace

import numpy as np
import pytest
from helpers import needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from fmcwlog.frontend.icp import ICPParams
from fmcwlog.frontend.keyframe_map import KeyframeMap
from fmcwlog.frontend.params import FrontEndParams
from fmcwlog.frontend.robust_icp import register, register_numpy
from fmcwlog.geometry import inverse, transform_points
from fmcwlog.kernels import compiled
from fmcwlog.kernels.normals import line_normals, line_normals_numpy, target_normals

ICP = FrontEndParams().icp  # what the improved method runs
P2P = replace(ICP, residual="point_to_point")


def _segment(a, b, spacing, offset=0.0):
    """Points from ``a`` to ``b`` (m) every ``spacing`` m, the first ``offset`` m from ``a``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = float(np.hypot(*(b - a)))
    t = np.arange(offset, length, spacing) / length
    return a + t[:, None] * (b - a)


def test_defaults():
    assert ICP.point_to_line and ICP.line_neighbours == 7 and ICP.line_eigen_ratio == 9.0
    assert not P2P.point_to_line


@pytest.mark.parametrize("kernels", ["numpy", "compiled"])
def test_normals_of_a_line_and_of_a_blob(use, kernels):
    """Points on a line 30° from x with 3 mm noise: every normal is the line's (±), every point a
    line point; points on a square 5 cm lattice have none."""
    if use(kernels) is None and kernels == "compiled":
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(1)
    angle = np.radians(30.0)
    along = np.array([np.cos(angle), np.sin(angle)])
    line = np.arange(0.0, 5.0, 0.05)[:, None] * along + rng.normal(0, 0.003, (100, 2))
    normals, on_line = line_normals(line, 7, 1 / 9)
    assert on_line.all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert np.abs(normals @ along).max() < np.sin(np.radians(5.0))
    g = np.arange(10) * 0.05
    blob = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    assert not line_normals(blob, 7, 1 / 9)[1].any()
    # fewer than 3 points make no line, however they lie
    assert not line_normals(line[:2], 7, 1 / 9)[1].any()


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 1500), k=st.integers(1, 12),
       ratio=st.sampled_from([1.0, 4.0, 9.0, 100.0]), lattice=st.booleans())
def test_compiled_normals_equal_numpy(use, seed, n, k, ratio, lattice):
    """The same neighbours (ties by index: the lattice has many), the same sums, the same eigenvectors:
    normals and flags equal bit for bit."""
    rng = np.random.default_rng(seed)
    if lattice:  # points on a 5 cm lattice, some missing: equal distances everywhere
        g = np.arange(40) * 0.05
        pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
        pts = pts[np.sort(rng.choice(len(pts), min(n, len(pts)), replace=False))]
    else:
        t = rng.random(n)
        ends = rng.uniform(-5, 5, (4, 4))
        seg = rng.integers(0, 4, n)
        pts = ends[seg, :2] + t[:, None] * (ends[seg, 2:] - ends[seg, :2]) + rng.normal(0, 0.01, (n, 2))
    module = use("compiled")
    fast_n, fast_f = np.empty((len(pts), 2)), np.empty(len(pts), bool)
    module.submap_normals(np.ascontiguousarray(pts), k, 1 / ratio, fast_n, fast_f)
    ref_n, ref_f = line_normals_numpy(pts, k, 1 / ratio, cKDTree(pts) if seed % 2 else None)
    np.testing.assert_array_equal(fast_f, ref_f)
    np.testing.assert_array_equal(fast_n, ref_n)
    # the robust ICP's lazy normals: the same numbers, each point's at its first use
    lazy = module.LineNormals(np.ascontiguousarray(pts), k, 1 / ratio)
    assert lazy.computed() == 0
    lazy_n, lazy_f = np.empty((len(pts), 2)), np.empty(len(pts), bool)
    lazy.fill(lazy_n, lazy_f)
    assert lazy.computed() == len(pts)
    np.testing.assert_array_equal(lazy_f, ref_f)
    np.testing.assert_array_equal(lazy_n, ref_n)


@needs_core
def test_compiled_icp_computes_only_the_normals_it_pairs_with(use):
    """A scan of part of a keyframe map: the kernel computes the normals of the map points it paired
    with, once per map state, and no others; numpy (all normals) gives the same registration."""
    use("compiled")
    m = KeyframeMap()
    target, scan = _corridor()
    m.add(target, 0.0)
    part = scan[scan[:, 0] > 2.0]
    a = register(part, m.tree, m.points, np.zeros(3), ICP)
    lines = m.tree.cache[("compiled_lines", 7, 1 / 9)]
    done = lines.computed()
    assert 0 < done < len(m.points) / 2
    b = register(part, m.tree, m.points, np.zeros(3), ICP)
    assert lines.computed() == done and b.iterations == a.iterations
    np.testing.assert_array_equal(a.pose, b.pose)
    ref = register_numpy(part, cKDTree(m.points), m.points, np.zeros(3), ICP)
    assert ref.iterations == a.iterations
    np.testing.assert_allclose(ref.pose, a.pose, rtol=0, atol=1e-9)


def test_normals_kept_per_map_state(use):
    """A keyframe map's index computes them once per state; a plain tree gets them fresh."""
    use("numpy")
    m = KeyframeMap()
    m.add(_segment((0, 0), (4, 0), 0.05), 0.0)
    first = target_normals(m.tree, m.points, 7, 1 / 9)
    assert target_normals(m.tree, m.points, 7, 1 / 9) is first
    m.add(_segment((0, 1), (4, 1), 0.05), 1.0)
    assert target_normals(m.tree, m.points, 7, 1 / 9) is not first
    again = target_normals(cKDTree(m.points), m.points, 7, 1 / 9)
    np.testing.assert_array_equal(again[0], target_normals(m.tree, m.points, 7, 1 / 9)[0])


def _room(offset):
    """Two perpendicular walls 4 m long meeting at the origin, a point every 5 cm from ``offset`` m
    along each (the map: 0; a scan: another sampling of the same walls)."""
    return np.concatenate([_segment((0, 0), (4, 0), 0.05, offset), _segment((0, 0), (0, 4), 0.05, offset)])


SHIFTS = [(0.05, -0.03, 0.02), (-0.1, 0.08, -0.03), (0.0, 0.0, 0.0)]


@pytest.mark.parametrize("kernels", ["numpy", "compiled"])
@pytest.mark.parametrize("shift", SHIFTS)
def test_two_walls_away_from_their_corner_give_the_shift_exactly(use, kernels, shift):
    """The map samples two perpendicular walls at 0, 5, 10 ... cm, the scan at 2.5, 7.5 ... cm (from
    30 cm beyond the corner on), seen from a pose ``shift`` (m, m, rad) off the map's origin: every
    pair is a line pair, and point-to-line finds the pose to rounding; no sample of the scan is a
    sample of the map."""
    if use(kernels) is None and kernels == "compiled":
        pytest.skip("compiled kernels not built")
    target, seen = _room(0.0), _room(0.025)
    scan = transform_points(inverse(np.array(shift)), seen[np.hypot(*seen.T) > 0.3])
    res = register(scan, compiled.MapIndex(target), target, np.zeros(3), ICP)
    assert res.converged
    np.testing.assert_allclose(res.pose, shift, atol=1e-9)


@pytest.mark.parametrize("kernels", ["numpy", "compiled"])
@pytest.mark.parametrize("shift", SHIFTS)
@pytest.mark.parametrize("seed", [0, 1])
def test_two_walls_recover_a_known_shift(use, kernels, shift, seed):
    """The same walls, the corner included and 3 mm noise on the scan: point-to-line is within 4 mm and
    1.2 mrad of the shift (measured: 2.2 mm and 0.8 mrad at most; the corner's points have no line,
    and their point-to-point pairs pull toward the map's samples). Point-to-point (the ablation)
    settles on the map's lattice, more than 1 cm off (measured 1.7-8.6 cm)."""
    if use(kernels) is None and kernels == "compiled":
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(seed)
    seen = _room(0.025)
    scan = transform_points(inverse(np.array(shift)), seen + rng.normal(0, 0.003, seen.shape))
    target = _room(0.0)
    res = register(scan, compiled.MapIndex(target), target, np.zeros(3), ICP)
    assert res.converged
    assert np.hypot(*(res.pose[:2] - shift[:2])) < 4e-3 and abs(res.pose[2] - shift[2]) < 1.2e-3
    ref = register(scan, compiled.MapIndex(target), target, np.zeros(3), P2P)
    assert np.hypot(*(ref.pose[:2] - shift[:2])) > 0.01


def _corridor():
    """A corridor 2 m wide and 10 m long, closed at x = 5 m: the map samples its walls every 5 cm from
    x = -5 m (and the end wall from y = -1 m), the scan, from the map's origin, 2 cm further on."""
    def walls(o):
        return np.concatenate([_segment((-5, -1), (5, -1), 0.05, o), _segment((-5, 1), (5, 1), 0.05, o),
                               _segment((5, -1), (5, 1), 0.05, o)])
    return walls(0.0), walls(0.02)


@pytest.mark.parametrize("kernels", ["numpy", "compiled"])
@pytest.mark.parametrize("seed", [0, 1])
def test_lattice_corridor_no_bias_along_walls(use, kernels, seed):
    """The truth is the map's origin; 3 mm noise on the scan. Point-to-line: the long walls hold y and
    yaw, the end wall x: within 4 mm along the corridor (measured 1.2-1.8 mm: the end wall's corners
    pull point-to-point). Point-to-point (the ablation): each scan point is drawn to the map sample
    2 cm behind it, and the 400 along-wall pairs outvote the 40 of the end wall: the pose slides
    more than 1.5 cm along the corridor (measured 2.0 cm). Across the corridor both hold (2 mm)."""
    if use(kernels) is None and kernels == "compiled":
        pytest.skip("compiled kernels not built")
    target, scan = _corridor()
    scan = scan + np.random.default_rng(seed).normal(0, 0.003, scan.shape)
    start = np.array([0.004, 0.003, 0.001])
    lines = register(scan, compiled.MapIndex(target), target, start, ICP)
    points = register(scan, compiled.MapIndex(target), target, start, P2P)
    assert abs(lines.pose[0]) < 4e-3 and abs(lines.pose[2]) < 5e-4
    assert points.pose[0] < -0.015
    assert abs(lines.pose[1]) < 2e-3 and abs(points.pose[1]) < 2e-3


def test_the_baseline_stays_point_to_point():
    """The baseline's ICP reads no residual choice: the same pose whichever is set."""
    from fmcwlog.frontend.point_to_point_icp import register_point_to_point

    target, scan = _corridor()
    scan = scan + np.random.default_rng(0).normal(0, 0.003, scan.shape)
    tree = cKDTree(target)
    a = register_point_to_point(scan, tree, target, np.zeros(3), ICP)
    b = register_point_to_point(scan, tree, target, np.zeros(3), P2P)
    np.testing.assert_array_equal(a.pose, b.pose)
    assert a.pose[0] < -0.01  # and it keeps the bias point-to-point has


def test_hessian_along_a_corridor_is_the_prior_alone():
    """Two long parallel walls and no end: point-to-line residuals carry no information along them,
    so the step's information there is the prior's (point-to-point claims some from the samples)."""
    target, scan = _corridor()
    keep = target[:, 0] < 4.9
    target, scan = target[keep], scan[scan[:, 0] < 4.9]
    prior = np.diag([1.0, 1.0, 1.0])
    res = register_numpy(scan, cKDTree(target), target, np.zeros(3), ICP, prior_pose=np.zeros(3),
                         prior_information=prior)
    np.testing.assert_allclose(res.hessian[0, 0], 1.0, rtol=1e-9)
    ref = register_numpy(scan, cKDTree(target), target, np.zeros(3), P2P, prior_pose=np.zeros(3),
                         prior_information=prior)
    assert ref.hessian[0, 0] > 100.0


def test_parameters_are_checked():
    with pytest.raises(Exception, match="residual"):
        ICPParams(residual="point_to_plane")
    with pytest.raises(Exception, match="line_neighbours"):
        ICPParams(line_neighbours=2)
