"""The back end's parts against known geometry: a known offset between two views of one scene, a
corridor that leaves its axis free, a periodic scene that cannot tell two places apart, a square
loop whose drift one true closure removes (and a false one under the Cauchy kernel does not bend),
local edges that undo a front end's sideways bias along a corridor, the local map's window of
recent keyframes, and the point-to-line ICP against a second solver (scipy's ``least_squares``) and
its pairing against a KD-tree asked afresh at every step.

Every scene is drawn here from wall segments, and every expected pose is the transform the test
applied, not a figure the code produced.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fmcwlog.backend.graph import Edge, PoseGraph
from fmcwlog.backend.keyframes import Node
from fmcwlog.backend.local_edges import LocalMatcher
from fmcwlog.backend.params import BackendParams
from fmcwlog.backend.registration import LineICPParams, build_submap, register_point_to_line
from fmcwlog.backend.verification import leave_free, verify
from fmcwlog.frontend.keyframe_map import KeyframeMap, LocalMapParams
from fmcwlog.geometry import between, compose, inverse, transform_points, wrap_angle
from fmcwlog.kernels.correlative import CorrelativeParams, correlative_match, grid_for
from fmcwlog.kernels.nearest import NearestPairs


def _walls(segments: list[tuple[float, float, float, float]], spacing: float = 0.03) -> np.ndarray:
    """Points every ``spacing`` m along each segment (x1, y1, x2, y2)."""
    parts = []
    for x1, y1, x2, y2 in segments:
        n = max(int(np.hypot(x2 - x1, y2 - y1) / spacing), 2)
        s = np.linspace(0.0, 1.0, n)[:, None]
        parts.append(np.array([x1, y1]) + s * np.array([x2 - x1, y2 - y1]))
    return np.concatenate(parts)


def _room() -> np.ndarray:
    """An 8 m x 6 m room with a pillar and a recess: nothing in it repeats."""
    return _walls([(-4, -3, 4, -3), (4, -3, 4, 3), (4, 3, -1, 3), (-1, 3, -1, 3.5), (-1, 3.5, -2, 3.5),
                   (-2, 3.5, -2, 3), (-2, 3, -4, 3), (-4, 3, -4, -3),
                   (1, 0, 1.4, 0), (1.4, 0, 1.4, 0.6), (1.4, 0.6, 1, 0.6), (1, 0.6, 1, 0)])


def _seen_from(scene: np.ndarray, pose: np.ndarray, rng: np.random.Generator, sigma: float = 0.01) -> np.ndarray:
    """The scene's points in the frame of ``pose``, with range-like noise, every other point."""
    pts = transform_points(inverse(pose), scene[::2])
    return pts + rng.normal(0.0, sigma, pts.shape)


def test_correlative_search_finds_a_known_offset_far_outside_an_icp_basin():
    rng = np.random.default_rng(0)
    scene = _room()
    truth = np.array([0.35, -0.25, np.radians(7.0)])
    source = _seen_from(scene, truth, rng)
    p = CorrelativeParams(linear_window=0.5, angular_window_deg=10.0)
    found = correlative_match(grid_for(scene, p), source, np.zeros(3), p)
    assert np.hypot(*(found.pose[:2] - truth[:2])) <= 1.5 * p.resolution
    assert abs(wrap_angle(found.pose[2] - truth[2])) <= np.radians(1.0)
    assert found.score > 0.8
    assert found.second_score < 0.9 * found.score  # the room is not ambiguous


