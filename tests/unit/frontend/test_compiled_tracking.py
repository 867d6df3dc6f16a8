"""The compiled segmentation and mover tracking (fmcwlog._core) against their numpy reference.

Labels, the clustered and moving masks are compared exactly, track states to 1e-9: on the sweeps
the improved method segments on the recorded logs, and on generated scenes. Where the module is
not built the comparisons skip, unless ``FMCWLOG_KERNELS=compiled`` asks for it (CI does).
"""

import os
import tempfile
from dataclasses import replace

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import segmentation as sg
from fmcwlog.frontend import tracking
from fmcwlog.frontend.segmentation import SegmentationParams
from fmcwlog.kernels import compiled


def assert_same_segmentation(fast, ref):
    for name in ("labels", "clustered", "moving"):
        got, want = getattr(fast, name), getattr(ref, name)
        assert got.dtype == want.dtype, name
        np.testing.assert_array_equal(got, want, err_msg=name)


def _state(tracker):
    return tuple(a.copy() for a in (tracker.x, tracker.cov, tracker.time, tracker.last_update, tracker.moving_hits))


def _set_state(tracker, state):
    tracker.x, tracker.cov, tracker.time, tracker.last_update, tracker.moving_hits = (a.copy() for a in state)


def _select(kind):
    os.environ[compiled.ENV] = kind
    compiled._chosen = None


def _both(segment, tracker, *args, **kw):
    """``segment`` (MoverTracker.segment) from the tracker's state with the numpy and the compiled
    kernels: (mask, state) of each, the state with the recent rays' ring after; the tracker is left in
    the numpy run's state."""
    before, runs = _state(tracker), {}
    rays = tracker.rays.state()  # the sweeps' rays before this one
    for kind in ("compiled", "numpy"):
        _set_state(tracker, before)
        near, origin, yaw_errors, tracker.rays.head, tracker.rays.count = rays
        tracker.rays.near, tracker.rays.origin, tracker.rays.yaw_errors = near.copy(), origin.copy(), yaw_errors.copy()
        _select(kind)
        mask = segment(tracker, *args, **kw)
        near, origin, yaw_errors, head, count = tracker.rays.state()
        runs[kind] = (mask, _state(tracker) + (near, origin, yaw_errors, np.array([head, count])))
    return runs["numpy"], runs["compiled"]


