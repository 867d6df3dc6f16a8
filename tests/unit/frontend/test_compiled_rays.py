"""Free space from the last sweeps' rays (:class:`RecentRays`): the compiled kernel against its numpy
reference, the bearing bins against the true angle, and the lidar's path within a sweep against the
de-skew's own arc.

Given the same inputs the two kernels give the same mask and the same ring to the bit: on generated
sweeps (points on bin edges, on the axes, at the lidar itself), and on every sweep the improved method
tracks on the recorded crowd log. Where the module is not built the comparisons skip, unless
``FMCWLOG_KERNELS=compiled`` asks for it (CI does).
"""

import math
import os
import tempfile

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import tracking
from fmcwlog.frontend.deskew import deskew_placed_numpy
from fmcwlog.frontend.tracking import RecentRays, bearing_bins, lidar_origins
from fmcwlog.kernels import compiled


def _select(kind):
    os.environ[compiled.ENV] = kind
    compiled._chosen = None


@pytest.fixture
def use():
    """Select kernels by name in a test (returns the compiled module or None); the environment is
    restored after it."""
    kind = os.environ.get(compiled.ENV)

    def select(name):
        _select(name)
        return compiled.core()

    yield select
    if kind is None:
        os.environ.pop(compiled.ENV, None)
    else:
        os.environ[compiled.ENV] = kind
    compiled._chosen = None


def _assert_same_ring(a: RecentRays, b: RecentRays):
    for got, want in zip(a.state(), b.state()):
        np.testing.assert_array_equal(got, want)


def _run_both(sweeps, step, margin, tolerance, window, kept):
    """Each sweep (map_xy, t, ends, yaw_error) through a compiled and a numpy ring: both masks equal
    and both rings equal after every sweep; the masks."""
    fast, ref = RecentRays(kept, window), RecentRays(kept, window)
    masks = []
    for map_xy, t, ends, yaw_error in sweeps:
        got = fast.sweep(map_xy, t, ends, step, margin, yaw_error, tolerance)
        want = ref.sweep_numpy(map_xy, t, ends, step, margin, yaw_error, tolerance)
        assert got.dtype == want.dtype == np.bool_
        np.testing.assert_array_equal(got, want)
        _assert_same_ring(fast, ref)
        masks.append(want)
    return masks


def test_bins_are_the_true_angles_within_a_bin():
    # the polynomial arctangent is within 1.3e-5 rad of the true angle (in float32): the bin is arctan2's, or its
    # neighbour where the true angle lies within 1.3e-5 rad of the edge between them
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200_000, 2)) * 10.0 ** rng.integers(-3, 3, size=(200_000, 1))
    bins = 1440
    got = bearing_bins(d[:, 0], d[:, 1], bins)
    angle = np.arctan2(d[:, 1], d[:, 0])
    true = np.floor((angle + math.pi) * (bins / (2 * math.pi))).astype(np.int64) % bins
    off = (got - true + bins // 2) % bins - bins // 2
    assert set(np.unique(off)) <= {-1, 0, 1}
    edge = -math.pi + np.round((angle + math.pi) / (2 * math.pi / bins)) * (2 * math.pi / bins)
    assert np.all(np.abs(angle[off != 0] - edge[off != 0]) < 1.3e-5)
    assert (off == 0).mean() > 0.99


def test_lidar_path_within_a_sweep_is_its_chord_within_millimetres():
    # the lidar's position at each point's time from the de-skew itself (a point at the lidar's
    # origin placed by it) against the chord between the sweep's ends: off by at most v T² ω / 8
    mount, pose = np.array([0.3, 0.1, 0.2]), np.array([4.0, -2.0, 0.7])
    t = np.linspace(0.0, 0.1, 1000)
    for v, omega in [(2.0, 2.0), (1.0, -0.5), (0.0, 1.5), (2.0, 0.0)]:
        arc = deskew_placed_numpy(np.zeros((len(t), 2)), t, v, omega, mount, pose)
        chord = lidar_origins(t, arc[[0, -1]])
        off = np.hypot(*(chord - arc).T).max()
        # the lidar turns about the base with the mount's lever arm too: sagitta of each part
        bound = (v * 0.1**2 * abs(omega) + math.hypot(0.3, 0.1) * (omega * 0.1) ** 2) / 8
        assert off <= bound + 1e-9, (v, omega, off)
    assert off < 1e-12  # straight: exact to rounding


def _scene(rng, n, k, jitter=0.0):
    """Sweep ``k`` of a lidar moving along x at 1 m/s in a room of radius 6-9 m, a blob crossing."""
    t = np.sort(rng.random(n)) * 0.1
    start = np.array([0.1 * k, 0.02 * k])
    ends = np.array([start, start + [0.1, 0.002]])
    origins = lidar_origins(t, ends)
    ang = -math.pi + 2 * math.pi * np.arange(n) / max(n, 1) + jitter * rng.normal(size=n)
    r = 6.0 + 3.0 * rng.random(n)
    blob = np.abs(ang - (0.3 * k - 2.0)) < 0.2  # something much nearer crossing the beams
    r[blob] = 2.0
    return origins + r[:, None] * np.column_stack([np.cos(ang), np.sin(ang)]), t, ends


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1500), kept=st.integers(1, 12), step=st.integers(1, 4),
       window=st.integers(0, 3), margin=st.floats(0.0, 2.0), tolerance=st.floats(0.0, 0.5),
       yaw=st.floats(0.0, 0.05), sweeps=st.integers(1, 16), level=st.sampled_from([2, 1, 0]))