def test_point_to_line_icp_agrees_with_least_squares_under_the_same_cauchy_loss():
    """The ICP's pose is the minimum of the Cauchy cost of its final pairs, as a second solver finds
    it (scipy's ``least_squares``, loss ``cauchy``, from the ICP's starting pose, with those pairs
    held); its ``hessian`` is ``JᵀWJ`` with a Jacobian by finite differences; and it lies near the
    pose the test applied. The normals of the walls' points are the walls' own."""
    from scipy.optimize import least_squares
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    scene = _room()
    p = LineICPParams()
    sub = build_submap(scene, p)
    horizontal = np.abs(scene[:, 1] - np.round(scene[:, 1] * 2) / 2) < 1e-9  # on y = -3, 0, 3, 3.5
    away = np.all(np.abs(scene[:, None, 0] - np.array([-4, -2, -1, 1, 1.4, 4])) > 0.1, axis=1)  # off every vertical wall and corner
    assert np.all(np.abs(sub.normals[horizontal & away & sub.has_normal, 1]) > 0.999)
    assert (horizontal & away & sub.has_normal).sum() > 300
    truth = np.array([0.3, -0.2, np.radians(4.0)])
    source = _seen_from(scene, truth, rng, sigma=0.005)
    initial = truth + np.array([0.06, -0.05, np.radians(2.0)])
    icp = register_point_to_line(source, sub, initial, p)
    assert icp.converged and icp.pairs > 300
    assert np.hypot(*(icp.pose[:2] - truth[:2])) < 0.001 and abs(wrap_angle(icp.pose[2] - truth[2])) < np.radians(0.03)

    # the final pairs, found here with a tree of our own
    dist, idx = cKDTree(scene).query(transform_points(icp.pose, source), distance_upper_bound=p.max_distance)
    ok = np.isfinite(dist)
    ok[ok] = sub.has_normal[idx[ok]]
    src, q, n = source[ok], scene[idx[ok]], sub.normals[idx[ok]]
    assert ok.sum() == icp.pairs

    def residuals(x: np.ndarray) -> np.ndarray:
        return np.sum(n * (transform_points(x, src) - q), axis=1)

    ref = least_squares(residuals, initial, loss="cauchy", f_scale=p.kernel_scale, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    # the ICP stops on a step under its tolerance (1e-4): 1-2e-7 from the minimum on seeds 3-5
    assert np.allclose(icp.pose[:2], ref.x[:2], atol=4e-7) and abs(wrap_angle(icp.pose[2] - ref.x[2])) < 4e-7
    np.testing.assert_allclose(icp.residuals, residuals(icp.pose), atol=1e-12)
    step = 1e-7
    jac = np.stack([(residuals(icp.pose + step * e) - residuals(icp.pose - step * e)) / (2 * step) for e in np.eye(3)], 1)
    w = 1.0 / (1.0 + (residuals(icp.pose) / p.kernel_scale) ** 2)
    np.testing.assert_allclose(icp.hessian, (jac * w[:, None]).T @ jac, rtol=1e-8)


@pytest.mark.parametrize("targets", ["room", "three points"])
def test_the_icps_pairing_is_the_kd_trees_at_every_step_of_a_random_walk(targets):
    """The ICP keeps each point's nearest targets between KD-tree queries; at every pose of a random
    walk (steps from 10 µm to 20 cm, turns to 3°) it must pair every point as the tree asked afresh
    does: points on the walls, midway between two wall points, in the open, far outside. (The pairing
    is the front end's ``NearestPairs``, which the back end shares.)"""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(7)
    scene = _room() if targets == "room" else np.array([[0.0, 0.0], [0.05, 0.0], [1.0, 1.0]])
    sub = build_submap(scene)
    midway = 0.5 * (scene[:-1] + scene[1:])
    source = np.concatenate([scene[::3] + rng.normal(0, 0.01, scene[::3].shape), midway[::5],
                             rng.uniform(-5, 5, (200, 2)), rng.uniform(-50, 50, (20, 2))])
    nearest, tree = NearestPairs(source, sub.tree, sub.points, 0.3), cKDTree(scene)
    pose = np.zeros(3)
    for step in range(300):
        size = 10.0 ** rng.uniform(-5, np.log10(0.2))
        pose = pose + np.array([*rng.normal(0, size, 2), rng.normal(0, np.radians(3.0) * size / 0.2)])
        moved = transform_points(pose, source)
        got_moved, idx, dist = nearest.nearest(pose)
        want_d, want = tree.query(moved, k=1, distance_upper_bound=0.3)
        assert np.array_equal(got_moved, moved), step
        paired = dist < 0.3
        assert np.array_equal(paired, want < len(scene)), step
        # the same target point (a corner given twice may come back as either copy) at the same distance
        assert np.array_equal(scene[idx[paired]], scene[want[paired]]), step
        assert np.array_equal(dist[paired], want_d[paired]), step


def test_a_closure_in_a_room_is_verified_at_the_true_relative_pose():
    rng = np.random.default_rng(1)
    scene = _room()
    truth = np.array([0.8, 0.4, np.radians(-12.0)])
    query = _seen_from(scene, truth, rng)
    prior = truth + np.array([0.6, -0.5, np.radians(8.0)])  # drift between the loop's two ends
    v = verify(query, scene, prior, BackendParams())
    assert v.accepted, v.reason
    assert v.relative is not None and v.covariance is not None
    assert np.hypot(*(v.relative[:2] - truth[:2])) < 0.02
    assert abs(wrap_angle(v.relative[2] - truth[2])) < np.radians(0.3)
    assert v.free_directions == 0
    assert np.all(np.linalg.eigvalsh(v.covariance) > 0)


def test_a_bare_corridor_is_closed_across_and_left_free_along_its_axis():
    rng = np.random.default_rng(2)
    scene = _walls([(-20, -1.25, 20, -1.25), (-20, 1.25, 20, 1.25)])
    truth = np.array([0.5, 0.15, np.radians(3.0)])
    query = _seen_from(scene[np.abs(scene[:, 0]) < 12], truth, rng)
    prior = truth + np.array([0.7, 0.2, np.radians(-4.0)])
    v = verify(query, scene, prior, BackendParams())
    assert v.accepted, v.reason
    assert v.free_directions == 1
    assert v.relative is not None and v.covariance is not None
    assert abs(v.relative[1] - truth[1]) < 0.02  # across: fixed by the walls
    assert abs(wrap_angle(v.relative[2] - truth[2])) < np.radians(0.3)
    # along: what the scene cannot tell is left to the graph, not asserted by the closure
    assert v.covariance[0, 0] > 100 * v.covariance[1, 1]


def _line_information(points: np.ndarray, normal: tuple[float, float]) -> np.ndarray:
    """``JᵀJ`` over (x, y, yaw about the origin) of point-to-line residuals ``nᵀ(R p + t - q)`` at
    ``points`` (N, 2) on lines of unit ``normal``: written out here, not taken from the code."""
    n = np.broadcast_to(np.asarray(normal, float), points.shape)
    j = np.column_stack([n[:, 0], n[:, 1], -n[:, 0] * points[:, 1] + n[:, 1] * points[:, 0]])
    return j.T @ j


def test_a_corridor_closure_leaves_a_pure_slide_free_and_a_door_jamb_tells_no_yaw_along_it():
    # two walls along x (3 m apart, 30 m seen) and one door jamb 6 m ahead, off to the left: the
    # jamb alone gives a little information along the axis, coupled with the yaw by its lever
    x = np.linspace(-15.0, 15.0, 600)
    walls = _line_information(np.column_stack([np.r_[x, x], np.r_[np.full_like(x, -1.5), np.full_like(x, 1.5)]]), (0.0, 1.0))
    jamb_y = np.linspace(1.5, 2.1, 12)
    jamb = _line_information(np.column_stack([np.full_like(jamb_y, 6.0), jamb_y]), (1.0, 0.0))
    kept, free = leave_free(walls + jamb)
    assert free.shape[1] == 1
    # sliding along the corridor turns nothing: what is left free is a pure translation along x
    assert abs(abs(free[0, 0]) - 1.0) < 1e-9 and abs(free[2, 0]) < 1e-9
    assert np.allclose(kept @ np.array([1.0, 0.0, 0.0]), 0.0, atol=1e-6)
    # with the position along the axis unknown, the jamb tells the yaw only through the spread of
    # its own points along its length; the walls tell the rest, and nothing is lost across
    spread = float(np.sum((jamb_y - jamb_y.mean()) ** 2))
    assert kept[1, 1] == pytest.approx(walls[1, 1], rel=1e-9)
    assert kept[2, 2] == pytest.approx(walls[2, 2] + spread, rel=1e-9)
    assert abs(kept[1, 2]) < 1e-6 * kept[2, 2]


def test_a_periodic_row_of_pillars_is_rejected_as_ambiguous():
    rng = np.random.default_rng(3)
    segs = [(-14, -1.5, 14, -1.5), (-14, 1.5, 14, 1.5)]
    for k in range(-13, 14):  # a pillar every metre on each wall: shifting by 1 m looks the same
        for y0, d in ((-1.5, 0.2), (1.5, -0.2)):
            segs += [(k, y0, k, y0 + d), (k, y0 + d, k + 0.2, y0 + d), (k + 0.2, y0 + d, k + 0.2, y0)]
    scene = _walls(segs)
    truth = np.array([0.3, 0.0, 0.0])
    query = _seen_from(scene[np.abs(scene[:, 0]) < 5], truth, rng)
    v = verify(query, scene, truth + np.array([0.4, 0.05, 0.0]), BackendParams())
    assert not v.accepted
    assert v.test == "ambiguity"


def _square_loop(side: float = 10.0, step: float = 1.0) -> np.ndarray:
    """True poses every ``step`` m around a square, counter-clockwise, back to the start."""
    poses, pose = [np.zeros(3)], np.zeros(3)
    for _ in range(4):
        for i in range(int(side / step)):
            turn = np.pi / 2 if i == int(side / step) - 1 else 0.0
            pose = compose(pose, np.array([step, 0.0, turn]))
            poses.append(pose)
    return np.array(poses)


def _drifting_graph(truth: np.ndarray, cauchy_scale: float, initial: np.ndarray | None = None) -> PoseGraph:
    """Odometry with a yaw bias of 1° per metre; the nodes start at ``initial``, else at the
    odometry integrated."""
    g = PoseGraph(cauchy_scale)
    est = truth[0]
    g.add_node(est if initial is None else initial[0])
    cov = np.diag([0.02**2, 0.02**2, 0.01**2])
    for i in range(1, len(truth)):
        rel = between(truth[i - 1], truth[i]) + np.array([0.0, 0.0, np.radians(1.0)])
        est = compose(est, rel)
        g.add_node(est if initial is None else initial[i])
        g.add_odometry(Edge(i - 1, i, rel, cov))
    return g


def _position_errors(g: PoseGraph, truth: np.ndarray) -> np.ndarray:
    return np.hypot(*(g.estimates()[:, :2] - truth[:, :2]).T)


def test_one_true_closure_removes_the_drift_of_a_loop_and_a_false_one_is_down_weighted():
    truth = _square_loop()
    last = len(truth) - 1
    closure_cov = np.diag([0.01**2, 0.01**2, 0.002**2])
    true_closure = Edge(0, last, between(truth[0], truth[last]), closure_cov)
    false_closure = Edge(0, 20, np.zeros(3), closure_cov)  # the far corner matched onto the start

    g = _drifting_graph(truth, 1e6)  # a kernel this wide is a Gaussian
    drift = _position_errors(g, truth).max()
    assert drift > 3.0  # 40 m at 1°/m
    g.add_closure(true_closure)
    g.optimize()
    corrected = _position_errors(g, truth).max()
    assert corrected < 0.1 * drift

    # the false closure arrives once the true one has corrected the graph (the pipeline optimises
    # as closures come): under the Cauchy kernel it is outvoted, under a Gaussian it bends the loop
    start = g.estimates()
    robust, gaussian = _drifting_graph(truth, 3.0, start), _drifting_graph(truth, 1e6, start)
    for h in (robust, gaussian):
        h.add_closure(true_closure)
        h.add_closure(false_closure)
        h.optimize()
    assert _position_errors(robust, truth).max() < 2 * corrected + 0.05
    assert _position_errors(gaussian, truth).max() > 1.0
    errors = robust.closure_errors()
    assert errors[0] < 3.0 < errors[1]


def _corridor_nodes(frontend_bias: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, list[Node]]:
    """Nodes every 0.6 m along a 2.5 m corridor with door recesses, each seeing the walls within
    12 m of its true pose; their front-end poses integrate the true steps plus ``frontend_bias``
    (x, y, yaw per step, in the step's frame)."""
    segs = [(-10, -1.25, 40, -1.25), (-10, 1.25, 40, 1.25)]
    for x0 in (1.0, 4.5, 9.0, 12.5, 17.0, 22.0):  # recesses 1 m wide, 0.3 m deep, irregular
        segs += [(x0, -1.25, x0, -1.55), (x0, -1.55, x0 + 1, -1.55), (x0 + 1, -1.55, x0 + 1, -1.25)]
    scene = _walls(segs)
    truth = np.array([[0.6 * i, 0.0, 0.0] for i in range(20)])
    nodes, fe = [], truth[0]
    for i, pose in enumerate(truth):
        if i:
            fe = compose(fe, between(truth[i - 1], pose) + frontend_bias)
        near = np.hypot(*(scene - pose[:2]).T) < 12.0
        nodes.append(Node(i, i, fe.copy(), _seen_from(scene[near], pose, rng).astype(np.float32), None, 0.6 * i))
    return truth, nodes


def test_local_edges_match_each_node_to_the_ones_before_it_without_the_front_ends_sideways_bias():
    truth, nodes = _corridor_nodes(np.array([0.0, 0.003, np.radians(0.05)]), np.random.default_rng(5))
    p = BackendParams()
    matcher = LocalMatcher(p)
    edges = [e for i in range(1, len(nodes)) for e in matcher.edges(nodes[: i + 1])]
    # all but a few (an ICP still sliding along the bare stretches after its 20 iterations; 2 of 70)
    assert len(edges) >= 0.9 * sum(min(i, p.local_links) for i in range(1, len(nodes)))
    assert set(matcher.rejected) <= {"converged"}, matcher.rejected
    for e in edges:
        true = between(truth[e.a], truth[e.b])
        k = e.b - e.a
        assert abs(e.relative[1] - true[1]) < 0.002, e  # the front end is 3 mm per step off across
        assert abs(wrap_angle(e.relative[2] - true[2])) < np.radians(0.03), e  # and 0.05° per step
        # along the corridor only the recesses hold it (measured up to 1.6 cm off), and the edge says so
        assert abs(e.relative[0] - true[0]) < 3 * np.sqrt(e.covariance[0, 0]), e
        assert np.all(np.linalg.eigvalsh(e.covariance) > 0)
        assert e.a >= e.b - p.local_links and k >= 1

    # in the graph, beside the biased front-end edges, they hold the corridor straight
    g = PoseGraph(p.cauchy_scale)
    for n in nodes:
        g.add_node(n.frontend_pose)
    for a, b in zip(nodes[:-1], nodes[1:]):
        g.add_odometry(Edge(a.index, b.index, between(a.frontend_pose, b.frontend_pose), np.diag([0.008**2] * 2 + [0.002**2])))
    before = np.abs(np.array([n.frontend_pose[1] for n in nodes])).max()
    for e in edges:
        g.add_odometry(e)
    g.optimize()
    after = np.abs(g.estimates()[:, 1]).max()
    assert before > 0.1  # the biases' sideways drift over 11 m (measured 14.7 cm)
    assert after < 0.01, (after, before)  # measured 3.6 mm


def test_a_local_match_far_from_the_front_ends_relative_pose_gives_no_edge():
    truth, nodes = _corridor_nodes(np.zeros(3), np.random.default_rng(6))
    nodes[1].frontend_pose = nodes[1].frontend_pose + np.array([0.0, 0.0, np.radians(5.0)])  # beyond the 2° gate
    matcher = LocalMatcher(BackendParams())
    assert matcher.edges(nodes[:2]) == []
    assert matcher.rejected == {"gate": 1}


def test_the_local_map_keeps_only_the_recent_keyframes_and_the_newest_point_per_voxel():
    m = KeyframeMap(0.05, LocalMapParams(window_distance=10.0, max_keyframes=60, min_keyframes=1))
    m.add(np.array([[0.01, 0.01], [100.0, 0.0]]), 0.0)
    m.add(np.array([[0.02, 0.02]]), 1.0)  # the same voxel as the first keyframe's first point
    assert len(m) == 2
    assert np.allclose(sorted(m.points.tolist()), [[0.02, 0.02], [100.0, 0.0]])
    for path in (5.0, 10.0):
        m.add(np.array([[path, 5.0]]), path)
    assert m.keyframes == 4 and [100.0, 0.0] in m.points.tolist()
    m.add(np.array([[11.0, 5.0]]), 11.0)  # 11 m after the first keyframe: it leaves
    assert m.keyframes == 4
    assert [100.0, 0.0] not in m.points.tolist()
    assert m.tree is not None and m.tree.n == len(m.points)
    few = KeyframeMap(0.05, dataclasses.replace(LocalMapParams(), max_keyframes=2, min_keyframes=1))
    for i in range(5):
        few.add(np.array([[float(i), 0.0]]), 0.1 * i)
    assert few.keyframes == 2 and sorted(few.points[:, 0].tolist()) == [3.0, 4.0]


@pytest.mark.parametrize("bad", [{"linear_window": 0.0}, {"levels": 5}, {"coarse_factor": 1}])
def test_search_parameters_outside_their_range_are_refused(bad):
    from fmcwlog.errors import ConfigError

    with pytest.raises(ConfigError, match=next(iter(bad))):
        CorrelativeParams(**bad)


@pytest.fixture(scope="module")
def ring_lap(tmp_path_factory):
    """110 s of the ring (a lap is about 95 s), the improved method with its back end."""
    from helpers import record_scenario

    from fmcwlog.api import ProcessOptions, process

    log = record_scenario(tmp_path_factory, "ring", 110.0)
    out = log.parent / "out"
    process(log, out, ProcessOptions(methods=("improved",)))
    return log, out


@pytest.mark.slow
def test_a_lap_of_the_ring_closes_with_closures_that_agree_with_the_ground_truth(ring_lap):
    import json

    from helpers import ate_rmse, ground_truth, tum

    log, out = ring_lap
    gt = ground_truth(log)
    graph = json.loads((out / "improved_backend.json").read_text())
    kept = [c for c in graph["closures"] if c["accepted"]]
    assert len(kept) >= 10  # measured 24 of 24 verified
    for c in kept:  # each closure's relative pose against the true one between its two stamps
        a, b = (gt[np.argmin(np.abs(gt[:, 0] - c[k] * 1e-9))] for k in ("candidate_stamp_ns", "query_stamp_ns"))
        true = between(np.array([a[1], a[2], a[3]]), np.array([b[1], b[2], b[3]]))
        rel = np.array(c["relative"])
        assert abs(wrap_angle(rel[2] - true[2])) < np.radians(0.2), c  # measured at most 0.08°
        dx, dy = np.abs(rel[:2] - true[:2])
        if c["free_directions"] == 0:
            assert np.hypot(dx, dy) < 0.04, c  # measured at most 1.8 cm
        else:  # along the corridor the closure says nothing (it was off by up to 11 cm); across, it does
            assert min(dx, dy) < 0.03, c  # measured at most 0.8 cm
    with_backend = ate_rmse(tum(out / "improved.tum"), gt)
    alone = ate_rmse(tum(out / "improved_frontend.tum"), gt)
    # measured 0.55 cm (1.4 cm before the local edges), the front end alone 4.1 cm
    assert with_backend < min(alone, 0.012), (with_backend, alone)


@pytest.mark.slow
def test_nodes_points_moved_to_disk_come_back_the_same_and_change_no_result(corridor_log, tmp_path, monkeypatch):
    """A node's points leave memory once no local edge reads them (:class:`PointStore`); closures'
    submaps and the final map read them back. The same sweeps through a back end that keeps every
    node's points in memory give the same result, bit for bit."""
    import json

    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.backend.pipeline import PoseGraphBackend

    seen = []
    add = PoseGraphBackend.add
    monkeypatch.setattr(PoseGraphBackend, "add", lambda self, r: (seen.append(r), add(self, r))[1])
    opts = ProcessOptions(methods=("improved",))
    process(corridor_log, tmp_path / "out", opts)
    monkeypatch.undo()
    mount = np.array(json.loads((tmp_path / "out" / "run.json").read_text())["mount"])
    spilling, kept = (PoseGraphBackend(opts.params.backend, mount, opts.params.map_resolution) for _ in range(2))
    kept._spill = lambda index: None  # type: ignore[method-assign]
    for r in seen:
        spilling.add(r)
        kept.add(r)
    in_memory = [n.index for n in spilling.nodes if n._points is not None]
    assert len(spilling.nodes) > 20 and in_memory == [n.index for n in spilling.nodes[-opts.params.backend.local_links:]]
    for a, b in zip(spilling.nodes, kept.nodes):
        assert a.points.dtype == np.float32 and a.points.tobytes() == b.points.tobytes()
    ra, rb = spilling.finish(), kept.finish()
    assert ra.poses.tobytes() == rb.poses.tobytes() and ra.node_poses.tobytes() == rb.node_poses.tobytes()
    assert [c.relative.tobytes() for c in ra.closures] == [c.relative.tobytes() for c in rb.closures]
    assert ra.grid.log_odds.tobytes() == rb.grid.log_odds.tobytes() and ra.summary() | {"seconds": 0} == rb.summary() | {"seconds": 0}


def test_a_point_store_gives_back_the_bytes_it_was_given_and_takes_only_float32_pairs():
    from fmcwlog.backend.point_store import PointStore

    rng = np.random.default_rng(3)
    store = PointStore()
    arrays = [(rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-3, 4)).astype(np.float32) for n in (0, 1, 7, 500)]
    where = [store.put(a) for a in arrays]
    for a, w in reversed(list(zip(arrays, where))):
        back = store.get(w)
        assert back.dtype == np.float32 and back.shape == a.shape and back.tobytes() == a.tobytes()
    with pytest.raises(ValueError):
        store.put(np.zeros((3, 2)))
    store.close()


