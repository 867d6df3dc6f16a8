"""Tests of fmcwlog.metrics against hand-derived answers, published numbers and evo."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.evaluation import metrics as M
from fmcwlog.geometry import between, compose, inverse, wrap_angle

try:  # evo is an optional test dependency (pyproject [test]); only the cross-checks need it
    from evo.core import filters as evo_filters
    from evo.core import metrics as evo_metrics
    from evo.core import sync as evo_sync
    from evo.core.sync_method import SyncMethod
    from evo.core.trajectory import PoseTrajectory3D

    HAVE_EVO = True
except ImportError:  # pragma: no cover
    HAVE_EVO = False

needs_evo = pytest.mark.skipif(not HAVE_EVO, reason="evo not installed")

# ---------------------------------------------------------------- helpers


def random_walk(rng: np.random.Generator, n: int, dt: float = 0.1, speed: float = 1.0) -> np.ndarray:
    """Planar unicycle random walk (N, 3), ~``speed`` m/s, sampled every ``dt`` s."""
    v = speed * (1.0 + 0.3 * rng.standard_normal(n - 1))
    w = 0.3 * rng.standard_normal(n - 1)
    yaw0 = rng.uniform(-np.pi, np.pi)
    yaw = np.concatenate([[yaw0], yaw0 + np.cumsum(w * dt)])
    steps = np.c_[v * dt * np.cos(yaw[:-1]), v * dt * np.sin(yaw[:-1])]
    xy = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]) + rng.uniform(-50, 50, 2)
    return np.c_[xy, wrap_angle(yaw)]


def drifting_estimate(rng: np.random.Generator, ref: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Dead-reckoned estimate: ref's relative motions with noise, started at ``start``."""
    rel = between(ref[:-1], ref[1:])
    rel = rel * (1.0 + 0.02 * rng.standard_normal(rel.shape))
    rel[:, 2] += 0.003 * rng.standard_normal(len(rel))
    out = np.empty_like(ref)
    out[0] = start
    for k, r in enumerate(rel):  # test data generation only
        out[k + 1] = compose(out[k], r)
    return out


def straight_line(n: int, step: float) -> np.ndarray:
    """Poses along +x, ``step`` m apart, yaw 0."""
    return np.c_[np.arange(n) * step, np.zeros(n), np.zeros(n)]


def zigzag(n: int, step: float) -> np.ndarray:
    """Back and forth along y between 0 and ``step``: every step is exactly ``step`` m."""
    return np.c_[np.zeros(n), np.where(np.arange(n) % 2 == 1, step, 0.0), np.zeros(n)]


# ---------------------------------------------------------------- statistics


def test_error_statistics_by_hand():
    s = M.error_statistics(np.array([3.0, 4.0]))
    assert s.rmse == pytest.approx(math.sqrt(12.5))
    assert s.mean == pytest.approx(3.5)
    assert s.median == pytest.approx(3.5)
    assert s.std == pytest.approx(0.5)  # population std, as evo
    assert (s.min, s.max, s.sse, s.n) == (3.0, 4.0, 25.0, 2)
    with pytest.raises(ValueError):
        M.error_statistics(np.array([]))


# ---------------------------------------------------------------- ATE, hand-made


def test_ate_constant_offset():
    ref = random_walk(np.random.default_rng(0), 200)
    est = ref + np.array([0.3, -0.4, 0.0])
    none = M.ate(est, ref, "none")
    np.testing.assert_allclose(none.errors, 0.5, atol=1e-12)
    for v in (none.rmse, none.mean, none.median, none.max, none.min):
        assert v == pytest.approx(0.5, abs=1e-12)
    assert none.std == pytest.approx(0.0, abs=1e-12)
    assert M.ate(est, ref, "se2").rmse == pytest.approx(0.0, abs=1e-9)
    assert M.ate(est, ref, "first").rmse == pytest.approx(0.0, abs=1e-9)


