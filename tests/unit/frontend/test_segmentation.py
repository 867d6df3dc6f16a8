"""Doppler segmentation on hand-built scenes with physically computed Doppler."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.egomotion import compensated_velocity, fit_sensor_velocity
from fmcwlog.frontend.segmentation import SegmentationParams, segment_clusters, segment_moving

BEAM = np.deg2rad(0.27)  # ~1000 beams over 270°


def _walls():
    """Points of a 12 x 8 m room ([-4, 8] x [-3, 5]) at one point per beam (lidar frame)."""
    ang = np.arange(-0.75 * np.pi, 0.75 * np.pi, BEAM)
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    with np.errstate(divide="ignore"):
        tx = np.where(u[:, 0] > 0, 8.0 / u[:, 0], -4.0 / u[:, 0])
        ty = np.where(u[:, 1] > 0, 5.0 / u[:, 1], -3.0 / u[:, 1])
    return u * np.minimum(np.abs(tx), np.abs(ty))[:, None]


def _disc_front(centre, radius):
    """Points of a disc's sensor-facing side, one per beam."""
    c = np.asarray(centre, float)
    d = np.hypot(*c)
    half = np.arcsin(radius / d)
    ang = np.arctan2(c[1], c[0]) + np.arange(-half, half, BEAM)[1:]
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    b = u @ c
    t = b - np.sqrt(np.maximum(b**2 - (d**2 - radius**2), 0.0))  # nearest intersection
    return u * t[:, None]


def _segment_x(x, y0, y1):
    """Points of the segment x = const, y in [y0, y1], one per beam."""
    ang = np.arange(np.arctan2(y0, x), np.arctan2(y1, x), BEAM)
    return np.stack([np.full(ang.shape, x), x * np.tan(ang)], -1)


def _scene(v_sensor, rng):
    """Static room + radial walker + tangential cart + walker beside a wall.

    Returns xy, quantised raw Doppler v_r, and an id per point:
    0 wall, 1 radial walker, 2 tangential cart, 3 walker beside the wall.
    Object velocities are world velocities in lidar axes (sensor yaw fixed).
    """
    parts = [
        (_walls(), np.zeros(2), 0),
        (_disc_front((4.0, 1.0), 0.2), np.array([1.2, 0.1]), 1),
        (_segment_x(1.5, -0.6, 0.6), np.array([0.0, 1.5]), 2),
        (_disc_front((7.4, -1.0), 0.2), np.array([-1.0, 0.0]), 3),  # 0.4 m gap to wall x = 8
    ]
    xy = np.concatenate([p for p, _, _ in parts])
    vel = np.concatenate([np.tile(v, (len(p), 1)) for p, v, _ in parts])
    ids = np.concatenate([np.full(len(p), i) for p, _, i in parts])
    u = xy / np.hypot(*xy.T)[:, None]
    v_r = np.sum(u * (vel - v_sensor), axis=1)  # range rate of a moving point
    v_r = np.round((v_r + rng.normal(0, 0.01, v_r.shape)) / 0.1) * 0.1
    return xy, v_r, ids


def test_moving_robot_compensated_works_raw_fails():
    rng = np.random.default_rng(0)
    v_sensor = np.array([1.5, 0.2])
    xy, v_r, ids = _scene(v_sensor, rng)
    fit = fit_sensor_velocity(xy, v_r, random_state=0)
    assert np.allclose(fit.v_sensor, v_sensor, atol=0.01)
    eps = compensated_velocity(xy, v_r, fit.v_sensor)
    moving = segment_moving(xy, eps)
    static = ids == 0
    assert moving[static].mean() < 0.005
    for i in (1, 2, 3):
        assert moving[ids == i].all(), i
    # the cart is carried by its clearly moving half: per point, about half of it
    # shows no Doppler at all
    cart = ids == 2
    assert 0.3 < (np.abs(eps[cart]) < 0.3).mean() < 0.7
    # eq. 18 on the raw Doppler (paper): the static room "moves" with the robot
    raw = segment_moving(xy, v_r)
    assert raw[static].mean() > 0.5


def test_standing_robot_raw_and_compensated_agree():
    rng = np.random.default_rng(1)
    xy, v_r, ids = _scene(np.zeros(2), rng)
    fit = fit_sensor_velocity(xy, v_r, random_state=0)
    eps = compensated_velocity(xy, v_r, fit.v_sensor)
    comp = segment_moving(xy, eps)
    raw = segment_moving(xy, v_r)
    np.testing.assert_array_equal(comp, raw)
    np.testing.assert_array_equal(comp, ids != 0)


