"""De-skewing by the wheels' motion within the sweep (``frontend.deskew_motion = "wheels"``).

Physics: a sweep of a room's walls captured from a robot whose yaw rate steps inside the sweep (the
end of an aisle), with the track of its poses at 50 Hz: the wheels' profile puts the points where
the walls are, to well within a millimetre, and one constant twist misplaces them by decimetres.
Kernels: the compiled ``deskew_source_wheels`` against the numpy reference, on generated inputs and
on every sweep the improved front end de-skews processing the 30 s crowd log.
"""

import tempfile

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import deskew_wheels as dw
from fmcwlog.frontend.deskew import deskewed_source_numpy
from fmcwlog.frontend.motion_prior import PoseTrack
from fmcwlog.geometry import compose, inverse, transform_points
from fmcwlog.kernels import voxel as vx

MOUNT = np.array([0.3, -0.05, 0.1])
ROOM = (-6.0, 8.0, -5.0, 7.0)  # x_min, x_max, y_min, y_max of the walls (m, world)


def _arc(pose, v, omega, dt):
    """The pose after ``dt`` on the circle (or line) of ``(v, omega)`` from ``pose``: the circle's
    centre and radius, not an exponential."""
    x, y, th = pose
    if omega == 0.0:
        return np.array([x + v * dt * np.cos(th), y + v * dt * np.sin(th), th])
    r = v / omega
    cx, cy = x - r * np.sin(th), y + r * np.cos(th)
    th1 = th + omega * dt
    return np.array([cx + r * np.sin(th1), cy - r * np.cos(th1), th1])


def _stepped_track(t, start, v, w0, w1, t_step):
    """Base poses (N, 3) at times ``t``: yaw rate ``w0`` until ``t_step``, ``w1`` after, speed ``v``."""
    at_step = _arc(start, v, w0, t_step)
    return np.array([_arc(start, v, w0, ti) if ti < t_step else _arc(at_step, v, w1, ti - t_step) for ti in t])


def _raycast_room(lidar, bearing):
    """The wall points (world) and as seen (lidar frame) of beams at ``bearing`` from the lidar poses."""
    ang = lidar[:, 2] + bearing
    c, s = np.cos(ang), np.sin(ang)
    x0, x1, y0, y1 = ROOM
    with np.errstate(divide="ignore", invalid="ignore"):
        cands = np.stack([(x0 - lidar[:, 0]) / c, (x1 - lidar[:, 0]) / c, (y0 - lidar[:, 1]) / s,
                          (y1 - lidar[:, 1]) / s], -1)
    rng = np.where(cands > 0, cands, np.inf).min(axis=1)
    world = np.stack([lidar[:, 0] + rng * c, lidar[:, 1] + rng * s], -1)
    return world, np.stack([rng * np.cos(bearing), rng * np.sin(bearing)], -1)


def _sweep_with_a_step(v=2.5, w0=0.0, w1=2.5, t_step=0.04, n=1080, duration=0.075):
    """A sweep (xy, t) of the room with the yaw rate stepping at ``t_step`` (a tick's stamp), the
    walls' points in base_link at the stamp (the truth), and a pose track at 50 Hz around it."""
    start = np.array([0.5, -1.0, 0.3])
    t = np.linspace(0.0, duration, n)
    base = _stepped_track(t, start, v, w0, w1, t_step)
    world, seen = _raycast_room(compose(base, MOUNT), np.linspace(-2.35, 2.35, n))
    truth = transform_points(inverse(base[0]), world)
    stamp = 100.0
    track = PoseTrack()
    ticks = np.arange(-0.1, 0.2, 0.02)
    for tk, pose in zip(ticks, _stepped_track(ticks, start, v, w0, w1, t_step), strict=True):
        track.add_pose(stamp + tk, pose)
    knots = track.knots(stamp, stamp + duration)
    assert knots is not None
    return seen, t, truth, dw.SweepKnots(*knots), (base, t)


def _mean_twist(base, t):
    d = compose(inverse(base[0]), base[-1])
    return d[0] / t[-1], d[2] / t[-1]