def test_ate_rotation_about_origin_by_hand():
    # rotating (1, 0) and (0, 2) by 90° moves them by sqrt(2)*|p|
    ref = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    est = compose(np.array([0.0, 0.0, np.pi / 2]), ref)
    res = M.ate(est, ref, "none")
    np.testing.assert_allclose(res.errors, [math.sqrt(2), 2 * math.sqrt(2)])
    assert res.rmse == pytest.approx(math.sqrt((2 + 8) / 2))
    assert M.ate(est, ref, "se2").rmse == pytest.approx(0.0, abs=1e-12)


def test_ate_known_rigid_motion_of_whole_path():
    # circle of radius r around c; the whole path is rotated by theta about c,
    # i.e. a rotation plus the translation c - R c: every point moves by the
    # chord 2 r sin(theta / 2).
    r, c, theta = 5.0, np.array([2.0, 1.0]), 0.6
    s = np.linspace(0, 1.8 * np.pi, 300)
    ref = np.c_[c[0] + r * np.cos(s), c[1] + r * np.sin(s), wrap_angle(s + np.pi / 2)]
    rc = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]]) @ c
    T = np.array([c[0] - rc[0], c[1] - rc[1], theta])
    est = compose(T, ref)
    none = M.ate(est, ref, "none")
    np.testing.assert_allclose(none.errors, 2 * r * math.sin(theta / 2), atol=1e-12)
    se2 = M.ate(est, ref, "se2")
    assert se2.rmse == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(M.align_se2(est[:, :2], ref[:, :2]), inverse(T), atol=1e-12)
    np.testing.assert_allclose(se2.est_aligned, ref, atol=1e-9)
    assert M.ate(est, ref, "first").rmse == pytest.approx(0.0, abs=1e-9)


def test_align_first_pose_maps_first_pose():
    rng = np.random.default_rng(3)
    ref, est = random_walk(rng, 50), random_walk(rng, 50)
    T = M.align_first_pose(est, ref)
    np.testing.assert_allclose(compose(T, est[0]), ref[0], atol=1e-12)
    assert M.ate(est, ref, "first").errors[0] == pytest.approx(0.0, abs=1e-12)


def test_align_se2_straight_line_and_mirror():
    # collinear data: rotation still determined in 2-D (evo's 3-D Umeyama refuses it)
    line = straight_line(50, 0.5)
    T = np.array([1.0, 2.0, 0.5])
    assert M.ate(compose(T, line), line, "se2").rmse == pytest.approx(0.0, abs=1e-9)
    # a mirrored path cannot be rigidly aligned: SE(2) keeps det(R) = +1
    ref = random_walk(np.random.default_rng(4), 300)
    mirrored = ref * np.array([1.0, -1.0, -1.0])
    assert M.ate(mirrored, ref, "se2").rmse > 0.1
    with pytest.raises(ValueError):
        M.align_se2(np.ones((5, 2)), np.zeros((5, 2)))


@pytest.mark.parametrize("alignment", ["none", "se2"])
def test_ate_gaussian_noise_is_sigma_sqrt2(alignment):
    # i.i.d. N(0, sigma^2) on x and y: the error is Rayleigh(sigma):
    # E[e^2] = 2 sigma^2, E[e] = sigma sqrt(pi/2), median = sigma sqrt(2 ln 2).
    rng = np.random.default_rng(5)
    sigma, n = 0.05, 20000
    ref = random_walk(rng, n)
    est = ref.copy()
    est[:, :2] += sigma * rng.standard_normal((n, 2))
    res = M.ate(est, ref, alignment)
    assert res.rmse == pytest.approx(sigma * math.sqrt(2), rel=0.02)
    assert res.mean == pytest.approx(sigma * math.sqrt(math.pi / 2), rel=0.02)
    assert res.median == pytest.approx(sigma * math.sqrt(2 * math.log(2)), rel=0.03)


# ---------------------------------------------------------------- RPE, hand-made