def assert_same_tracks(fast, ref):
    """Masks, track counts, hits and times exactly; states and covariances to 1e-9 (and, where given,
    the recent rays' ring to 1e-9, its slots exactly)."""
    (mask, state), (want_mask, want) = fast, ref
    assert mask.dtype == want_mask.dtype
    np.testing.assert_array_equal(mask, want_mask)
    assert state[0].shape == want[0].shape
    np.testing.assert_allclose(state[0], want[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(state[1], want[1], rtol=0, atol=1e-9)
    for got, expected in zip(state[2:5], want[2:5]):
        assert got.dtype == expected.dtype
        np.testing.assert_array_equal(got, expected)
    if len(want) > 5:  # the recent rays' ring (from each kernel's de-skew: the same to rounding) and its slots
        for got, expected in zip(state[5:8], want[5:8]):
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(state[8], want[8])


@pytest.fixture(scope="module")
def recorded():
    """The two 30 s logs processed by the improved method, every sweep's tracking done with both
    kernels from the same state (the run goes on from the numpy one): "sweeps", the (numpy, compiled)
    results of each, and "segmentations", what the tracker gave DBSCAN on every third sweep
    (xy, epsilon, params, seeds, seed_points); "rays", how many sweeps' rays the tracker held after each."""
    from fmcwlog.api import ProcessOptions, process

    sweeps, segmentations, rays = [], [], []
    original_segment, original_clusters = tracking.MoverTracker.segment, tracking.segment_clusters

    def clusters(xy, epsilon, params, seeds=None, seed_points=None):
        segmentations.append((xy.copy(), np.array(epsilon, float), params, seeds, seed_points))
        return original_clusters(xy, epsilon, params, seeds, seed_points)

    def segment(tracker, *args, **kw):
        ref, fast = _both(original_segment, tracker, *args, **kw)
        sweeps.append((ref, fast))
        rays.append(tracker.rays.count)
        return ref[0]

    kind = os.environ.get(compiled.ENV)
    tracking.MoverTracker.segment, tracking.segment_clusters = segment, clusters
    try:
        for log in ("crowd_30s", "corridor_30s"):
            with tempfile.TemporaryDirectory() as tmp:
                process(str(SAMPLE_LOGS / f"{log}.mcap"), tmp + "/out",
                        ProcessOptions(methods=("improved",), backend="none"), jobs=1)
    finally:
        tracking.MoverTracker.segment, tracking.segment_clusters = original_segment, original_clusters
        if kind is None:
            os.environ.pop(compiled.ENV, None)
        else:
            os.environ[compiled.ENV] = kind
        compiled._chosen = None
    return {"sweeps": sweeps, "segmentations": segmentations[::3], "rays": rays}


@needs_core
def test_recorded_tracking_agrees(recorded):
    sweeps = recorded["sweeps"]
    assert len(sweeps) == 600
    for ref, fast in sweeps:
        assert_same_tracks(fast, ref)
    assert sum(len(ref[1][0]) for ref, _ in sweeps) > 3000  # tracks were followed (crowd_30s holds movers)
    assert sum(int(ref[0].sum()) for ref, _ in sweeps) > 50_000
    # each sweep's rays are kept once (both runs start from the same ones), up to displacement_sweeps
    kept = recorded["rays"]
    assert kept[:12] == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 10, 10]


@needs_core
def test_recorded_segmentations_agree(recorded, use):
    assert len(recorded["segmentations"]) > 150
    use("compiled")
    clusters = 0
    for xy, epsilon, params, seeds, seed_points in recorded["segmentations"]:
        ref = sg.segment_clusters_numpy(xy, epsilon, params, seeds, seed_points)
        fast = sg.segment_clusters(xy, epsilon, params, seeds, seed_points)
        assert_same_segmentation(fast, ref)
        clusters += int(ref.labels.max()) + 1
        feats = np.column_stack([xy, epsilon])
        for eps, min_samples in ((0.3, 5), (1.0, 12)):
            np.testing.assert_array_equal(sg.dbscan(feats, eps, min_samples), sg.dbscan_numpy(feats, eps, min_samples))
    assert clusters > 1000  # the sweeps hold clusters (the comparison is not between empty labels)


def _scene(seed, n_objects, n_points, n_clutter):
    """Objects (blobs with a shared Doppler) and walls (lines with none) around the origin, and clutter."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-12, 12, (n_objects, 2))
    speed = rng.choice([0.0, 0.0, 0.5, -1.2, 2.0], n_objects)
    which = rng.integers(0, n_objects, n_points)
    xy = centres[which] + rng.normal(0, rng.uniform(0.05, 0.4, n_objects)[which, None], (n_points, 2))
    eps = speed[which] + rng.normal(0, 0.05, n_points)
    wall = rng.uniform(-12, 12, (n_clutter, 2))
    wall[: n_clutter // 2, 1] = rng.uniform(-12, 12)  # half of it along one line
    xy = np.concatenate([xy, wall])
    eps = np.concatenate([eps, rng.normal(0, 0.1, n_clutter)])
    order = rng.permutation(len(xy))
    return np.ascontiguousarray(xy[order]), eps[order], rng


@needs_core
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_objects=st.integers(1, 20), n_points=st.integers(0, 1500),
       n_clutter=st.integers(0, 400), alpha=st.sampled_from([0.0, 1.0, 25.0]), eps=st.sampled_from([0.1, 0.3, 0.8]),
       min_samples=st.integers(1, 12), fraction=st.sampled_from([0.1, 0.3, 1.0]),
       neighbourhood=st.sampled_from([0.0, 0.5, 2.0]), keep=st.booleans(), n_seeds=st.integers(0, 6),
       marks=st.booleans())
def test_generated_segmentations_agree(use, seed, n_objects, n_points, n_clutter, alpha, eps, min_samples, fraction,
                                       neighbourhood, keep, n_seeds, marks):
    xy, epsilon, rng = _scene(seed, n_objects, n_points, n_clutter)
    params = replace(SegmentationParams(), alpha=alpha, eps=eps, min_samples=min_samples,
                     min_moving_fraction=fraction, neighbourhood=neighbourhood, keep_strong_points=keep)
    seeds = rng.uniform(-12, 12, (n_seeds, 2)) if n_seeds else None
    seed_points = rng.random(len(xy)) < 0.05 if marks else None
    ref = sg.segment_clusters_numpy(xy, epsilon, params, seeds, seed_points)
    use("compiled")
    assert_same_segmentation(sg.segment_clusters(xy, epsilon, params, seeds, seed_points), ref)


@needs_core
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 600), dim=st.integers(1, 6), eps=st.floats(0.05, 3.0),
       min_samples=st.integers(1, 15), grid=st.booleans())
def test_generated_dbscan_agrees(use, seed, n, dim, eps, min_samples, grid):
    """Any dimension; on a lattice (``grid``) many pairs lie exactly at ``eps``, where the ``<=`` decides."""
    rng = np.random.default_rng(seed)
    feats = rng.integers(-6, 7, (n, dim)).astype(float) if grid else rng.normal(0, 2.0, (n, dim))
    if grid:
        eps = float(np.round(eps)) or 1.0
    want = sg.dbscan_numpy(feats, eps, min_samples)
    use("compiled")
    np.testing.assert_array_equal(sg.dbscan(feats, eps, min_samples), want)


@needs_core
def test_odd_inputs(use):
    """No point, one point, far-apart points; a NaN is the reference's error (the compiled kernel hands it over)."""
    use("compiled")
    params = SegmentationParams()
    for xy, epsilon in ((np.empty((0, 2)), np.empty(0)), (np.array([[1.0, 2.0]]), np.array([0.5])),
                        (np.array([[0.0, 0.0], [1e7, -1e7], [0.1, 0.0]] * 3), np.full(9, 1.0))):
        ref = sg.segment_clusters_numpy(xy, epsilon, params)
        assert_same_segmentation(sg.segment_clusters(xy, epsilon, params), ref)
        feats = np.column_stack([xy, epsilon])
        np.testing.assert_array_equal(sg.dbscan(feats, 0.3, 2), sg.dbscan_numpy(feats, 0.3, 2))
    xy = np.array([[0.0, 0.0], [np.nan, 1.0], [0.1, 0.0]] * 3)
    for run in (sg.segment_clusters_numpy, sg.segment_clusters):
        with pytest.raises(ValueError, match="finite"):
            run(xy, np.ones(9), params)
    for run in (sg.dbscan_numpy, sg.dbscan):
        with pytest.raises(ValueError, match="finite"):
            run(np.column_stack([xy, np.ones(9)]), 0.3, 2)


class _Free:
    """The free-space lookup's stand-in (:func:`tracking.placed_free_space`): the sweep placed by the
    compiled de-skew, the candidates seen free where a given mask says."""

    def __init__(self):
        self.mask = None

    def __call__(self, recent, xy, t, twist, mount, lidar, ranges, yaw_error, tolerance, threshold):
        placed = tracking.deskew_placed(xy, t, twist[0], twist[1], mount, lidar)
        candidates = (np.hypot(xy[:, 0], xy[:, 1]) if ranges is None else ranges) * yaw_error <= tolerance
        return placed, self.mask & candidates


@needs_core
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n_walkers=st.integers(0, 8), n_sweeps=st.integers(1, 12),
       min_hits=st.integers(1, 3), min_speed=st.sampled_from([0.0, 0.3]), claim_radius=st.sampled_from([0.0, 0.5, 1.5]),
       max_tracks=st.sampled_from([1, 3, 64]), free=st.sampled_from([0.0, 0.3]), gate=st.sampled_from([0.5, 1.0, 3.0]))
