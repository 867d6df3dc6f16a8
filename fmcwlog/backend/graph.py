"""The pose graph and its optimisation with gtsam (Levenberg-Marquardt).

Variables: one ``Pose2`` per node (base_link in the method's frame, m, rad). Factors: a prior
holding the first node where the front end put it (the frame stays ``<method>/odom``);
``BetweenFactorPose2`` odometry edges with Gaussian noise; loop closures with the same factor
under a robust Cauchy kernel (``noiseModel.Robust``): a wrong closure that passed
verification ends with a large whitened error and a small weight, instead of bending the
graph as a Gaussian one does (on Intel, a deliberately loose gate admitted 7 % wrong closures,
which a Cauchy kernel absorbed and a Gaussian one did not).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np


def _pose2(x: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(x[0]), float(x[1]), float(x[2]))


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
    """Nodes, odometry edges and robust loop closures; :meth:`optimize` runs LM from the current
    estimate. ``cauchy_scale``: the kernel's scale, in standard deviations."""

    def __init__(self, cauchy_scale: float = 3.0):
        self.graph = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.cauchy_scale = cauchy_scale
        self.closures: list[Edge] = []
        self._closure_factors: list[gtsam.BetweenFactorPose2] = []
        self.n = 0

    def add_node(self, estimate: np.ndarray) -> int:
        """A node with an initial estimate (3,); the first is held by a tight prior."""
        i = self.n
        self.values.insert(i, _pose2(estimate))
        if i == 0:
            self.graph.add(gtsam.PriorFactorPose2(0, _pose2(estimate), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
        self.n += 1
        return i

    def add_odometry(self, e: Edge) -> None:
        noise = gtsam.noiseModel.Gaussian.Covariance(e.covariance)
        self.graph.add(gtsam.BetweenFactorPose2(e.a, e.b, _pose2(e.relative), noise))

    def add_closure(self, e: Edge) -> int:
        """A loop closure under the Cauchy kernel; returns its index among the closures."""
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(self.cauchy_scale),
                                               gtsam.noiseModel.Gaussian.Covariance(e.covariance))
        factor = gtsam.BetweenFactorPose2(e.a, e.b, _pose2(e.relative), noise)
        self.graph.add(factor)
        self.closures.append(e)
        self._closure_factors.append(factor)
        return len(self.closures) - 1

    def optimize(self, max_iterations: int = 100) -> None:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        self.values = gtsam.LevenbergMarquardtOptimizer(self.graph, self.values, params).optimize()

    def estimate(self, i: int) -> np.ndarray:
        return _array(self.values.atPose2(i))

    def estimates(self) -> np.ndarray:
        """(n, 3) the current estimate of every node."""
        return np.array([self.estimate(i) for i in range(self.n)]).reshape(-1, 3)

    def closure_errors(self) -> np.ndarray:
        """Whitened error (standard deviations, Mahalanobis) of each closure at the estimate."""
        out = np.zeros(len(self.closures))
        for k, (e, f) in enumerate(zip(self.closures, self._closure_factors)):
            pred = self.values.atPose2(e.a).between(self.values.atPose2(e.b))
            err = np.asarray(gtsam.Pose2.Logmap(f.measured().between(pred)))
            out[k] = float(np.sqrt(err @ np.linalg.solve(e.covariance, err)))
        return out
