"""Local edges: each new node matched, point to line, against the nodes just before it.

The front end's relative poses carry a bias that loop closures cannot remove where a loop has
no cross-visibility. On the 200 s ``ring`` log (``fmcwlog record --scenario ring --duration
200``, seed 0) the front end's motion between two consecutive nodes (0.59 m) is 1.5 mm to the
left of the truth on average (its heading sits 0.14° right of its direction of travel, in every
corridor of the ring) and 0.068° rms off in yaw; a closure ties the second lap to the first but
leaves the shape of the lap as the odometry drew it. With exact closures (the truth's relative
poses, held tight) the graph still ends at 1.25 cm ATE, against 0.59 cm with exact odometry and
the real closures: the odometry, not the closures, sets the floor.

The same nodes matched by :mod:`.registration` (point to line, full-density points, no
motion prior) have no such bias: node to the one before it 2.1 mm rms across (mean 0.6 mm)
and 0.034° in yaw; to the node four back (2.4 m) 2.5 mm and 0.047°, where the front end's
own relative pose is 9.1 mm (mean 5.4 mm) and 0.12°. Along a bare corridor they determine
less than the front end does (its Doppler speed holds the axis; 4.8 against 2.8 mm rms along
track), so they are *added* to the front end's edges rather than replacing them: each with the
information of its match (``effective_pairs`` pairs of ``residual_sigma``, as a closure's), in
which a corridor's axis is free and the front end's edge keeps it.

Each new node ``i`` is matched against each of the nodes ``i-1 … i-L`` (``L`` = ``local_links``),
one at a time: a submap of one node's own points (its normals built once), not of several placed
by the front end's poses, since on both logs the single node does better (ring 0.55 against
0.69 cm, corridor 0.49 against 0.64 cm with four; offline, on the same graphs). ``L`` = 4, the
query is the node's points thinned to 5 cm; the alternatives measured against both are in
docs/design/back-end.md. A match that did not
converge, paired fewer than ``min_pairs`` points or moved more than ``local_gate`` m or
``local_gate_deg`` from the front end's relative pose gives no edge (counted, not an error); nor
does a node with no static points (``empty``: every point of its sweep was on a mover or dropped).

Cost: a match is some 1.1-1.4 ms, mostly the nearest-point pairing (a 6-nearest KD-tree query of
every query point, then re-queries of the points that moved). Its ICP stops once a step moves less
than ``local_tolerance`` = 0.1 mm, as the closures' does: a 1 mm tolerance saves about 2 % of a
whole ``process`` run's CPU for 2-3 % of the accuracy (on the 120 s ``corridor``, ``fmcwlog
process --set backend.local_tolerance=0.001``: back-end ATE 0.679 against 0.666 cm). The front
end's own scan-to-map pose is no substitute: it is the odometry edge already, the biased
measurement these edges are added to correct.

With the compiled core a node's matches are one call (``src/core/local_edges.cpp``: the thinning,
each earlier node's submap, the ICPs, the gates and the covariances), which keeps each node's
points while a later node may still match them; the numpy path here stays the reference. On the
20-minute ten-lap corridor the local edges alone take 0.65 against 0.91 ms a node (improved) and
0.90 against 1.10 ms (baseline) with the matches one call each.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geometry import between, wrap_angle
from ..kernels import compiled
from ..kernels.voxel import voxel_downsample
from .graph import Edge
from .keyframes import Node, match_covariance
from .params import BackendParams
from .registration import LineICPParams, Submap, build_submap, register_point_to_line


@dataclass
class LocalMatcher:
    """The submaps of recent nodes (built once each) and the matching of a new node against them.
    ``rejected``: matches that gave no edge, by reason (``empty``, ``points``, ``converged``, ``pairs``,
    ``gate``)."""

    p: BackendParams
    _submaps: dict[int, Submap] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    icp: LineICPParams = field(init=False)
    _core: Any = field(default=None, init=False, repr=False)  # the compiled core's LocalEdges, once used
    _held: set[int] = field(default_factory=set, init=False, repr=False)  # the nodes it holds the points of
    iterations: list[int] = field(default_factory=list, init=False, repr=False)  # the core's last call: ICP
    # iterations of each match, node order (0: none ran)

    def __post_init__(self) -> None:
        self.icp = dataclasses.replace(self.p.icp, max_iterations=self.p.local_max_iterations,
                                       tolerance=self.p.local_tolerance)

    def edges(self, nodes: list[Node], first: int = 0) -> list[Edge]:
        """Edges from ``local_links`` nodes before the last one of ``nodes`` to it (module docstring),
        none from a node before ``first`` (the first node of a new piece, after a jump)."""
        query = nodes[-1]
        module = compiled.core()
        if module is not None:
            return self._compiled_edges(module, nodes, max(query.index - self.p.local_links, first, 0))
        q = voxel_downsample(query.points.astype(float), self.p.local_query_voxel)
        out = []
        for j in range(max(query.index - self.p.local_links, first, 0), query.index):
            edge = self._match(nodes, j, q)
            if edge is not None:
                out.append(edge)
        for old in [k for k in self._submaps if k < query.index - self.p.local_links]:
            del self._submaps[old]
        return out

    def _compiled_edges(self, module, nodes: list[Node], lo: int) -> list[Edge]:
        """:meth:`edges` in one call of the compiled core (``src/core/local_edges.cpp``) from node ``lo``:
        the same submaps, pairs, iterations and gates; poses and covariances agree to rounding. The
        core keeps each node's points from the call that added it until no later node matches it."""
        if self._core is None:
            p, icp = self.p, self.icp
            self._core = module.LocalEdges(
                p.local_links, p.local_query_voxel, p.local_submap_voxel, icp.normal_neighbours, icp.min_planarity,
                icp.max_distance, icp.max_iterations, icp.kernel_scale, icp.tolerance, p.min_pairs, p.local_gate,
                p.local_gate_deg, p.effective_pairs, p.residual_sigma, p.local_sigma_xy_floor, p.local_sigma_yaw_floor)
        core, held, i = self._core, self._held, nodes[-1].index
        for j in range(lo, i):
            if j not in held:  # the first node, or one made before the core was used
                core.add(j, np.ascontiguousarray(nodes[j].points, float))
                held.add(j)
        found, rejected, self.iterations = core.edges(i, np.ascontiguousarray(nodes[-1].points, float),
                                     np.array([nodes[j].frontend_pose for j in range(lo, i + 1)], float))
        held.add(i)
        for old in [k for k in held if k < i - self.p.local_links]:
            held.discard(old)
        for reason in rejected:
            self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return [Edge(j, i, np.array(pose), np.array(cov).reshape(3, 3)) for j, pose, cov in found]

    def _submap(self, nodes: list[Node], j: int) -> Submap:
        if j not in self._submaps:
            self._submaps[j] = build_submap(voxel_downsample(nodes[j].points.astype(float), self.p.local_submap_voxel),
                                          self.icp)
        return self._submaps[j]

    def _match(self, nodes: list[Node], j: int, q: np.ndarray) -> Edge | None:
        p = self.p
        if not len(nodes[j].points) or not len(q):  # a keyframe without static points: nothing to match
            self.rejected["empty"] = self.rejected.get("empty", 0) + 1
            return None
        prior = between(nodes[j].frontend_pose, nodes[-1].frontend_pose)
        sub = self._submap(nodes, j)
        failed = "points" if min(len(q), len(sub.points)) < p.min_pairs else None
        if failed is None:
            icp = register_point_to_line(q, sub, prior, self.icp)
            moved = icp.pose - prior
            moved[2] = wrap_angle(moved[2])
            far = np.hypot(moved[0], moved[1]) > p.local_gate or abs(moved[2]) > np.radians(p.local_gate_deg)
            failed = ("converged" if not icp.converged else "pairs" if icp.pairs < p.min_pairs
                      else "gate" if far else None)
        if failed is not None:
            self.rejected[failed] = self.rejected.get(failed, 0) + 1
            return None
        cov = match_covariance(icp.hessian, icp.pairs, icp.pose, p, p.local_sigma_xy_floor, p.local_sigma_yaw_floor)
        return Edge(j, nodes[-1].index, icp.pose, cov)