@pytest.mark.parametrize("delta", [1.0, 10.0])
def test_rpe_linear_scale_drift(delta):
    # est overestimates distance by a factor (1 + k) on a straight line: every
    # pair spanning L metres is off by k L, i.e. 100 k % of distance, 0° yaw.
    k = 0.03
    ref = straight_line(801, 0.125)  # 100 m in steps that sum exactly
    est = ref * np.array([1.0 + k, 1.0, 1.0])
    res = M.rpe(est, ref, delta)
    per = int(delta / 0.125)
    np.testing.assert_array_equal(res.pairs[:, 0], np.arange(0, 800 - per + 1, per))
    np.testing.assert_array_equal(res.pairs[:, 1] - res.pairs[:, 0], per)
    np.testing.assert_allclose(res.path_lengths, delta)
    np.testing.assert_allclose(res.trans_errors, k * delta, rtol=1e-9)
    assert res.trans.rmse == pytest.approx(k * delta, rel=1e-9)
    assert res.trans_pct.mean == pytest.approx(100 * k, rel=1e-9)
    assert res.rot_deg.max == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("delta", [1.0, 10.0])
def test_rpe_linear_heading_drift(delta):
    # ref drives straight along x; est has a constant heading drift kappa
    # rad/m, so it drives on an arc of radius 1/kappa. Over a pair of L m the
    # estimated relative pose is (sin(kL)/k, (1 - cos(kL))/k, kL) against
    # (L, 0, 0): error translation and yaw follow in closed form.
    kappa = 0.01
    ref = straight_line(801, 0.125)
    s = ref[:, 0]
    est = np.c_[np.sin(kappa * s) / kappa, (1 - np.cos(kappa * s)) / kappa, kappa * s]
    res = M.rpe(est, ref, delta)
    L = delta
    expected_t = math.hypot(math.sin(kappa * L) / kappa - L, (1 - math.cos(kappa * L)) / kappa)
    np.testing.assert_allclose(res.trans_errors, expected_t, rtol=1e-6)
    assert res.trans_pct.mean == pytest.approx(100 * expected_t / L, rel=1e-6)
    np.testing.assert_allclose(res.rot_errors_deg, math.degrees(kappa * L), rtol=1e-9)
    assert res.rot_deg_per_m.mean == pytest.approx(math.degrees(kappa), rel=1e-9)


def test_rpe_pairs_from_estimate_and_errors():
    ref = straight_line(801, 0.125)
    est = ref * np.array([2.0, 1.0, 1.0])  # estimate travels twice as far
    assert M.rpe(est, ref, 1.0, pairs_from="estimate").pairs[0].tolist() == [0, 4]
    assert M.rpe(est, ref, 1.0, pairs_from="reference").pairs[0].tolist() == [0, 8]
    with pytest.raises(ValueError):
        M.rpe(est, ref, 1000.0)  # no pair spans 1 km
    with pytest.raises(ValueError):
        M.rpe(est, ref, 1.0, delta_unit="frames")
    with pytest.raises(ValueError):
        M.rpe(est[:-1], ref, 1.0)


def test_path_pairs_float_accumulation_by_hand():
    # ten exact 0.1 m steps add up to 0.9999999999999999 < 1 in floating point,
    # so evo's accumulator only closes a 1 m pair after eleven steps
    assert sum([0.1] * 10) < 1.0 <= sum([0.1] * 11)
    pairs = M.path_pairs(zigzag(200, 0.1), 1.0)
    assert pairs[:3].tolist() == [[0, 11], [11, 22], [22, 33]]


# ---------------------------------------------------------------- association, hand-made


def test_interpolate_reference_by_hand():
    t_ref = np.arange(0.0, 2.0, 0.02)
    ref = np.c_[3.0 * t_ref, -t_ref, wrap_angle(np.pi - 0.1 + 0.2 * t_ref)]  # crosses ±pi
    t_est = np.array([-0.1, 0.05, 0.5, 0.999, 1.98, 3.0])
    ie, r = M.interpolate_reference(t_est, t_ref, ref)
    assert ie.tolist() == [1, 2, 3, 4]
    tt = t_est[ie]
    np.testing.assert_allclose(r[:, :2], np.c_[3.0 * tt, -tt], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(r[:, 2] - (np.pi - 0.1 + 0.2 * tt)), 0.0, atol=1e-12)
    # a ground-truth dropout between 0.4 s and 0.6 s
    keep = (t_ref < 0.4) | (t_ref > 0.6)
    ie2, _ = M.interpolate_reference(t_est, t_ref[keep], ref[keep], max_gap=0.05)
    assert ie2.tolist() == [1, 3, 4]