def test_a_point_store_that_cannot_write_says_so_in_one_line(monkeypatch, tmp_path):
    """A full temporary folder is an OutputError naming it (the CLI's one line), not a traceback."""
    import errno
    import tempfile

    from fmcwlog.backend.point_store import PointStore
    from fmcwlog.errors import OutputError

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(tempfile, "TemporaryFile", full)
    with pytest.raises(OutputError, match=f"^{tmp_path}: cannot keep fmcwlog's temporary point store") as err:
        PointStore()
    assert "\n" not in str(err.value)


def test_isam2_fed_as_the_pipeline_feeds_it_ends_where_a_batch_solve_and_the_truth_put_the_loop():
    """Two laps of the square with a 1°/m yaw bias: nodes and odometry come one by one, each
    node from the end of the first lap on closes on its twin a lap before (the true relative pose), and the graph is
    re-solved every 5 nodes as the pipeline does. ISAM2, given only what was added since its last
    update, must end where Levenberg-Marquardt on the whole graph ends, and near the truth; its
    final whole-graph solve must give the batch answer."""
    lap = _square_loop()
    truth = np.vstack([lap, lap[1:]])
    n_lap = len(lap) - 1
    odom_cov = np.diag([0.02**2, 0.02**2, 0.01**2])
    closure_cov = np.diag([0.01**2, 0.01**2, 0.002**2])
    graphs = {"batch": PoseGraph(3.0), "isam2": PoseGraph(3.0, "isam2", isam2_steps=3, relinearize_threshold=0.001)}
    for g in graphs.values():
        est = truth[0]
        g.add_node(est)
        for i in range(1, len(truth)):
            rel = between(truth[i - 1], truth[i]) + np.array([0.0, 0.0, np.radians(1.0)])
            # a new node starts where the current estimate of the one before and the odometry put it
            est = compose(g.estimate(i - 1), rel)
            g.add_node(est)
            g.add_odometry(Edge(i - 1, i, rel, odom_cov))
            if i >= n_lap:  # back at the start, then along the first lap
                g.add_closure(Edge(i - n_lap, i, between(truth[i - n_lap], truth[i]), closure_cov))
            if i >= n_lap and i % 5 == 0:
                g.optimize()
        g.optimize()
    batch, isam2 = graphs["batch"].estimates(), graphs["isam2"].estimates()
    drift = np.hypot(*(_drifting_graph(truth, 3.0).estimates()[:, :2] - truth[:, :2]).T).max()
    assert drift > 5.0
    assert np.hypot(*(batch[:, :2] - truth[:, :2]).T).max() < 0.1
    assert np.hypot(*(isam2[:, :2] - batch[:, :2]).T).max() < 0.01
    assert np.abs(wrap_angle(isam2[:, 2] - batch[:, 2])).max() < np.radians(0.1)
    graphs["isam2"].optimize(final=True)
    final = graphs["isam2"].estimates()
    assert np.abs(final[:, :2] - batch[:, :2]).max() < 1e-4
    assert np.allclose(graphs["isam2"].closure_errors(), graphs["batch"].closure_errors(), atol=1e-3)


