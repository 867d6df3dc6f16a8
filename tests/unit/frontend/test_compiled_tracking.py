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
from helpers import SAMPLE_LOGS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import segmentation as sg
from fmcwlog.frontend import tracking
from fmcwlog.frontend.segmentation import SegmentationParams
from fmcwlog.kernels import compiled

CORE, WHY_NOT = compiled._load()
needs_core = pytest.mark.skipif(
    CORE is None and os.environ.get(compiled.ENV) != "compiled", reason=f"{WHY_NOT} (FMCWLOG_KERNELS=compiled fails instead)")


@pytest.fixture
def use(monkeypatch):
    """``use("compiled")`` or ``use("numpy")``: the switch as a fresh process would set it."""
    def select(kind):
        monkeypatch.setenv(compiled.ENV, kind)
        monkeypatch.setattr(compiled, "_chosen", None)
        monkeypatch.setattr(compiled, "_core", None)
        return compiled.core()
    return select


def assert_same_segmentation(fast, ref):
    for name in ("labels", "clustered", "moving"):
        got, want = getattr(fast, name), getattr(ref, name)
        assert got.dtype == want.dtype, name
        np.testing.assert_array_equal(got, want, err_msg=name)


@pytest.fixture(scope="module")
def recorded_sweeps():
    """What the tracker gives DBSCAN on every third sweep of the two 30 s logs (numpy kernels):
    (xy, epsilon, params, seeds, seed_points)."""
    from fmcwlog.api import ProcessOptions, process

    seen, original = [], tracking.segment_clusters

    def capture(xy, epsilon, params, seeds=None, seed_points=None):
        seen.append((xy.copy(), np.array(epsilon, float), params, seeds, seed_points))
        return sg.segment_clusters_numpy(xy, epsilon, params, seeds, seed_points)

    tracking.segment_clusters = capture
    kind = os.environ.get(compiled.ENV)
    try:
        os.environ[compiled.ENV] = "numpy"
        compiled._chosen = None
        for log in ("crowd_30s", "corridor_30s"):
            with tempfile.TemporaryDirectory() as tmp:
                process(str(SAMPLE_LOGS / f"{log}.mcap"), tmp + "/out",
                        ProcessOptions(methods=("improved",), backend="none"), jobs=1)
    finally:
        tracking.segment_clusters = original
        if kind is None:
            os.environ.pop(compiled.ENV, None)
        else:
            os.environ[compiled.ENV] = kind
        compiled._chosen = None
    return seen[::3]


@needs_core
def test_recorded_segmentations_agree(recorded_sweeps, use):
    assert len(recorded_sweeps) > 150
    use("compiled")
    clusters = 0
    for xy, epsilon, params, seeds, seed_points in recorded_sweeps:
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


def test_numpy_switch(use):
    """With ``FMCWLOG_KERNELS=numpy`` the reference answers."""
    assert use("numpy") is None
    xy, epsilon, _ = _scene(1, 5, 300, 50)
    assert_same_segmentation(sg.segment_clusters(xy, epsilon), sg.segment_clusters_numpy(xy, epsilon))