@pytest.mark.parametrize("kernels", ["numpy", "compiled"])
@pytest.mark.parametrize("w0,w1", [(0.0, 2.5), (2.5, 0.0), (-1.5, 1.5)])
def test_a_yaw_rate_step_inside_the_sweep_is_taken_out_by_the_wheels_not_by_one_twist(use, kernels, w0, w1):
    if kernels == "compiled":
        pytest.importorskip("fmcwlog._core")
    use(kernels)
    xy, t, truth, knots, (base, tt) = _sweep_with_a_step(w0=w0, w1=w1)
    near = np.zeros(len(xy), bool)
    v, omega = _mean_twist(base, tt)
    for speed in (None, v):  # the wheels' own speeds, and scaled to the sweep's mean speed (the same here)
        profile = dw.wheel_profile(knots, speed)
        assert profile is not None and len(profile.starts) == 4  # 0, 0.02, 0.04, 0.06 s
        _, got, _, _ = dw.deskewed_source_wheels(xy, t, profile, MOUNT, near, None, None, 0.0)
        err = np.linalg.norm(got - truth, axis=1)
        assert err.max() < 1e-3, err.max()  # measured 0.2 mm: the track's pose at the sweep's end is interpolated
    _, twist, _, _ = deskewed_source_numpy(xy, t, v, omega, MOUNT, near, None, None, 0.0)
    assert np.linalg.norm(twist - truth, axis=1).max() > 0.05  # measured 0.23-0.37 m at the far walls


def test_a_steady_sweep_is_the_constant_twist_deskew():
    """Where the wheels' twist does not change the profile is one twist, and gives its de-skew."""
    xy, t, _, knots, _ = _sweep_with_a_step(w0=1.2, w1=1.2, duration=0.08)  # ends on a stamp
    near = np.zeros(len(xy), bool)
    profile = dw.wheel_profile(knots)
    np.testing.assert_allclose(profile.twists, np.tile([2.5, 1.2], (len(profile.starts), 1)), rtol=0, atol=1e-9)
    _, got, _, _ = dw.deskewed_source_wheels_numpy(xy, t, profile, MOUNT, near, None, None, 0.0)
    _, ref, _, _ = deskewed_source_numpy(xy, t, 2.5, 1.2, MOUNT, near, None, None, 0.0)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)


def test_speed_is_scaled_and_yaw_rate_kept():
    _, _, _, knots, _ = _sweep_with_a_step(v=2.0, w0=0.0, w1=2.0)
    own = dw.wheel_profile(knots)
    scaled = dw.wheel_profile(knots, 2.2)
    dt = np.diff(np.append(own.starts, knots.times[-1]))
    mean = (own.twists[:, 0] * dt).sum() / dt.sum()
    assert abs(mean - 2.0) < 1e-4  # the arcs' speed (the last one's end interpolated)
    np.testing.assert_allclose(scaled.twists[:, 0], 2.2 / mean * own.twists[:, 0], rtol=1e-12)
    np.testing.assert_allclose((scaled.twists[:, 0] * dt).sum() / dt.sum(), 2.2, rtol=1e-12)
    np.testing.assert_array_equal(scaled.twists[:, 1], own.twists[:, 1])
    slow = dw.wheel_profile(dw.SweepKnots(knots.times, np.zeros_like(knots.poses)), 0.3)  # standing: shifted
    np.testing.assert_allclose(slow.twists[:, 0], 0.3)
    assert dw.wheel_profile(knots, float("nan")) is None
    assert dw.wheel_profile(dw.SweepKnots(np.array([0.0]), np.zeros((1, 3)))) is None
    assert dw.wheel_profile(dw.SweepKnots(np.array([0.0, 1e-6]), np.zeros((2, 3)))) is None  # too close to split
    assert dw.wheel_profile(knots, min_step=1.9) is not None  # the step: 2 rad/s
    assert dw.wheel_profile(knots, min_step=2.1) is None


def test_track_knots_cover_the_sweep_or_are_none():
    track = PoseTrack()
    for k in range(6):
        track.add_pose(10.0 + 0.02 * k, np.array([0.1 * k, 0.0, 0.01 * k]))
    times, poses = track.knots(10.01, 10.075)
    np.testing.assert_allclose(times, [0.0, 0.01, 0.03, 0.05, 0.065], atol=1e-12)
    np.testing.assert_allclose(poses[0], 0.0, atol=1e-15)
    np.testing.assert_allclose(poses[-1], [0.3250, 0.0, 0.0325], atol=2e-3)  # the motion from 10.01 s
    np.testing.assert_allclose(poses[-1, 2], 0.0325, atol=1e-12)
    assert track.knots(9.99, 10.05) is None  # starts before the track
    assert track.knots(10.05, 10.2) is None  # ends after it
    assert track.knots(10.05, 10.05) is None