def test_generated_tracking_agrees(use, seed, n_walkers, n_sweeps, min_hits, min_speed, claim_radius, max_tracks,
                                   free, gate):
    """Walkers (blobs moving at constant velocity, with the Doppler of their motion, some across the
    beams) among walls, seen from a robot driving ahead, a sweep every 0.1 s; parts of the scene in
    free space at random; the tracker run by both kernels from the same state every sweep."""
    use("compiled")  # the switch comes back as it was after the test
    rng = np.random.default_rng(seed)
    params = replace(tracking.TrackingParams(), min_moving_hits=min_hits, min_speed=min_speed,
                     claim_radius=claim_radius, max_tracks=max_tracks, gate_distance=gate)
    tracker = tracking.MoverTracker(params)
    free_space, lookup = tracking.placed_free_space, _Free()
    tracking.placed_free_space = lookup
    try:
        _walk(tracker, rng, n_walkers, n_sweeps, free, lookup)
    finally:
        tracking.placed_free_space = free_space


def _walk(tracker, rng, n_walkers, n_sweeps, free, lookup):
    """test_generated_tracking_agrees's sweeps, each segmented by both kernels from the same state."""
    start = rng.uniform(-8, 8, (n_walkers, 2))
    velocity = rng.normal(0, 1.0, (n_walkers, 2))
    walls = np.concatenate([np.column_stack([np.linspace(-10, 10, 200), np.full(200, y)]) for y in (-6.0, 7.0)])
    mount = np.array([0.1, 0.0, 0.0])
    for k in range(n_sweeps):
        stamp = 0.1 * k
        base = np.array([0.3 * stamp, 0.0, 0.02 * stamp])
        lidar = tracking.compose(base, mount)
        centres = start + velocity * stamp
        which = rng.integers(0, max(n_walkers, 1), 30 * n_walkers)
        blobs = centres[which] + rng.normal(0, 0.15, (len(which), 2)) if n_walkers else np.empty((0, 2))
        world = np.concatenate([blobs, walls + rng.normal(0, 0.01, walls.shape)])
        xy = tracking.transform_points(tracking.inverse(lidar), world)
        u = (world - lidar[:2]) / np.linalg.norm(world - lidar[:2], axis=1)[:, None]
        v = np.concatenate([velocity[which], np.zeros((len(walls), 2))]) if n_walkers else np.zeros((len(walls), 2))
        epsilon = np.round(np.einsum("ij,ij->i", u, v) / 0.1) * 0.1 + rng.normal(0, 0.02, len(xy))
        order = np.argsort(np.arctan2(xy[:, 1], xy[:, 0]))
        xy, epsilon = np.ascontiguousarray(xy[order]), epsilon[order]
        t = np.linspace(0.0, 0.1, len(xy), endpoint=False)
        lookup.mask = rng.random(len(xy)) < free
        ref, fast = _both(tracking.MoverTracker.segment, tracker, xy, t, epsilon, stamp, base, (0.3, 0.02), mount,
                          None, SegmentationParams(), 0.0)
        assert_same_tracks(fast, ref)


def test_numpy_switch(use):
    """With ``FMCWLOG_KERNELS=numpy`` the reference answers."""
    assert use("numpy") is None
    xy, epsilon, _ = _scene(1, 5, 300, 50)
    assert_same_segmentation(sg.segment_clusters(xy, epsilon), sg.segment_clusters_numpy(xy, epsilon))
