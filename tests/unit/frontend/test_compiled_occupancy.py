"""The compiled occupancy kernels (ray casting, applying a cast, the tracker's grid lookups) against
their numpy reference: the same cells, the same float32 increments and log-odds bit for bit, the
same free-space verdicts and local maxima. On what the improved method casts and looks up on a
recorded log, and on generated scans (cells on the lattice's lines, beams cut at the range limit,
zero-length beams, other resolutions and sampling steps)."""

import os

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, needs_core
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend import recent_grid
from fmcwlog.frontend.recent_grid import RecentOccupancy, local_max_log_odds, local_max_log_odds_numpy
from fmcwlog.kernels import compiled
from fmcwlog.kernels import occupancy as occ
from fmcwlog.kernels.occupancy import OccupancyGrid, OccupancyParams, Scan


def assert_same_update(fast: occ.ScanUpdate, ref: occ.ScanUpdate) -> None:
    assert (fast.y0, fast.x0) == (ref.y0, ref.x0)
    for name in ("rows", "cols", "increment"):
        a, b = getattr(fast, name), getattr(ref, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name


def _grid_bytes(scans, params, kind, use):
    """The log-odds and observed arrays of a grid given ``scans`` with the ``kind`` kernels."""
    use(kind)
    grid = OccupancyGrid(params)
    for origin, points in scans:
        grid.integrate(origin, points)
    return grid.log_odds.tobytes(), grid.observed.tobytes(), grid.ix0, grid.iy0, grid.log_odds.shape


@pytest.fixture(scope="module")
def recorded():
    """What the improved method casts and looks up processing the 30 s crowd log with the compiled
    kernels: the scans (origin, points, params) and, at every lookup, both kernels' answers."""
    import tempfile

    from fmcwlog.api import ProcessOptions, process

    casts, lookups = [], []
    update, seen_free, local_max = Scan.update, RecentOccupancy.seen_free, recent_grid.local_max_log_odds

    def record_update(self, params):
        if params not in self._updates:
            casts.append((self.origin.copy(), self.points.copy(), params))
        return update(self, params)

    def record_seen_free(self, map_xy, candidates, threshold):
        fast = seen_free(self, map_xy, candidates, threshold)
        lookups.append(("seen_free", fast, self.seen_free_numpy(map_xy, candidates, threshold)))
        return fast

    def record_placed_free(recent, xy, t, twist, mount, lidar, ranges, yaw_error, tolerance, threshold):
        map_xy, free = placed_free(recent, xy, t, twist, mount, lidar, ranges, yaw_error, tolerance, threshold)
        candidates = (np.hypot(xy[:, 0], xy[:, 1]) if ranges is None else ranges) * yaw_error <= tolerance
        lookups.append(("seen_free", free, recent.seen_free_numpy(map_xy, candidates, threshold)))
        lookups.append(("placed", map_xy, deskew.deskew_placed(xy, t, twist[0], twist[1], mount, lidar)))
        ref_xy, _ = tracking.placed_free_space_numpy(recent, xy, t, twist, mount, lidar, ranges, yaw_error, tolerance,
                                                     threshold)
        np.testing.assert_allclose(map_xy, ref_xy, rtol=0, atol=1e-9)
        return map_xy, free

    def record_local_max(grid, map_xy):
        fast = local_max(grid, map_xy)
        lookups.append(("local_max", fast, local_max_log_odds_numpy(grid, map_xy)))
        return fast

    saved = os.environ.get(compiled.ENV), compiled._chosen, compiled._core
    Scan.update, RecentOccupancy.seen_free, recent_grid.local_max_log_odds = record_update, record_seen_free, record_local_max
    from fmcwlog.frontend import deskew, tracking
    tracking_local_max, tracking.local_max_log_odds = tracking.local_max_log_odds, record_local_max
    placed_free, tracking.placed_free_space = tracking.placed_free_space, record_placed_free
    os.environ[compiled.ENV], compiled._chosen, compiled._core = "compiled", None, None
    try:
        if compiled.core() is not None:
            with tempfile.TemporaryDirectory() as tmp:
                process(str(SAMPLE_LOGS / "crowd_30s.mcap"), tmp + "/out", ProcessOptions(methods=("improved",)), jobs=1)
    finally:
        Scan.update, RecentOccupancy.seen_free, recent_grid.local_max_log_odds = update, seen_free, local_max
        tracking.local_max_log_odds = tracking_local_max
        tracking.placed_free_space = placed_free
        if saved[0] is None:
            os.environ.pop(compiled.ENV, None)
        else:
            os.environ[compiled.ENV] = saved[0]
        compiled._chosen, compiled._core = saved[1], saved[2]
    return casts, lookups


@needs_core
def test_recorded_casts_agree(recorded, use):
    casts, _ = recorded
    assert len(casts) > 40
    use("compiled")
    for origin, points, params in casts:
        assert_same_update(occ.cast(origin, points, params), occ.cast_numpy(origin, points, params))


@needs_core
def test_recorded_grids_agree(recorded, use):
    """All the log's scans in one grid, and in one with a range limit (clamps reached, cells cut off)."""
    casts, _ = recorded
    scans = [(origin, points) for origin, points, _ in casts]
    for params in (OccupancyParams(), OccupancyParams(max_range=6.0, l_max=1.7, l_min=-0.8)):
        assert _grid_bytes(scans, params, "compiled", use) == _grid_bytes(scans, params, "numpy", use)


@needs_core
def test_recorded_lookups_agree(recorded):
    """Every free-space lookup of the tracker (the sweep placed and looked up in one call: the points of
    the compiled de-skew, the verdicts of the numpy lookup on them) and every structure check: the same
    answers."""
    _, lookups = recorded
    kinds = [kind for kind, _, _ in lookups]
    assert kinds.count("seen_free") > 250 and kinds.count("local_max") > 50 and kinds.count("placed") > 250
    assert any(fast.any() for kind, fast, _ in lookups if kind == "seen_free")
    for kind, fast, ref in lookups:
        assert fast.dtype == ref.dtype and fast.tobytes() == ref.tobytes(), kind


_resolutions = st.sampled_from([0.05, 0.1, 0.037, 0.25, 1.0])


@st.composite
def scans(draw, far=False):
    """A sensor and beams about it; with ``snap``, the sensor and the end points on lattice lines
    (where a sample's cell is decided by the division itself). ``far``: the sensor may be 6e7 m
    out too, where the lattice's cells pass 2^30 (the kernel's scalar loop)."""
    res = draw(_resolutions)
    snap = draw(st.booleans())
    offset = draw(st.sampled_from([0.0, 6e7, -6e7])) if far else 0.0
    ox, oy = draw(st.floats(-30, 30)) + offset, draw(st.floats(-30, 30))
    beams = draw(st.lists(st.tuples(st.floats(0, 12), st.floats(-np.pi, np.pi)), min_size=1, max_size=40))
    origin = np.array([ox, oy])
    points = origin + np.array([[r * np.cos(a), r * np.sin(a)] for r, a in beams])
    if snap:
        origin = np.round(origin / res) * res
        points = np.round(points / res) * res
        points[::3] = origin  # zero-length beams too
        points[1::4, 1] = origin[1]  # and beams along the lattice's lines
    return res, origin, points


@pytest.fixture(params=[2, 1, 0], ids=["avx2", "sse2", "scalar"])
def simd(request, use):
    """The kernel's widest ray-sample loop for the test (AVX2 only where the CPU has it)."""
    core = use("compiled")
    was = core._occupancy_simd(request.param)
    yield request.param
    core._occupancy_simd(was)


@needs_core
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scan=scans(far=True), max_range=st.sampled_from([None, 3.0, 0.01]), protect_hits=st.booleans(),
       step_fraction=st.sampled_from([0.5, 0.3, 1.0, 2.5]))