def test_an_unknown_solver_is_refused():
    with pytest.raises(ValueError, match="solver"):
        PoseGraph(3.0, "gauss-seidel")


def test_a_looser_tolerance_stops_a_solve_sooner_and_the_final_solve_ends_where_the_default_does():
    truth = _square_loop()
    last = len(truth) - 1
    closure = Edge(0, last, between(truth[0], truth[last]), np.diag([0.01**2, 0.01**2, 0.002**2]))
    default, loose = _drifting_graph(truth, 3.0), _drifting_graph(truth, 3.0)
    for g in (default, loose):
        g.add_closure(closure)
    default.optimize()
    loose.optimize(relative_tolerance=0.5)  # stops after the first iteration that gains less than half
    assert np.abs(loose.estimates() - default.estimates()).max() > 1e-6
    loose.optimize(final=True)
    assert np.abs(loose.estimates()[:, :2] - default.estimates()[:, :2]).max() < 1e-3


@pytest.mark.parametrize(("share", "nodes", "period"), [(0.0, 5000, 10), (0.05, 100, 10), (0.05, 2000, 100)])
def test_re_optimisations_come_every_optimize_every_nodes_or_a_share_of_the_graph_where_that_is_more(share, nodes, period):
    from fmcwlog.backend.pipeline import PoseGraphBackend

    backend = PoseGraphBackend(dataclasses.replace(BackendParams(), optimize_share=share), np.zeros(3))
    backend.nodes = [None] * nodes  # only their count is read
    assert backend._optimize_period() == period


