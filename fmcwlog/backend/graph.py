"""The pose graph and its optimisation with gtsam (Levenberg-Marquardt).

Variables: one ``Pose2`` per node (base_link in the method's frame, m, rad). Factors: a prior
holding the first node where the front end put it (the frame stays ``<method>/odom``);
``BetweenFactorPose2`` odometry edges with Gaussian noise; loop closures with the same factor
under a robust Cauchy kernel (``noiseModel.Robust``): a wrong closure that passed
verification ends with a large whitened error and a small weight, instead of bending the
graph as a Gaussian one does (on Intel, a deliberately loose gate admitted 7 % wrong closures,
which a Cauchy kernel absorbed and a Gaussian one did not).

The solver: by default Levenberg-Marquardt re-solves the whole graph each time (``batch``).
gtsam's ISAM2 (``solver = "isam2"``) is offered beside it and not the default: it is given only
what was added since its last update, and the whole graph is solved once by LM at the end, from
its estimate, so the final answer is the batch one (sub-millimetre; about 1 mm on the baseline's
200 s ring, whose Cauchy-weighted closures leave more than one optimum). It saves CPU but holds
its Bayes tree, which grows with the log: on a 1,200 s ``ring`` log (``fmcwlog record --scenario
ring --duration 1200``; 12 laps, 1,690 closures; the improved method's graph calls replayed) the
re-solves take 6.3 s CPU with ISAM2 (``--set backend.solver=isam2 --set backend.isam2_steps=1
--set backend.isam2_relinearize=0.1``) against 29.9 s with LM, and glibc's heap in use grows to
173-181 MB against LM's 22 MB. The back end keeps memory from growing with the log, so LM is the
default (docs/design/back-end.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import gtsam

# The elimination order of LM's linear solves: METIS's nested dissection. A log that passes the same
# places many times ties every pass to the ones before, and COLAMD's order then fills the factor far
# more: on the 20-minute ten-lap corridor's last graphs (2,000 nodes, 11,000 factors) a solve takes
# 0.33 against 0.46 s CPU, to the same optimum (poses within 1e-9 m).
ORDERING = "METIS"


def _gtsam():
    """gtsam, imported at the first solve (0.08 s of imports a run without a closure never needs)."""
    import gtsam

    return gtsam


def _pose2(x: np.ndarray) -> gtsam.Pose2:
    return _gtsam().Pose2(float(x[0]), float(x[1]), float(x[2]))


def _array(p: gtsam.Pose2) -> np.ndarray:
    return np.array([p.x(), p.y(), p.theta()])


@dataclass
class Edge:
    """A relative-pose measurement: node ``b`` in node ``a``'s frame, ``relative`` (3,), its
    covariance (3, 3) in gtsam's tangent space at ``relative``."""

    a: int
    b: int
    relative: np.ndarray
    covariance: np.ndarray


