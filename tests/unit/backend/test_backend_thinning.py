"""The back end's thinning: re-solves only for closures that disagree with the estimate, and fewer
closure queries along a stretch already tied to an earlier pass."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from fmcwlog.backend.graph import Edge
from fmcwlog.backend.params import BackendParams
from fmcwlog.backend.pipeline import PoseGraphBackend
from fmcwlog.geometry import compose

TIGHT = np.diag([0.01**2, 0.01**2, 0.002**2])
FREE_X = np.diag([100.0**2, 0.01**2, 0.002**2])  # a corridor along x: the closure leaves x free


def _backend(**changes) -> PoseGraphBackend:
    return PoseGraphBackend(dataclasses.replace(BackendParams(), **changes), np.zeros(3))


@pytest.mark.parametrize(("moved", "covariance", "due"), [
    ((0.03, 0.02, 0.002), TIGHT, False),        # within the gaps: the estimate is good enough
    ((0.0, 0.15, 0.0), TIGHT, True),            # across by more than optimize_gap
    ((0.0, 0.0, np.radians(1.5)), TIGHT, True),  # turned by more than optimize_gap_deg
    ((0.8, 0.02, 0.0), FREE_X, False),          # slid along the axis the closure leaves free
    ((0.8, 0.02, 0.0), TIGHT, True),            # the same slide where the closure determines it
])
def test_only_a_closure_that_moved_beyond_the_gap_in_a_determined_direction_makes_a_re_solve_due(moved, covariance, due):
    backend = _backend(optimize_gap=0.1, optimize_gap_deg=1.0)
    prior = np.array([2.0, -1.0, 0.3])
    edge = Edge(0, 1, compose(prior, np.array(moved)), covariance)
    assert backend._disagrees(edge, prior) is due


def test_zero_gaps_make_every_closure_call_for_a_re_solve():
    backend = _backend(optimize_gap=0.0, optimize_gap_deg=0.0)
    prior = np.array([1.0, 2.0, 0.1])
    assert backend._disagrees(Edge(0, 1, prior.copy(), TIGHT), prior)


@pytest.mark.parametrize("closed_every", [1.0, 2.0, 3.5])
def test_after_a_query_that_closed_a_loop_the_next_comes_closure_every_closed_later(closed_every, monkeypatch):
    """A straight drive, one node every 0.5 m; every query "closes" a loop: queries come every
    ``closure_every_closed`` m of path (rounded up to whole nodes), not every ``closure_every``."""


    backend = _backend(closure_every=1.0, closure_every_closed=closed_every, local_links=0)
    queried: list[float] = []

    def close(query: int) -> bool:
        queried.append(backend.nodes[query].path_m)
        return True

    monkeypatch.setattr(backend, "_close_loops", close)
    for k in range(60):
        pose = np.array([0.5 * k, 0.0, 0.0])
        backend.add(SimpleNamespace(pose=pose, keyframe=True, stamp_ns=k, static_map_xy=np.zeros((0, 2)),
                                    pose_covariance=None, jump=None, jump_prior=None, jump_back=0))
    gaps = np.diff(queried)
    assert len(gaps) > 5
    assert np.all(gaps >= closed_every - 1e-9) and np.all(gaps < closed_every + 0.5)


def test_an_accepted_closure_pulls_the_newest_node_in_the_directions_it_determines():
    """A closure across a corridor along x (x free): the query node moves to where the closure puts
    it across (y, yaw) and keeps the estimate's x; the graph's estimate moves with it."""
    backend = _backend(closure_pull=1.0, optimize_gap=0.1, optimize_gap_deg=1.0)
    for pose in ([0.0, 0.0, 0.0], [5.0, 0.0, 0.0]):
        backend.graph.add_node(np.array(pose))
        backend._estimates = np.vstack([backend._estimates, pose])
    prior = np.array([5.0, 0.0, 0.0])
    measured = np.array([5.6, 0.05, 0.01])  # 0.6 m along the free axis, 5 cm and 0.01 rad across
    backend._pull_tail(Edge(0, 1, measured, FREE_X), prior)
    moved = backend._estimates[1]
    assert moved[0] == pytest.approx(5.0, abs=1e-3)
    assert moved[1] == pytest.approx(0.05, abs=2e-3) and moved[2] == pytest.approx(0.01, abs=1e-3)
    np.testing.assert_allclose(backend.graph.estimate(1), moved)


def test_no_pull_leaves_the_estimate():
    backend = _backend(closure_pull=0.0)
    backend.graph.add_node(np.zeros(3))
    backend._estimates = np.zeros((1, 3))
    backend._pull_tail(Edge(0, 0, np.array([0.0, 0.3, 0.1]), TIGHT), np.zeros(3))
    np.testing.assert_array_equal(backend._estimates, np.zeros((1, 3)))


@pytest.mark.parametrize(("since_disagree", "thinned"), [(3.0, False), (12.0, True)])
def test_queries_thin_only_where_no_closure_disagreed_over_closure_settle(since_disagree, thinned, monkeypatch):
    """A query whose closures agree thins the next query only ``closure_settle`` m after the last disagreement."""


    from fmcwlog.backend import pipeline

    backend = _backend(closure_settle=10.0, closure_min_path=0.0)
    backend.graph.add_node(np.zeros(3))
    backend.graph.add_node(np.zeros(3))
    backend.nodes = [SimpleNamespace(path_m=0.0, stamp_ns=0), SimpleNamespace(path_m=20.0, stamp_ns=1)]
    backend._estimates = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    backend._node_path.append(0.0)
    backend._node_path.append(20.0)
    backend._last_disagree_path = 20.0 - since_disagree
    backend._last_closure_path = 20.0
    verdict = SimpleNamespace(accepted=True, relative=np.zeros(3), covariance=TIGHT, score=1.0, second_score=0.0,
                              inlier_fraction=1.0, free_directions=0)
    monkeypatch.setattr(pipeline, "verify", lambda *a, **k: verdict)
    monkeypatch.setattr(pipeline, "voxel_downsample", lambda xy, v: xy)
    monkeypatch.setattr(backend, "_submap", lambda cand: np.zeros((0, 2)))
    backend.nodes[1].points = np.zeros((0, 2), np.float32)
    assert backend._close_loops(1) is thinned


def test_a_query_right_after_a_pulled_closure_searches_the_tied_window():
    backend = _backend(tied_window=0.5, tied_window_deg=5.0)
    backend.nodes = [SimpleNamespace(path_m=30.0)]
    backend._last_closure_path = 30.0
    assert backend._search_window(0)[1] == backend.p.search
    backend._tied = True
    radius, search = backend._search_window(0)
    assert radius == backend.p.closure_radius
    assert (search.linear_window, search.angular_window_deg) == (0.5, 5.0)
    assert search.resolution == backend.p.search.resolution
    backend = _backend(tied_window=0.0)
    backend.nodes, backend._last_closure_path, backend._tied = [SimpleNamespace(path_m=30.0)], 30.0, True
    assert backend._search_window(0)[1] == backend.p.search


@pytest.mark.parametrize(("after_agreement", "offset", "narrowed"), [
    (True, 0.0, True),     # every closure where the estimate put it: the next query searches the tied window
    (True, 0.4, False),    # each 0.4 m off the estimate (beyond optimize_gap): the full window stays
    (False, 0.0, False),   # switched off: only a pull narrows it
])
def test_a_query_right_after_closures_that_agreed_with_the_estimate_searches_the_tied_window(after_agreement, offset,
                                                                                             narrowed, monkeypatch):
    """A straight drive, a node every 0.5 m, each query closing on the nodes behind it: where every
    closure lands within ``optimize_gap`` of the estimate the queries after the first search
    ``tied_window``; where they land beyond it, or with ``tied_after_agreement`` off, ``search``'s."""
    from fmcwlog.backend import pipeline

    backend = _backend(closure_min_path=0.0, local_links=0, tied_window=0.5, tied_window_deg=5.0,
                       tied_after_agreement=after_agreement, closure_every_closed=1.0)
    windows: list[float] = []

    def verify(q, submap, prior, p, search):
        windows.append(search.linear_window)
        return SimpleNamespace(accepted=True, relative=compose(prior, np.array([0.0, offset, 0.0])), covariance=TIGHT,
                               score=1.0, second_score=0.0, inlier_fraction=1.0, free_directions=0, test="")

    monkeypatch.setattr(pipeline, "verify", verify)
    monkeypatch.setattr(pipeline, "voxel_downsample", lambda xy, v: xy)
    monkeypatch.setattr(backend, "_submap", lambda cand: np.zeros((0, 2)))
    monkeypatch.setattr(backend, "_optimize", lambda final=False: None)  # the estimate stays the odometry's
    for k in range(30):
        backend.add(SimpleNamespace(pose=np.array([0.5 * k, 0.0, 0.0]), keyframe=True, stamp_ns=k,
                                    static_map_xy=np.zeros((0, 2)), pose_covariance=None, jump=None, jump_prior=None,
                                    jump_back=0))
    assert len(windows) > 10 and windows[0] == backend.p.search.linear_window
    assert set(windows[2:]) == ({0.5} if narrowed else {backend.p.search.linear_window})