def _random_profile(rng, k):
    starts = np.concatenate([[0.0], np.sort(rng.uniform(0.001, 0.1, k - 1))])
    twists = np.stack([rng.uniform(-3, 3, k), rng.uniform(-3, 3, k)], -1)
    twists[rng.random(k) < 0.2, 1] = 0.0  # straight segments
    poses = np.zeros((k, 3))
    for j in range(1, k):
        poses[j] = _arc(poses[j - 1], twists[j - 1, 0], twists[j - 1, 1], starts[j] - starts[j - 1])
    return dw.SweepProfile(starts, poses, twists)


def assert_same_source(got, ref, centroid, size):
    np.testing.assert_array_equal(got[0], ref[0])
    assert got[1].shape == ref[1].shape
    np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-9)
    thin = vx.voxel_centroids_numpy if centroid else vx.voxel_downsample_numpy
    np.testing.assert_array_equal(got[2], thin(got[1], size))  # the compiled thinning of its own points
    if ref[3] is None:
        assert got[3] is None
    else:
        assert got[3].tobytes() == ref[3].tobytes()


@needs_core
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1500), k=st.integers(1, 7),
       mount=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-4.0, 4.0)),
       near_share=st.sampled_from([0.0, 0.1, 1.0]), moving_share=st.sampled_from([None, 0.0, 0.3]),
       velocity=st.sampled_from([None, "float64", "float32"]), size=st.sampled_from([0.0, 0.03, 0.1]),
       centroid=st.booleans())
def test_generated_wheel_deskew_agrees(use, seed, n, k, mount, near_share, moving_share, velocity, size, centroid):
    """Random profiles (1-7 segments), points with times before, inside and after them: the compiled
    kernel's mask and velocities exactly, its points numpy's to 1e-9 m, its thinning that of its points."""
    rng = np.random.default_rng(seed)
    profile = _random_profile(rng, k)
    xy = rng.uniform(-40, 40, (n, 2))
    t = np.sort(rng.uniform(-0.01, 0.12, n))
    if n:
        t[rng.integers(0, n, min(n, 3))] = profile.starts[rng.integers(0, k, min(n, 3))]  # exactly on a knot
        t.sort()
    near = rng.uniform(size=n) < near_share
    moving = None if moving_share is None else rng.uniform(size=n) < moving_share
    vel = None if velocity is None else rng.normal(0, 2, n).astype(velocity)
    use("compiled")
    mount = np.array(mount)
    got = dw.deskewed_source_wheels(xy, t, profile, mount, near, moving, vel, size, centroid)
    ref = dw.deskewed_source_wheels_numpy(xy, t, profile, mount, near, moving, vel, size, centroid)
    assert_same_source(got, ref, centroid, size)


@pytest.fixture(scope="module")
def recorded():
    """Every wheel-profile source cloud the improved front end makes processing the 30 s crowd log, each
    sweep de-skewed by the wheels (``deskew_min_yaw_step`` 0)."""
    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.frontend import methods
    from fmcwlog.pipeline.params import load_params

    seen = []
    original = methods.deskewed_source_wheels

    def capture(*args):
        seen.append(tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args))
        return dw.deskewed_source_wheels_numpy(*args)

    methods.deskewed_source_wheels = capture
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/out",
                    ProcessOptions(methods=("improved",), backend="none",
                                   params=load_params({"deskew_min_yaw_step": 0.0})), jobs=1)
    finally:
        methods.deskewed_source_wheels = original
    return seen


@needs_core
def test_recorded_wheel_deskew_agrees(recorded, use):
    use("compiled")
    assert len(recorded) > 200
    segments = 0
    for xy, t, profile, mount, near, moving, velocity, size, centroid in recorded:
        segments = max(segments, len(profile.starts))
        for s, c in ((size, centroid), (0.03, False), (size, True), (0.0, False)):
            got = dw.deskewed_source_wheels(xy, t, profile, mount, near, moving, velocity, s, c)
            ref = dw.deskewed_source_wheels_numpy(xy, t, profile, mount, near, moving, velocity, s, c)
            assert_same_source(got, ref, c, s)
    assert segments >= 3  # the ticks' stamps split the sweeps