def test_generated_casts_agree(simd, scan, max_range, protect_hits, step_fraction):
    res, origin, points = scan
    params = OccupancyParams(resolution=res, max_range=max_range, protect_hits=protect_hits, step_fraction=step_fraction)
    assert_same_update(occ.cast(origin, points, params), occ.cast_numpy(origin, points, params))


@needs_core
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scan=scans(far=True), max_range=st.sampled_from([None, 3.0, 0.01]), odd=st.sampled_from([None, 0, 1]))
def test_generated_scan_cells_agree(use, scan, max_range, odd):
    """The cells a grid must hold for a scan: the same as numpy's; with ``odd``, a point or the sensor
    not finite, where the kernel declines and numpy answers."""
    res, origin, points = scan
    params = OccupancyParams(resolution=res, max_range=max_range)
    if odd is not None:
        (points if odd else origin)[0] = np.nan
    core = use("compiled")
    with np.errstate(invalid="ignore"):
        ref = occ.scan_cells_numpy(origin, points, params)
        assert occ.scan_cells(origin, points, params) == ref
    direct = core.occupancy_scan_cells(points, *origin.tolist(), max_range is not None, max_range or 0.0, res)
    assert (direct is None) == (odd is not None)
    if direct is not None:
        assert direct == ref


@needs_core
def test_recorded_scan_cells_agree(recorded, use):
    casts, _ = recorded
    use("compiled")
    for origin, points, params in casts:
        for p in (params, OccupancyParams(resolution=params.resolution, max_range=4.0)):
            assert occ.scan_cells(origin, points, p) == occ.scan_cells_numpy(origin, points, p)


