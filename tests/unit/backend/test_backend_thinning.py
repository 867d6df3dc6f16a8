"""The back end's thinning: re-solves only for closures that disagree with the estimate, and fewer
closure queries along a stretch already tied to an earlier pass."""

from __future__ import annotations

import dataclasses

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
    from types import SimpleNamespace

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