class PoseGraph:
    """Nodes, odometry edges and robust loop closures. ``cauchy_scale``: the kernel's scale, in
    standard deviations. ``solver``: ``"batch"``, :meth:`optimize` runs LM on the whole graph from
    the current estimate; ``"isam2"``, it hands the factors and nodes added since the last call to
    gtsam's ISAM2 (``isam2_steps`` Gauss-Newton updates, ``relinearize_threshold`` on a variable's
    change, rad or m), and :meth:`optimize` with ``final=True`` runs LM on the whole graph once from
    ISAM2's estimate (and releases ISAM2: any later :meth:`optimize` runs LM). Another ``solver``
    raises ``ValueError``. Poses are ``(x, y, θ)`` of base_link in the method's frame (m, m, rad).

    Until the first :meth:`optimize` the nodes and edges are only listed (``_pending``, in the order
    given); that call imports gtsam and builds the graph from them in that order, so the graph, and
    every solve, is the same as built one call at a time, and a run that never optimises (no
    closure) never imports gtsam."""

    def __init__(self, cauchy_scale: float = 3.0, solver: str = "batch", isam2_steps: int = 3,
                 relinearize_threshold: float = 0.001):
        if solver not in ("batch", "isam2"):
            raise ValueError(f"unknown solver {solver!r} (batch, isam2)")
        self.cauchy_scale = cauchy_scale
        self.closures: list[Edge] = []
        self.n = 0
        self.isam2_steps = isam2_steps
        self._solver, self._relinearize_threshold = solver, relinearize_threshold
        # what add_node / add_odometry / add_closure were given before the graph is built
        self._pending: list[tuple[str, np.ndarray | Edge]] | None = []
        self._pending_nodes: list[np.ndarray] = []  # the pending nodes' estimates, by index

    def _build(self) -> None:
        """Import gtsam, make the graph and add what :attr:`_pending` lists, in its order."""
        if self._pending is None:
            return
        gt = _gtsam()  # the module; the annotations name it as gtsam
        self.graph = gt.NonlinearFactorGraph()
        self.values = gt.Values()
        self._closure_factors: list[gtsam.BetweenFactorPose2] = []
        self._isam: gtsam.ISAM2 | None = None  # None: LM on the whole graph (batch, or after the final solve)
        self._new_values = gt.Values()  # ISAM2: the nodes and factors it has not seen yet
        self._new_factors = gt.NonlinearFactorGraph()
        if self._solver == "isam2":
            params = gt.ISAM2Params()
            params.setRelinearizeThreshold(self._relinearize_threshold)
            params.relinearizeSkip = 1
            self._isam = gt.ISAM2(params)
        pending, self._pending, self.n, self.closures = self._pending, None, 0, []
        self._pending_nodes = []
        for kind, item in pending:
            if kind == "node":
                self.add_node(item)  # type: ignore[arg-type]
            elif kind == "odometry":
                self.add_odometry(item)  # type: ignore[arg-type]
            else:
                self.add_closure(item)  # type: ignore[arg-type]

    def _add(self, factor: gtsam.NonlinearFactor) -> None:
        self.graph.add(factor)
        if self._isam is not None:
            self._new_factors.add(factor)

    def add_node(self, estimate: np.ndarray) -> int:
        """A node with an initial estimate (3,); the first is held by a tight prior."""
        i = self.n
        if self._pending is not None:
            self._pending.append(("node", np.array(estimate, float)))
            self._pending_nodes.append(self._pending[-1][1])  # type: ignore[arg-type]
            self.n += 1
            return i
        gtsam = _gtsam()
        self.values.insert(i, _pose2(estimate))
        if self._isam is not None:
            self._new_values.insert(i, _pose2(estimate))
        if i == 0:
            self._add(gtsam.PriorFactorPose2(0, _pose2(estimate), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
        self.n += 1
        return i

    def set_estimate(self, i: int, estimate: np.ndarray) -> None:
        """Replace node ``i``'s current estimate (3,) with ``estimate``: the next batch solve starts from
        it (ISAM2 starts from it only for a node it has not been handed yet)."""
        if self._pending is not None:
            self._pending_nodes[i][:] = estimate
            return
        self.values.update(i, _pose2(estimate))
        if self._isam is not None and self._new_values.exists(i):
            self._new_values.update(i, _pose2(estimate))

    def add_odometry(self, e: Edge) -> None:
        """An odometry edge ``e`` between two existing nodes, with Gaussian noise of its covariance."""
        if self._pending is not None:
            self._pending.append(("odometry", e))
            return
        gtsam = _gtsam()
        noise = gtsam.noiseModel.Gaussian.Covariance(e.covariance)
        self._add(gtsam.BetweenFactorPose2(e.a, e.b, _pose2(e.relative), noise))

    def add_closure(self, e: Edge) -> int:
        """A loop closure under the Cauchy kernel; returns its index among the closures."""
        if self._pending is not None:
            self._pending.append(("closure", e))
            self.closures.append(e)
            return len(self.closures) - 1
        gtsam = _gtsam()
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(self.cauchy_scale),
                                               gtsam.noiseModel.Gaussian.Covariance(e.covariance))
        factor = gtsam.BetweenFactorPose2(e.a, e.b, _pose2(e.relative), noise)
        self._add(factor)
        self.closures.append(e)
        self._closure_factors.append(factor)
        return len(self.closures) - 1

    def optimize(self, max_iterations: int = 100, final: bool = False, relative_tolerance: float | None = None) -> None:
        """Optimise from the current estimate (class docstring); ``final``: the last solve of the run.
        ``relative_tolerance``: LM stops once an iteration lowers the error by less than this fraction
        of it (None: gtsam's default, 1e-5)."""
        self._build()
        gtsam = _gtsam()
        if self._isam is not None:
            self._isam.update(self._new_factors, self._new_values)
            for _ in range(self.isam2_steps - 1):
                self._isam.update()
            self._new_factors, self._new_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
            self.values = self._isam.calculateEstimate()
            if not final:
                return
            self._isam = None  # its Bayes tree freed before LM builds its own (the peak); LM from here on
        params = gtsam.LevenbergMarquardtParams()
        params.setOrderingType(ORDERING)
        params.setMaxIterations(max_iterations)
        if relative_tolerance is not None:
            params.setRelativeErrorTol(relative_tolerance)
        self.values = gtsam.LevenbergMarquardtOptimizer(self.graph, self.values, params).optimize()

    def estimate(self, i: int) -> np.ndarray:
        """The current estimate (3,) of node ``i`` (m, m, rad)."""
        self._build()
        return _array(self.values.atPose2(i))

    def estimates(self) -> np.ndarray:
        """(n, 3) the current estimate of every node, in index order (one call into gtsam: its values
        are the nodes' ``Pose2`` alone, under the keys ``0 … n-1``, which it keeps sorted)."""
        self._build()
        gtsam = _gtsam()
        return np.asarray(gtsam.utilities.extractPose2(self.values), float).reshape(-1, 3)

    def closure_errors(self) -> np.ndarray:
        """Whitened error (standard deviations, Mahalanobis) of each closure at the estimate."""
        self._build()
        gtsam = _gtsam()
        out = np.zeros(len(self.closures))
        for k, (e, f) in enumerate(zip(self.closures, self._closure_factors)):
            pred = self.values.atPose2(e.a).between(self.values.atPose2(e.b))
            err = np.asarray(gtsam.Pose2.Logmap(f.measured().between(pred)))
            out[k] = float(np.sqrt(err @ np.linalg.solve(e.covariance, err)))
        return out