# ---------------------------------------------------------------- feature lengths (paper)

TRUE_MM = [2344, 6775, 6686, 1064, 8094, 1029, 7901, 26681, 25534]
TABLE2_MM = [2409, 7438, 7407, 1092, 7369, 1012, 8837, 25967, 24679]
TABLE3_MM = [2366, 7081, 7115, 1039, 8607, 1047, 8411, 26266, 25021]


def test_feature_length_errors_reproduce_paper_tables():
    t = np.array(TRUE_MM) / 1000.0
    rec2 = M.feature_length_errors(t, np.array(TABLE2_MM) / 1000.0)
    rec3 = M.feature_length_errors(t, np.array(TABLE3_MM) / 1000.0)
    assert rec2[0].abs_error_m == pytest.approx(0.065)
    assert rec2[0].rel_error_pct == pytest.approx(100 * 65 / 2344)
    avg2 = M.mean_relative_error_pct(rec2)
    avg3 = M.mean_relative_error_pct(rec3)
    # published averages (4 decimals; Table 3's 3.59199 is printed truncated)
    assert avg2 == pytest.approx(6.0505, abs=1e-4)
    assert avg3 == pytest.approx(3.5919, abs=1e-4)
    assert M.relative_reduction_pct(avg2, avg3) == pytest.approx(40.6, abs=0.05)
    assert M.relative_reduction_pct(6.0505, 3.5919) == pytest.approx(40.6, abs=0.05)


# ---------------------------------------------------------------- cross-check with evo

STATS = ("rmse", "mean", "median", "max", "min", "std")


def to_evo(t: np.ndarray, poses: np.ndarray) -> PoseTrajectory3D:
    z = np.zeros(len(poses))
    quat_wxyz = np.c_[np.cos(poses[:, 2] / 2), z, z, np.sin(poses[:, 2] / 2)]
    return PoseTrajectory3D(np.c_[poses[:, 0], poses[:, 1], z], quat_wxyz, np.asarray(t, float))


def evo_yaw(traj: PoseTrajectory3D) -> np.ndarray:
    q = traj.orientations_quat_wxyz
    return 2 * np.arctan2(q[:, 3], q[:, 0])


@pytest.fixture(params=[11, 22, 33])
def walk_pair(request):
    rng = np.random.default_rng(request.param)
    ref = random_walk(rng, 800)  # ~80 m at 10 Hz
    est = drifting_estimate(rng, ref, np.array([5.0, -3.0, 1.0]))  # other world frame
    t = np.arange(len(ref)) * 0.1
    return t, est, ref


@needs_evo
@pytest.mark.parametrize("alignment", ["none", "se2", "first"])
def test_ate_matches_evo(walk_pair, alignment):
    t, est, ref = walk_pair
    traj_ref, traj_est = to_evo(t, ref), to_evo(t, est)
    if alignment == "se2":
        traj_est.align(traj_ref, correct_scale=False)
    elif alignment == "first":
        traj_est.align_origin(traj_ref)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    expected = ape.get_all_statistics()
    ours = M.ate(est, ref, alignment)
    for k in STATS:
        assert getattr(ours, k) == pytest.approx(expected[k], abs=1e-6), k
    np.testing.assert_allclose(ours.errors, ape.error, atol=1e-6)