def test_velocity_term_of_eq17_keeps_a_post_beside_a_walker_static():
    # A thin static post 0.15 m from a radially moving walker. Without the velocity
    # term (α = 0) DBSCAN merges them and the walker's majority drags the post
    # along; with α = 1 s² the 1 m/s difference separates them.
    post = _disc_front((3.0, 0.0), 0.05)
    walker = _disc_front((3.0, 0.45), 0.25)
    xy = np.concatenate([post, walker])
    eps = np.concatenate([np.zeros(len(post)), np.full(len(walker), 1.0)])
    is_post = np.arange(len(xy)) < len(post)
    assert len(post) >= 5 and len(walker) > 3 * len(post)
    with_v = segment_moving(xy, eps, SegmentationParams(alpha=1.0))
    without_v = segment_moving(xy, eps, SegmentationParams(alpha=0.0))
    assert not with_v[is_post].any() and with_v[~is_post].all()
    assert without_v[is_post].all()


def test_median_rule_misses_the_tangential_cart():
    # the same cart judged with min_moving_fraction = 0.5 ("median |ε| ≥ v_th") and
    # no per-point override loses its central points: the default 0.3 is deliberate
    cart = _segment_x(1.5, -0.6, 0.6)
    eps = 1.5 * cart[:, 1] / np.hypot(*cart.T)  # u·V for V = (0, 1.5), static sensor
    strict = SegmentationParams(min_moving_fraction=0.5, keep_strong_points=False)
    assert not segment_moving(cart, eps, strict).any()
    assert segment_moving(cart, eps).all()


def test_noise_points_judged_individually_and_empty_input():
    xy = np.array([[1.0, 0.0], [0.0, 5.0], [-3.0, 0.0]])  # far apart: all DBSCAN noise
    eps = np.array([0.5, 0.1, -0.4])
    np.testing.assert_array_equal(segment_moving(xy, eps), [True, False, True])
    assert segment_moving(np.zeros((0, 2)), np.zeros(0)).shape == (0,)


def test_dbscan_labels_are_sklearns():
    """The DBSCAN used here numbers clusters, borders and noise exactly as sklearn's does (a second
    implementation): on the scene's (x, y, ε) points, on random clouds with ties, chains and lone points."""
    from sklearn.cluster import DBSCAN

    from fmcwlog.frontend.segmentation import dbscan

    rng = np.random.default_rng(3)
    xy, v_r, _ = _scene(np.array([1.0, 0.0]), rng)
    ego = fit_sensor_velocity(xy, v_r)
    clouds = [np.column_stack([xy, compensated_velocity(xy, v_r, ego.v_sensor)])]
    for n in (0, 1, 7, 200, 1500):
        pts = rng.uniform(0, 6, (n, 3))
        pts[: n // 3] = np.round(pts[: n // 3] * 4) / 4  # repeated points and exact-eps spacings
        clouds.append(pts)
    clouds.append(np.column_stack([np.arange(100) * 0.3, np.zeros(100), np.zeros(100)]))  # a chain at exactly eps
    for pts in clouds:
        for eps, min_samples in ((0.3, 5), (0.5, 3), (0.25, 1), (1.0, 12)):
            want = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(pts) if len(pts) else np.zeros(0, int)
            np.testing.assert_array_equal(dbscan(pts, eps, min_samples), want)


def test_seed_points_are_seeds():
    """Points of the sweep given as ``seed_points`` cluster exactly as the same points given as ``seeds``."""
    rng = np.random.default_rng(5)
    xy = np.concatenate([rng.uniform(-15, 15, (600, 2)), rng.normal([4.0, 2.0], 0.2, (40, 2))])
    eps = np.concatenate([rng.normal(0, 0.03, 600), rng.normal(0.0, 0.05, 40)])  # a mover showing no Doppler
    eps[:30] = 0.8  # some movers that do
    mask = np.zeros(len(xy), bool)
    mask[600:605] = True
    extra = np.array([[-3.0, 7.0]])
    a = segment_clusters(xy, eps, seeds=np.concatenate([extra, xy[mask]]))
    b = segment_clusters(xy, eps, seeds=extra, seed_points=mask)
    assert a.clustered[600:].all()  # the seeds brought the silent mover in
    assert np.array_equal(a.labels, b.labels) and np.array_equal(a.clustered, b.clustered)
    assert np.array_equal(a.moving, b.moving)


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 60), edges=st.lists(st.tuples(st.integers(0, 59), st.integers(0, 59)), max_size=150))
def test_lowest_connected_is_the_lowest_node_of_each_component(n, edges):
    """Any graph (self-loops, repeated edges, either order, isolated nodes): each node gets the lowest
    node of its component, the components being scipy's (an independent labelling, not the one the
    fast one replaced)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from fmcwlog.frontend.segmentation import _lowest_connected

    e = np.array([(a % n, b % n) for a, b in edges], np.intp).reshape(-1, 2)
    got = _lowest_connected(n, e[:, 0], e[:, 1])
    _, comp = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    lowest = np.full(comp.max() + 1, n)
    np.minimum.at(lowest, comp, np.arange(n))
    np.testing.assert_array_equal(got, lowest[comp])