def test_generated_sweeps_agree(use, seed, n, kept, step, window, margin, tolerance, yaw, sweeps, level):
    core = use("compiled")
    rng = np.random.default_rng(seed)
    data = []
    for k in range(sweeps):
        map_xy, t, ends = _scene(rng, n, k, jitter=0.01)
        data.append((map_xy, t, ends if n else None, float(yaw * rng.random())))
    was = core._rays_simd(level)  # the widest loop: AVX-512, AVX2 (each where the CPU has it), scalar
    try:
        _run_both(data, step, margin, tolerance, window, kept)
    finally:
        core._rays_simd(was)


@needs_core
def test_edges_axes_and_the_lidar_itself_agree(use):
    # directions exactly on the bin edges (as cos/sin of them round), on the axes with signed zeros,
    # points at the lidar's position itself: the compiled bins are numpy's, the masks and rings equal
    use("compiled")
    bins = RecentRays(1, 0).bins
    edge = -math.pi + np.arange(bins) * (2 * math.pi / bins)
    unit = np.column_stack([np.cos(edge), np.sin(edge)])
    axes = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [1.0, -0.0], [-1.0, -0.0], [-0.0, 1.0],
                     [-0.0, -1.0], [0.0, 0.0], [-0.0, -0.0], [1.0, 1.0], [-1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])
    data = []
    for scale in [3.0, 2.0, 7.5, 3.0, 1e-3, 2.5]:
        xy = np.concatenate([unit * scale, axes * scale, unit * (scale * 0.5)])
        t = np.zeros(len(xy))  # one time: every point's origin is the first end
        ends = np.array([[0.0, 0.0], [0.0, 0.0]])
        data.append((xy, t, ends, 0.0))
    masks = _run_both(data, 1, 0.5, 0.15, 1, 4)
    assert masks[3].any() and masks[4].any()  # nearer than the sweep before saw: where its rays went through


@needs_core
def test_not_finite_falls_back_to_numpy(use):
    use("compiled")
    rng = np.random.default_rng(5)
    data = [(*_scene(rng, 300, k)[:3], 0.01) for k in range(4)]
    bad_xy = data[3][0].copy()
    bad_xy[7, 1] = np.nan
    fast, ref = RecentRays(4, 1), RecentRays(4, 1)
    for map_xy, t, ends, yaw_error in data[:3]:
        fast.sweep(map_xy, t, ends, 1, 0.5, yaw_error, 0.15)
        ref.sweep_numpy(map_xy, t, ends, 1, 0.5, yaw_error, 0.15)
    with np.errstate(invalid="ignore"):
        got = fast.sweep(bad_xy, data[3][1], data[3][2], 1, 0.5, 0.01, 0.15)
        want = ref.sweep_numpy(bad_xy, data[3][1], data[3][2], 1, 0.5, 0.01, 0.15)
    np.testing.assert_array_equal(got, want)
    _assert_same_ring(fast, ref)


@pytest.fixture(scope="module")
def recorded_sweeps():
    """What the improved method's tracker hands the recent rays on every sweep of the 30 s crowd log."""
    from fmcwlog.api import ProcessOptions, process

    seen = []
    original = tracking.RecentRays.sweep

    def sweep(self, map_xy, t, ends, *args):
        seen.append((map_xy.copy(), t.copy(), None if ends is None else ends.copy(), *args))
        return original(self, map_xy, t, ends, *args)

    tracking.RecentRays.sweep = sweep
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/out",
                    ProcessOptions(methods=("improved",), backend="none"), jobs=1)
    finally:
        tracking.RecentRays.sweep = original
    return seen


@needs_core
@pytest.mark.parametrize("level", [2, 1, 0])  # AVX-512, AVX2 (each where the CPU has it), scalar
def test_recorded_sweeps_agree(use, recorded_sweeps, level):
    core = use("compiled")
    was = core._rays_simd(level)
    try:
        _recorded_agree(recorded_sweeps)
    finally:
        core._rays_simd(was)


def _recorded_agree(recorded_sweeps):
    params = tracking.TrackingParams()
    assert len(recorded_sweeps) == 300
    fast = RecentRays(params.displacement_sweeps, params.displacement_window)
    ref = RecentRays(params.displacement_sweeps, params.displacement_window)
    total = 0
    for map_xy, t, ends, step, margin, yaw_error, tolerance in recorded_sweeps:
        got = fast.sweep(map_xy, t, ends, step, margin, yaw_error, tolerance)
        want = ref.sweep_numpy(map_xy, t, ends, step, margin, yaw_error, tolerance)
        np.testing.assert_array_equal(got, want)
        total += int(want.sum())
    _assert_same_ring(fast, ref)
    assert total > 1000  # the crowd's walkers stand where earlier rays saw through