@needs_evo
@pytest.mark.parametrize("delta", [1.0, 10.0])
@pytest.mark.parametrize("pairs_from", ["reference", "estimate"])
def test_rpe_matches_evo(walk_pair, delta, pairs_from):
    t, est, ref = walk_pair
    traj_ref, traj_est = to_evo(t, ref), to_evo(t, est)
    ours = M.rpe(est, ref, delta, pairs_from=pairs_from)
    for relation, mine in (
        (evo_metrics.PoseRelation.translation_part, ours.trans),
        (evo_metrics.PoseRelation.rotation_angle_deg, ours.rot_deg),
    ):
        r = evo_metrics.RPE(
            relation,
            delta=delta,
            delta_unit=evo_metrics.Unit.meters,
            all_pairs=False,
            pairs_from_reference=(pairs_from == "reference"),
        )
        r.process_data((traj_ref, traj_est))
        assert r.delta_ids == ours.pairs[:, 1].tolist()
        expected = r.get_all_statistics()
        for k in STATS:
            assert getattr(mine, k) == pytest.approx(expected[k], abs=1e-6), (relation, k)


@needs_evo
def test_path_pairs_match_evo_on_float_boundaries():
    # evo's accumulator restarts at 0 at every pair start; a running total
    # over the whole path (cum[j] - cum[i]) rounds differently on these paths
    # and picks different pairs, ours must agree with evo index for index.
    paths = [zigzag(1001, 0.1), zigzag(1001, 0.3), zigzag(300, 0.7)]
    paths += [straight_line(2001, 0.1), straight_line(500, 0.2 / 3)]
    for poses in paths:
        se3 = to_evo(np.arange(len(poses)), poses).poses_se3
        for delta in (0.3, 0.7, 1.0, 2.0, 2.1, 3.0, 7.0):
            expected = evo_filters.filter_pairs_by_path(se3, delta, 0.0, all_pairs=False)
            assert M.path_pairs(poses, delta).tolist() == [list(p) for p in expected]


def _stamps(rng):
    t_ref = np.sort(np.arange(0.0, 60.0, 0.02) + 0.002 * rng.standard_normal(3000))  # 50 Hz
    t_est = np.arange(0.3, 61.0, 0.1) + 0.004 * rng.standard_normal(607)  # 10 Hz, overhangs
    return t_est, t_ref


@needs_evo
def test_interpolate_reference_matches_evo_interpolation():
    rng = np.random.default_rng(8)
    t_est, t_ref = _stamps(rng)
    ref = random_walk(rng, t_ref.size, 0.02)
    traj_ref, traj_est = to_evo(t_ref, ref), to_evo(t_est, random_walk(rng, t_est.size))
    r2, e2 = evo_sync.associate_trajectories(
        traj_ref, traj_est, max_diff=0.03, sync_method=SyncMethod.interpolation
    )
    ie, ours = M.interpolate_reference(t_est, t_ref, ref)
    # evo also keeps (clamped) stamps just past the reference's end; compare the common ones
    common = np.isin(e2.timestamps, t_est[ie])
    assert common.sum() == ie.size >= e2.timestamps.size - 2
    np.testing.assert_allclose(ours[:, :2], r2.positions_xyz[common, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(ours[:, 2] - evo_yaw(r2)[common]), 0.0, atol=1e-9)


# ---------------------------------------------------------------- properties

rigid = st.tuples(
    st.floats(-1e3, 1e3, allow_nan=False),
    st.floats(-1e3, 1e3, allow_nan=False),
    st.floats(-math.pi, math.pi, allow_nan=False),
)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), T=rigid)
def test_aligned_ate_invariant_to_rigid_transform_of_estimate(seed, T):
    rng = np.random.default_rng(seed)
    ref = random_walk(rng, 60)
    est = drifting_estimate(rng, ref, ref[0])
    moved = compose(np.array(T), est)
    a, b = M.ate(est, ref, "se2"), M.ate(moved, ref, "se2")
    assert b.rmse == pytest.approx(a.rmse, abs=1e-7)
    np.testing.assert_allclose(b.errors, a.errors, atol=1e-7)
    # RPE needs no alignment at all
    ra, rb = M.rpe(est, ref, 1.0), M.rpe(moved, ref, 1.0)
    assert rb.trans.rmse == pytest.approx(ra.trans.rmse, abs=1e-7)
    # the least-squares alignment is at least as good as the other two
    assert a.rmse <= M.ate(moved, ref, "first").rmse + 1e-9
    assert a.rmse <= M.ate(moved, ref, "none").rmse + 1e-9