def test_a_graph_of_many_laps_tied_to_each_other_ends_at_the_same_optimum_in_either_elimination_order(monkeypatch):
    """Ten laps of the square with a 1°/m yaw bias, each node tied to its twins one and two laps
    before (the true relative poses), as a log that passes the same places again and again ties
    them: the elimination order only changes how the linear solves factor the graph, so METIS's
    order (the default) must end where COLAMD's does, to rounding, and near the truth."""
    from fmcwlog.backend import graph as graph_module

    lap = _square_loop()
    n_lap = len(lap) - 1
    truth = np.vstack([lap] + [lap[1:]] * 9)
    closure_cov = np.diag([0.01**2, 0.01**2, 0.002**2])
    solved = {}
    for ordering in ("METIS", "COLAMD"):
        monkeypatch.setattr(graph_module, "ORDERING", ordering)
        g = _drifting_graph(truth, 3.0)
        for i in range(n_lap, len(truth)):
            for back in (1, 2):
                j = i - back * n_lap
                if j >= 0:
                    g.add_closure(Edge(j, i, between(truth[j], truth[i]), closure_cov))
        g.optimize()
        solved[ordering] = g.estimates()
    assert np.abs(solved["METIS"][:, :2] - solved["COLAMD"][:, :2]).max() < 1e-7
    assert np.abs(wrap_angle(solved["METIS"][:, 2] - solved["COLAMD"][:, 2])).max() < 1e-8
    assert np.hypot(*(solved["METIS"][:, :2] - truth[:, :2]).T).max() < 0.1