@needs_core
def test_recorded_casts_agree_in_every_loop(recorded, simd):
    casts, _ = recorded
    for origin, points, params in casts[::4]:
        assert_same_update(occ.cast(origin, points, params), occ.cast_numpy(origin, points, params))


@needs_core
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(many=st.lists(scans(), min_size=1, max_size=8), l_max=st.sampled_from([3.5, 0.9, 3.3]))
def test_generated_grids_agree(use, many, l_max):
    """Scans piled on one grid until the clamps bind (l_max 3.3 is not a float32)."""
    res = many[0][0]
    scans_ = [(origin, points) for _, origin, points in many] * 3
    params = OccupancyParams(resolution=res, l_max=l_max, l_min=-1.1)
    assert _grid_bytes(scans_, params, "compiled", use) == _grid_bytes(scans_, params, "numpy", use)


@needs_core
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(many=st.lists(st.tuples(scans(), st.floats(0, 30)), min_size=1, max_size=8),
       threshold=st.sampled_from([-1.2, -0.4, 0.0, 0.85]), seed=st.integers(0, 3))
def test_generated_lookups_agree(use, many, threshold, seed):
    """Points on the grids, about them, far off and not finite: the same verdicts and maxima."""
    use("compiled")
    res = many[0][0][0]
    recent = RecentOccupancy(20.0, res)
    grid = OccupancyGrid(OccupancyParams(resolution=res))
    path, hits = 0.0, []
    for (_, origin, points), travelled in many:
        path += travelled
        scan = Scan(origin, points)
        grid.add(scan)
        recent.integrate(scan, path)
        hits.append(points)
    rng = np.random.default_rng(seed)
    hit = np.concatenate(hits)
    map_xy = np.concatenate([hit, hit + rng.normal(0, res, hit.shape), rng.uniform(-60, 60, (30, 2)),
                             [[1e300, 0.0], [-1e30, 5.0], [np.nan, 1.0], [np.inf, -np.inf]]])
    candidates = rng.random(len(map_xy)) < 0.8
    with np.errstate(invalid="ignore"):
        ref = recent.seen_free_numpy(map_xy, candidates, threshold)
        ref_max = local_max_log_odds_numpy(grid, map_xy)
    fast = recent.seen_free(map_xy, candidates, threshold)
    fast_max = local_max_log_odds(grid, map_xy)
    assert fast.tobytes() == ref.tobytes()
    assert fast_max.dtype == ref_max.dtype and fast_max.tobytes() == ref_max.tobytes()
    # the same points as a sweep seen from a lidar pose, placed and looked up in one call: the compiled
    # de-skew's points, the numpy lookup's verdicts on them (ranges given or the kernel's own np.hypot)
    from fmcwlog.frontend.deskew import deskew_placed
    from fmcwlog.frontend.tracking import placed_free_space

    lidar = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-3, 3)])
    mount = np.array([0.3, -0.1, rng.uniform(-3, 3)])
    xy = np.ascontiguousarray(map_xy)
    t = np.sort(rng.uniform(0, 0.1, len(xy)))
    twist = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
    with np.errstate(invalid="ignore", over="ignore"):
        for ranges in (None, np.hypot(xy[:, 0], xy[:, 1])):
            for yaw_error in (0.0, 0.01, np.inf):
                placed, free = placed_free_space(recent, xy, t, twist, mount, lidar, ranges, yaw_error, 0.05, threshold)
                assert placed.tobytes() == deskew_placed(xy, t, twist[0], twist[1], mount, lidar).tobytes()
                candidates = np.hypot(xy[:, 0], xy[:, 1]) * yaw_error <= 0.05
                assert free.tobytes() == recent.seen_free_numpy(placed, candidates, threshold).tobytes()


