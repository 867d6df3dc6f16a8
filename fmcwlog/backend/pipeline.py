"""The back end of one method, sweep by sweep: nodes, odometry edges, verified loop closures, the
optimised trajectory and the map rebuilt from it.

:meth:`PoseGraphBackend.add` takes every :class:`~fmcwlog.frontend.methods.SweepResult` of its
method. A keyframe that moved ``node_distance`` since the last node becomes a node, joined to
it by an odometry edge (the front end's relative pose) and by local edges (the node matched
against the few nodes before it, :mod:`.local_edges`); every ``closure_every`` metres of path
(``closure_every_closed`` after a query whose closures agreed with the estimate, where none
disagreed over the last ``closure_settle`` m) a node looks for
loop closures (:mod:`.candidates`), verifies each candidate against a submap of the candidate's
neighbours placed by the current estimate (:mod:`.verification`) and adds the ones that pass under the
Cauchy kernel (:mod:`.graph`). Once a closure is in that moved beyond ``optimize_gap`` from the
estimate in a direction it determines, the graph is re-optimised every
``optimize_every`` nodes (or ``optimize_share`` of its nodes, where more: a re-solve costs more the
larger the graph), to ``optimize_tolerance``, so that later candidates are searched around corrected
estimates. Between re-solves each accepted closure pulls the newest node, and the nodes after it, toward
where it puts it (``closure_pull``), so drift does not build up into closures that disagree.
:meth:`PoseGraphBackend.finish` optimises once more, to gtsam's default tolerance, and
returns every sweep's pose corrected through its node (the last node at or before it: ``x_node ⊕ (f_node⁻¹ ⊕ f_sweep)`` with ``f``
the front end's poses), the closures, and an occupancy grid rebuilt from the nodes' points at
their optimised poses.

Cost (CPU time, ``fmcwlog record --scenario ring --duration 200``, seed 0, both methods): ``add``
takes 12.5 s for both methods (the baseline 6.8 s, its wide closure searches), ``finish`` about
1 s each; on the 120 s ``corridor`` ``add`` takes 5.3 s, where the local edges' nearest-point
pairing (:class:`~fmcwlog.kernels.nearest.NearestPairs`) is the largest part (about a third). The
profile, and what each tuning step saved: docs/design/speed-experiments.md.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from ..geometry import between, compose, inverse, transform_points
from ..kernels.correlative import MAX_LEVELS, CorrelativeParams
from ..kernels.growing import GrowingArray
from ..kernels.occupancy import OccupancyGrid, OccupancyParams
from ..kernels.voxel import voxel_downsample
from ..types import SweepResult
from .candidates import closure_candidates
from .consistency import RevisitDistances, revisit_distances, worse
from .graph import Edge, PoseGraph
from .keyframes import Node, NodePoints, is_new_node, odometry_covariance
from .local_edges import LocalMatcher
from .params import BackendParams
from .point_store import PointStore
from .verification import verify

# The odometry edge across a jump (a robot carried away): a standard deviation of 1 km and 10 rad, no weight
# against any other edge; the front end's relative pose only seeds the node's estimate.
JUMP_COVARIANCE = np.diag([1e6, 1e6, 1e2])
NEW_PIECE = "new piece"  # :data:`fmcwlog.frontend.relocalise.NEW_PIECE` (the back end imports no front end)
QUERY_VOXEL = 0.1  # m: the query node's points are thinned to this for verification
SUBMAP_VOXEL = 0.05  # m: and the submap's


@dataclass
class ClosureRecord:
    """A verified closure: ``query`` and ``candidate`` node indices, their stamps (ns), the query's
    pose in the candidate's frame as matched (``relative``, m, m, rad), the verification's
    figures, and ``accepted`` (set by :meth:`PoseGraphBackend.finish`: the
    closure's whitened error at the optimum is within the Cauchy scale, i.e. it weighs at
    least half)."""

    query: int
    candidate: int
    query_stamp_ns: int
    candidate_stamp_ns: int
    relative: np.ndarray
    score: float
    second_score: float
    inlier_fraction: float
    free_directions: int
    whitened_error: float = 0.0
    accepted: bool = False


@dataclass
class BackendResult:
    """poses: (S, 3) every sweep's optimised pose, in the order the sweeps were added;
    node_stamps_ns, node_poses: the nodes; closures;
    grid: the occupancy map rebuilt from the nodes; counts and the back end's time (s).
    revisits: the two trajectories' revisit distances (:mod:`.consistency`), where closures changed the
    graph; kept_front_end: the optimised trajectory drew revisited places worse than the front end's,
    so ``poses``, ``node_poses`` and ``grid`` are the front end's (its poses, its nodes' map)."""

    poses: np.ndarray
    node_stamps_ns: np.ndarray
    node_poses: np.ndarray
    closures: list[ClosureRecord]
    grid: OccupancyGrid
    proposed: int
    verified: int
    accepted: int
    rejections: dict[str, int]
    seconds: float
    local_edges: int = 0
    local_rejections: dict[str, int] = field(default_factory=dict)
    revisits: RevisitDistances | None = None
    kept_front_end: bool = False

    def summary(self) -> dict:
        """The counts and the time (s) for ``run.json``'s ``backend``; where the front end's trajectory
        was kept, ``kept_front_end`` with the revisit distances that decided it."""
        out = {"nodes": int(len(self.node_stamps_ns)), "local_edges": self.local_edges,
               "local_rejections": dict(sorted(self.local_rejections.items())), "closures_proposed": self.proposed,
               "closures_verified": self.verified, "closures_accepted": self.accepted,
               "rejections": dict(sorted(self.rejections.items())), "seconds": round(self.seconds, 3)}
        if self.kept_front_end and self.revisits is not None:
            r = self.revisits
            out["kept_front_end"] = {"revisit_distance_m": {"front_end": round(r.frontend, 4),
                                                            "optimised": round(r.optimised, 4)},
                                     "points": r.points, "nodes_compared": r.queries}
        return out

    def to_json(self) -> dict:
        """What ``<method>_backend.json`` holds: the nodes (optimised poses, in the method's own
        ``<method>/odom``), every verified closure and the :meth:`summary`."""
        return {
            "frame": "the method's own <method>/odom; base_link",
            "nodes": {"stamp_ns": self.node_stamps_ns.tolist(), "x": self.node_poses[:, 0].round(6).tolist(),
                      "y": self.node_poses[:, 1].round(6).tolist(), "yaw": self.node_poses[:, 2].round(6).tolist()},
            "closures": [{"query": c.query, "candidate": c.candidate, "query_stamp_ns": c.query_stamp_ns,
                          "candidate_stamp_ns": c.candidate_stamp_ns, "relative": [round(float(v), 6) for v in c.relative],
                          "score": round(c.score, 4), "second_score": round(c.second_score, 4),
                          "inlier_fraction": round(c.inlier_fraction, 4), "free_directions": c.free_directions,
                          "whitened_error": round(c.whitened_error, 4), "accepted": c.accepted} for c in self.closures],
            "summary": self.summary(),
        }


@dataclass
class _Sweeps:
    """Every sweep's front-end pose (x, y, yaw) and the node it is corrected through, in numpy: a
    few bytes a sweep, where a list held an object per value. (The stamps are the outputs'.)"""

    poses: GrowingArray = field(default_factory=lambda: GrowingArray(np.float64, (3,)))
    node: GrowingArray = field(default_factory=lambda: GrowingArray(np.int64))


class PoseGraphBackend:
    """The pose-graph back end of one method (module docstring). ``mount``: the lidar in base_link
    (x, y, yaw), for the map's ray origins; ``map_resolution``: the rebuilt map's cell (m)."""

    def __init__(self, params: BackendParams, mount: np.ndarray, map_resolution: float = 0.05):
        self.p = params
        self.mount = np.asarray(mount, float)
        self.map_resolution = map_resolution
        self.graph = PoseGraph(params.cauchy_scale, params.solver, params.isam2_steps, params.isam2_relinearize)
        self.local = LocalMatcher(params)
        self.local_edges = 0
        self.nodes: list[Node] = []
        self.sweeps = _Sweeps()
        self.records: list[ClosureRecord] = []
        self.proposed = 0
        self.rejections: dict[str, int] = {}
        self.seconds = 0.0
        self._path_m = 0.0
        self._last_pose: np.ndarray | None = None
        self._last_query_path = -np.inf
        self._query_every = params.closure_every  # path (m) to the next query: less often after a closure
        self._last_wide_path = -np.inf
        self._last_closure_path = 0.0  # path at the last node that closed a loop (m)
        self._last_disagree_path = -np.inf  # path at the last node whose closure disagreed (m)
        self._tied = False  # the last query tied the tail to an earlier pass: the narrower search (_search_window)
        self._agreed = False  # the last query added closures, each within the gaps of the estimate (_disagrees)
        self._tied_search = params.search if params.tied_window == 0.0 else dataclasses.replace(
            params.search, linear_window=min(params.tied_window, params.search.linear_window),
            angular_window_deg=min(params.tied_window_deg, params.search.angular_window_deg))
        self._nodes_since_opt = 0
        self._dirty = False
        self._estimates = np.zeros((0, 3))  # the graph's estimate of every node, kept current
        self._store: PointStore | None = None  # the points of nodes older than the local links'
        self._node_path = GrowingArray(np.float64)  # every node's path_m (m), for the candidates
        self._jump: str | None = None  # a jump since the last node (:mod:`fmcwlog.frontend.relocalise`)
        # per relocalised sweep: its index, the suspect sweeps just before it, the prior's pose of it
        self._carried: list[tuple[int, int, np.ndarray]] = []
        self._piece_first = 0  # the first node of the current piece: local edges reach no node before it

    # --- sweep by sweep -------------------------------------------------------------------
    def add(self, r: SweepResult) -> None:
        """One sweep of the method, in time order: its pose (base_link in ``<method>/odom``, m, m,
        rad), and, for a keyframe, its deskewed static points and the ICP's covariance; it may
        become a node and look for loop closures (module docstring)."""
        t0 = time.perf_counter()
        if self._last_pose is not None:
            self._path_m += float(np.hypot(*(r.pose[:2] - self._last_pose[:2])))
        self._last_pose = r.pose
        last = self.nodes[-1] if self.nodes else None
        if r.jump is not None:  # a robot carried away: no edge may claim it drove the jump
            self._jump = r.jump
            if r.jump == NEW_PIECE:  # and the poses after it are at an unknown offset: no local edge across it
                self._piece_first = len(self.nodes)
        if (r.keyframe or last is None) and is_new_node(last, r.pose, self.p) or (r.jump is not None and r.keyframe):
            self._add_node(r)
        self.sweeps.poses.append(np.asarray(r.pose, float))
        self.sweeps.node.append(len(self.nodes) - 1)
        if r.jump_prior is not None and r.jump_back > 0:  # the suspect sweeps before a relocalised one
            self._carried.append((len(self.sweeps.poses) - 1, r.jump_back, np.asarray(r.jump_prior, float)))
        self.seconds += time.perf_counter() - t0

    def _add_node(self, r: SweepResult) -> None:
        points = transform_points(inverse(r.pose), r.static_map_xy).astype(np.float32)
        node = Node(len(self.nodes), r.stamp_ns, np.asarray(r.pose, float), points, r.pose_covariance, self._path_m)
        if not self.nodes:
            self.graph.add_node(node.frontend_pose)
            self._estimates = node.frontend_pose[None, :].copy()
        else:
            prev = self.nodes[-1]
            rel = between(prev.frontend_pose, node.frontend_pose)
            estimate = compose(self._estimates[-1], rel)
            self.graph.add_node(estimate)
            cov = odometry_covariance(prev, node, self.p)
            if self._jump is not None:
                cov = cov + JUMP_COVARIANCE
                self._jump = None
            self.graph.add_odometry(Edge(prev.index, node.index, rel, cov))
            self._estimates = np.vstack([self._estimates, estimate])
        self.nodes.append(node)
        self._node_path.append(node.path_m)
        if len(self.nodes) > 1 and self.p.local_links:
            for edge in self.local.edges(self.nodes, self._piece_first):
                self.graph.add_odometry(edge)
                self.local_edges += 1
        self._nodes_since_opt += 1
        if self._path_m - self._last_query_path >= self._query_every:
            self._last_query_path = self._path_m
            closed = self._close_loops(node.index)
            just_closed = self._last_closure_path == self._path_m
            self._tied = just_closed and (self.p.closure_pull > 0.0 or self.p.tied_after_agreement and self._agreed)
            self._query_every = self.p.closure_every_closed if closed else self.p.closure_every
        if self._dirty and self._nodes_since_opt >= self._optimize_period():
            self._optimize()
        self._spill(node.index - max(self.p.local_links, 1))

    def _spill(self, index: int) -> None:
        """Node ``index``'s points out of memory (:class:`~fmcwlog.backend.point_store.PointStore`): no later
        local edge reads them; a closure's submap and the final map read them back, the same
        float32 values. Kept in memory they would be the one per-node cost that grows with the log (~4 kB a node)."""
        if index >= 0:
            if self._store is None:
                self._store = PointStore()
            self.nodes[index].spill(self._store)

    def _search_window(self, query: int) -> tuple[float, CorrelativeParams] | None:
        """The candidates' radius and the search for ``query``, widened with the path since the
        last closure; None when a widened search is due but ran less than ``wide_every`` ago."""
        p = self.p
        since = self.nodes[query].path_m - self._last_closure_path
        window = min(max(p.search.linear_window, p.drift_per_m * since), p.max_window)
        if window <= p.search.linear_window:
            # right after a closure pulled the tail onto an earlier pass, or closures that all agreed
            # with the estimate: the narrower window
            return p.closure_radius, self._tied_search if self._tied else p.search
        if self.nodes[query].path_m - self._last_wide_path < p.wide_every:
            return None
        self._last_wide_path = self.nodes[query].path_m
        angle = min(max(p.search.angular_window_deg, p.drift_deg_per_m * since), p.max_window_deg)
        levels = min(p.search.levels + (window > 2 * p.search.linear_window), MAX_LEVELS)
        search = dataclasses.replace(p.search, linear_window=window, angular_window_deg=angle, levels=levels)
        return p.closure_radius + window - p.search.linear_window, search

    def _close_loops(self, query: int) -> bool:
        """Verify ``query``'s candidates and add the closures that pass; whether any did, each within
        the gaps of the estimate (:meth:`_disagrees`): a stretch tied where the estimate already had it."""
        path = self._node_path.values
        window = self._search_window(query)
        if window is None:
            return False
        radius, search = window
        q, closed, agreed = None, False, True
        self._agreed = False
        for cand in closure_candidates(query, self._estimates[:, :2], path, self.p, radius):
            self.proposed += 1
            prior = between(self._estimates[cand], self._estimates[query])
            if q is None:  # the query's points, thinned once for all its candidates
                q = voxel_downsample(self.nodes[query].points.astype(float), QUERY_VOXEL)
            verdict = verify(q, self._submap(cand), prior, self.p, search)
            if not verdict.accepted:
                self.rejections[verdict.test] = self.rejections.get(verdict.test, 0) + 1
                continue
            assert verdict.relative is not None and verdict.covariance is not None
            edge = Edge(cand, query, verdict.relative, verdict.covariance)
            self.graph.add_closure(edge)
            self.records.append(ClosureRecord(query, cand, self.nodes[query].stamp_ns, self.nodes[cand].stamp_ns,
                                              verdict.relative, verdict.score, verdict.second_score, verdict.inlier_fraction,
                                              verdict.free_directions))
            disagrees = self._disagrees(edge, prior)
            self._dirty = self._dirty or disagrees
            if disagrees:
                self._last_disagree_path = self.nodes[query].path_m
            self._pull_tail(edge, prior)
            self._last_closure_path = self.nodes[query].path_m
            closed, agreed = True, agreed and not disagrees
        self._agreed = closed and agreed
        settled = self.nodes[query].path_m - self._last_disagree_path >= self.p.closure_settle
        return closed and agreed and settled

    def _disagrees(self, edge: Edge, prior: np.ndarray) -> bool:
        """Whether a closure ``edge`` moved beyond ``optimize_gap`` (m) or ``optimize_gap_deg`` from the
        ``prior`` (3,, m, m, rad) the current estimate gave, in a direction it determines: the
        difference whitened by its covariance plus the gaps' squares exceeds 1, so a slide along a
        corridor's axis, which the closure leaves free, counts for nothing. Only such a closure
        makes a re-solve due; with both gaps 0, every closure does."""
        if self.p.optimize_gap == 0.0 and self.p.optimize_gap_deg == 0.0:
            return True
        moved = between(prior, edge.relative)
        gap = np.diag([self.p.optimize_gap, self.p.optimize_gap, np.radians(self.p.optimize_gap_deg)]) ** 2
        return bool(moved @ np.linalg.solve(edge.covariance + gap, moved) >= 1.0)

    def _pull_tail(self, edge: Edge, prior: np.ndarray) -> None:
        """Move the query node ``edge.b`` (the newest: later nodes follow it by odometry)
        ``closure_pull`` of the way from ``prior`` (its pose in ``edge.a``'s frame by the estimate) to
        the closure's ``edge.relative``: the difference (m, m, rad, in the query's frame) through the
        gain ``S (S + C)⁻¹``, ``S`` the gaps' squares (:meth:`_disagrees`), ``C`` the closure's
        covariance, so a direction the closure leaves free (a corridor's axis) keeps the estimate's."""
        if self.p.closure_pull == 0.0:
            return
        moved = between(prior, edge.relative)
        gap = np.diag([self.p.optimize_gap, self.p.optimize_gap, np.radians(self.p.optimize_gap_deg)]) ** 2
        gap = np.maximum(gap, np.diag([1e-6, 1e-6, 1e-8]))  # zero gaps: still a gain, not a singular sum
        step = self.p.closure_pull * (gap @ np.linalg.solve(edge.covariance + gap, moved))
        self._estimates[edge.b] = compose(self._estimates[edge.b], step)
        self.graph.set_estimate(edge.b, self._estimates[edge.b])

    def _submap(self, cand: int) -> np.ndarray:
        """The points of the nodes within ``submap_nodes`` of ``cand``, in its frame, placed by the
        current estimate."""
        lo, hi = max(cand - self.p.submap_nodes, 0), min(cand + self.p.submap_nodes + 1, len(self.nodes))
        ref = self._estimates[cand]
        parts = [transform_points(between(ref, self._estimates[i]), self.nodes[i].points.astype(float))
                 for i in range(lo, hi)]
        return voxel_downsample(np.concatenate(parts), SUBMAP_VOXEL)

    def _optimize_period(self) -> int:
        """New nodes between two re-optimisations: ``optimize_every``, or ``optimize_share`` of the
        graph's nodes where that is more (a re-solve costs more the larger the graph: a share keeps
        their total linear in the log's length)."""
        return max(self.p.optimize_every, int(self.p.optimize_share * len(self.nodes)))

    def _optimize(self, final: bool = False) -> None:
        """Re-solve the graph and take its estimates; a solve before the last stops at
        ``optimize_tolerance`` (its estimates only place the next candidates' searches, which
        reach 1.5 m and more around them), the last one runs to gtsam's default."""
        self.graph.optimize(final=final, relative_tolerance=None if final else self.p.optimize_tolerance)
        self._estimates = self.graph.estimates()
        self._nodes_since_opt = 0
        self._dirty = False

    # --- the end ----------------------------------------------------------------------------
    def finish(self) -> BackendResult:
        """The last optimisation, every sweep's corrected pose and the map rebuilt from the nodes;
        call once, after the last :meth:`add`."""
        t0 = time.perf_counter()
        if self.records:
            self._optimize(final=True)
            for rec, err in zip(self.records, self.graph.closure_errors()):
                rec.whitened_error = float(err)
                rec.accepted = bool(err <= self.p.cauchy_scale)
        revisits = None
        frontend = np.array([n.frontend_pose for n in self.nodes]).reshape(-1, 3)
        if self.records:
            revisits = revisit_distances(NodePoints(self.nodes), np.array([n.path_m for n in self.nodes]),
                                         frontend, self._estimates)
        keep = revisits is not None and worse(revisits)
        if keep:  # the front end's own: every sweep where it put it, the map from its nodes
            self._estimates = frontend
            poses = self.sweeps.poses.values.copy()
        else:
            poses = self._corrected_sweeps()
        self._place_carried(poses)
        grid = self._rebuild_map()
        self.seconds += time.perf_counter() - t0
        return BackendResult(poses, np.array([n.stamp_ns for n in self.nodes], np.int64), self._estimates.copy(),
                             self.records, grid, self.proposed, len(self.records),
                             sum(r.accepted for r in self.records), self.rejections, self.seconds,
                             self.local_edges, dict(self.local.rejected), revisits, keep)

    def _corrected_sweeps(self) -> np.ndarray:
        """Every sweep through its node: ``x_node ⊕ (f_node⁻¹ ⊕ f_sweep)``."""
        f = self.sweeps.poses.values.copy()
        if not self.nodes:
            return f
        idx = np.maximum(self.sweeps.node.values, 0)
        f_node = np.array([n.frontend_pose for n in self.nodes])[idx]
        return compose(self._estimates[idx], between(f_node, f))

    def _place_carried(self, poses: np.ndarray) -> None:
        """The suspect sweeps before each relocalised sweep, in ``poses`` (S, 3): where the robot was
        carried, not where the prior left them: the relocalised sweep's pose composed with the prior's
        motion from it to each (``x_r ⊕ (p_r⁻¹ ⊕ f_i)``; they kept the prior's poses, one chain with
        ``p_r``). The front end's own trajectory keeps them where the prior put them."""
        f = self.sweeps.poses.values
        for r, back, prior in self._carried:
            lo = max(r - back, 0)
            poses[lo:r] = compose(poses[r], between(prior, f[lo:r]))

    def _rebuild_map(self) -> OccupancyGrid:
        grid = OccupancyGrid(OccupancyParams(resolution=self.map_resolution))
        for node, pose in zip(self.nodes, self._estimates):
            if len(node.points):
                grid.integrate(compose(pose, self.mount)[:2], transform_points(pose, node.points.astype(float)))
        return grid