@needs_core
def test_declined_scans_are_cast_in_numpy(use):
    """A point not finite, or a window over max_cells: the kernel declines, cast gives numpy's answer."""
    core = use("compiled")
    points = np.array([[1.0, 2.0], [np.nan, 0.0]])
    assert core.occupancy_cast(points, 0.0, 0.0, 0.05, 0.5, 0.85, -0.4, False, 0.0, True, 10**6) is None
    far = np.array([[100.0, 100.0]])
    assert core.occupancy_cast(far, 0.0, 0.0, 0.05, 0.5, 0.85, -0.4, False, 0.0, True, 1000) is None
    small = OccupancyParams(max_cells=1000)
    assert_same_update(occ.cast(np.zeros(2), far, small), occ.cast_numpy(np.zeros(2), far, small))


@needs_core
def test_apply_rejects_cells_outside_the_grid(use):
    core = use("compiled")
    log_odds, observed = np.zeros((4, 5), np.float32), np.zeros((4, 5), bool)
    cells = np.array([0, 4], np.int32)
    with pytest.raises(IndexError):
        core.occupancy_apply(log_odds, observed, 0, 1, cells, cells, np.ones(2, np.float32), -2.0, 3.5)
    assert not observed.any() and not log_odds.any()  # nothing written


def _ros_pair(grid, use):
    use("compiled")
    fast = grid.to_ros_int8()
    return fast, grid.to_ros_int8_numpy()


@needs_core
def test_recorded_map_messages_agree(recorded, use):
    casts, _ = recorded
    grid = OccupancyGrid()
    for origin, points, _ in casts:
        grid.integrate(origin, points)
    fast, ref = _ros_pair(grid, use)
    assert fast.dtype == ref.dtype == np.int8 and fast.tobytes() == ref.tobytes()
    assert (ref == -1).any() and (ref > 65).any() and ((ref >= 0) & (ref < 25)).any()


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), shape=st.tuples(st.integers(0, 40), st.integers(0, 40)))
def test_map_messages_agree_at_the_rounding_edges(use, seed, shape):
    """Log-odds where 100 p is a half (to float32) and a float32 step either side, clamps, zeros and
    any value, observed or not: the same int8 values."""
    rng = np.random.default_rng(seed)
    halves = (np.arange(100) + 0.5) / 100.0
    edge = np.log(halves / (1.0 - halves)).astype(np.float32)
    edges = np.concatenate([edge, np.nextafter(edge, np.float32(-np.inf)), np.nextafter(edge, np.float32(np.inf)),
                            np.float32([0.0, -0.0, -2.0, 3.5, 20.0, -20.0, 100.0, -100.0])])
    values = np.where(rng.random(shape) < 0.5, rng.choice(edges, shape), rng.normal(0, 3, shape)).astype(np.float32)
    grid = OccupancyGrid()
    grid._log_odds, grid._observed = values, rng.random(shape) < 0.8
    fast, ref = _ros_pair(grid, use)
    assert fast.tobytes() == ref.tobytes()
