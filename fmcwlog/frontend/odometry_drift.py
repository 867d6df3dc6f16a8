"""The motion prior's drift in heading and distance, learnt from the scans while they match: what a gap's bridge corrects.

Frames and units: base_link; metres, radians.

Wheel odometry's heading error is mostly systematic. Rear wheels whose radii differ by a fraction
of a percent from what the calibration says turn the robot's believed heading by a fixed amount per
metre driven (the simulator's default robot, left radius 0.5 % and right 0.3 % larger than
calibrated over a 0.45 m track: 4.4 mrad per metre, 0.26 °/s at 1 m/s), and a track width or mean
radius off by a fraction turns every turn by that fraction of its angle. Between two sweeps that
drift is far below what the scans resolve, and the front end's fusion treats it as noise (:class:
`~.twist_fusion.WheelNoise`). Across a gap in the sweeps it is what the bridge gets wrong: on the
30 s corridor sample with the 6 s across its corner removed, 19 mrad of heading, which the scans
after the gap cannot take out (they see a corridor the map has not seen yet) and which then stays
in every pose after it.

The same radii, 0.4 % larger on average than calibrated, make the prior's distances 0.4 % short:
1.6 cm over a 4 s gap at 1 m/s, as much as the heading's error puts across the path.

While the sweeps match, each registered interval compares the prior's motion with the scans' over
the same interval. The model is the odometry calibration's (Censi et al. 2013, linearised for a
small error), with the scans' motion standing for the true one:

    Δψ_w = Δψ + a s + b Δψ,        s_w = (1 + c) s

with ``s`` the signed distance along the heading (m, forward positive: the radii's drift changes
sign when the robot reverses) and ``Δψ`` (rad) the heading change, ``w`` the prior's. ``a`` (rad/m)
is the differential radii's drift, ``b`` the track's and mean radius's scale error on turns, ``c``
the mean radius's on distance. They are least-squares fits of ``Δψ_w - Δψ_s`` on ``(s_s, Δψ_s)``
and of ``s_w - s_s`` on ``s_s`` (the scans' values as regressors: the prior's own noise in them
would fit itself) over the recent path, each interval weighted by how long ago it was (``memory``
m of path); ``b`` is held towards 0 by a prior of ``scale_sigma`` (a log without turns does not fix
it). Each is used only where it stands out of its own uncertainty, measured from the intervals'
scatter about the fit (``significance``). :meth:`OdometryDrift.corrected` inverts the model on a
bridge's motion: ``s = s_w / (1 + c)``, ``Δψ = (Δψ_w - a s) / (1 + b)``, the chord scaled by
``s / s_w`` and turned by half the heading's correction (the heading error grows evenly along it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..config import Checked, param


@dataclass(frozen=True)
class OdometryDriftParams(Checked):
    """enabled: learn the drift and take it out of the gaps' bridges.
    memory: path length (m, > 0) over which an interval's weight falls to 1/e.
    min_path: path (m, ≥ 0) of registered intervals before the fits are used.
    scale_sigma: the prior's standard deviation of the heading's scale error ``b`` (≥ 0, a
        fraction: 0.02 is 2 % of every turn). 0, the default, keeps ``b`` at 0. On the Intel subset
        a prior of 0.02 fits that log's odometry's turns 1.0-1.2 % long (5 mrad on two of its
        gaps); taking that out moved the relations of the baseline by +2.4 mm and of the improved
        method by -0.4 mm: no sign that it helps. An odometry whose track width is in doubt may
        set it.
    heading_sigma: the standard deviation (rad, > 0) of one interval's ``Δψ_w - Δψ_s`` about the
        model at least (what weighs the prior on ``b`` against the intervals, and the floor of the
        scatter measured). 0.001: the 30 s corridor sample's intervals scatter by 0.6 mrad.
    distance_sigma: the same (m, > 0) for ``s_w - s_s``.
    max_heading_error, max_distance_error: an interval whose motions disagree by more than this
        (rad, m; > 0) is not an odometry drift (a slip, a bad match) and is left out.
    significance: each of ``a``, ``b`` and ``c`` is used only where it exceeds this many of its
        own standard deviations (≥ 0), from the scatter of the intervals about the fit: an odometry
        whose heading errs at random from interval to interval (the Intel subset's, 41 mrad in the
        median over 0.7 m) has no drift to learn.
    """

    enabled: bool = True
    memory: float = param(50.0, "m", gt=0.0, le=1e6)
    min_path: float = param(5.0, "m", ge=0.0, le=1e6)
    scale_sigma: float = param(0.0, "", ge=0.0, le=1.0)
    heading_sigma: float = param(0.001, "rad", gt=0.0, le=1.0)
    distance_sigma: float = param(0.001, "m", gt=0.0, le=1.0)
    max_heading_error: float = param(0.02, "rad", gt=0.0, le=1.0)
    max_distance_error: float = param(0.02, "m", gt=0.0, le=10.0)
    significance: float = param(3.0, "standard deviations", ge=0.0, le=100.0)


class RunningFit:
    """Weighted linear least squares ``e ≈ θᵀx`` over a stream, older rows discounted: the sums
    ``Σ w x xᵀ``, ``Σ w x e``, ``Σ w e²`` and ``Σ w``. Kept as Python floats: a row is added every
    sweep, a solve is asked for at a gap."""

    def __init__(self, size: int):
        self.size = size
        self._normal = [0.0] * (size * size)  # row-major
        self._moment = [0.0] * size
        self.square = 0.0
        self.count = 0.0

    @property
    def normal(self) -> np.ndarray:
        """``Σ w x xᵀ`` (size, size)."""
        return np.array(self._normal).reshape(self.size, self.size)

    @property
    def moment(self) -> np.ndarray:
        """``Σ w x e`` (size,)."""
        return np.array(self._moment)

    def add(self, x: tuple[float, ...], error: float, keep: float) -> None:
        """One row ``x`` (size floats) and its ``error``, after the sums so far are multiplied by
        ``keep`` (0..1)."""
        n, normal, moment = self.size, self._normal, self._moment
        for i in range(n):
            moment[i] = moment[i] * keep + x[i] * error
            for j in range(n):
                normal[i * n + j] = normal[i * n + j] * keep + x[i] * x[j]
        self.square = self.square * keep + error * error
        self.count = self.count * keep + 1.0

    def solve(self, prior: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray] | None:
        """``θ`` and its covariance. ``prior``: the diagonal added to the normal equations (a
        zero-mean prior on each parameter, as the row noise's variance over the parameter's);
        ``floor``: the rows' variance at least. The rows' variance is their scatter about the fit
        (the residual sum of squares over the rows' weight less the parameters). None where the
        rows are too few or do not fix ``θ``."""
        n = self.size
        if self.count <= n:
            return None
        normal = self.normal + np.diag(prior)
        try:
            inverse = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(inverse)) or np.any(np.diag(inverse) <= 0):
            return None
        moment = self.moment
        theta = inverse @ moment
        scatter = max(self.square - float(theta @ moment), 0.0) / (self.count - n)
        return theta, inverse * max(scatter, floor)


class OdometryDrift:
    """The running fits of the prior's drift (module docstring)."""

    def __init__(self, params: OdometryDriftParams):
        self.params = params
        self.heading = RunningFit(2)  # x = (s_s, Δψ_s), e = Δψ_w - Δψ_s
        self.distance = RunningFit(1)  # x = (s_s,), e = s_w - s_s
        self.path = 0.0  # m of registered intervals observed

    def observe(self, prior_motion: Sequence[float] | np.ndarray, scan_motion: Sequence[float] | np.ndarray) -> None:
        """One registered interval: the prior's motion and the scans' over it (x, y, yaw;
        base_link at its start, m and rad)."""
        p = self.params
        s_w, s_s, turn_s = float(prior_motion[0]), float(scan_motion[0]), float(scan_motion[2])
        heading = math.remainder(float(prior_motion[2]) - turn_s, 2.0 * math.pi)
        along = s_w - s_s
        if not (math.isfinite(s_s) and math.isfinite(turn_s) and math.isfinite(heading) and math.isfinite(along)):
            return
        keep = math.exp(-abs(s_s) / p.memory)
        if abs(heading) <= p.max_heading_error:
            self.heading.add((s_s, turn_s), heading, keep)
        if abs(along) <= p.max_distance_error:
            self.distance.add((s_s,), along, keep)
        self.path += abs(s_s)

    def drift(self) -> tuple[float, float, float] | None:
        """``(a, b, c)`` (module docstring: rad/m, rad/rad, m/m), each 0 where it does not stand out
        of its uncertainty; None before ``min_path`` m of intervals (or with the estimate off)."""
        p = self.params
        if not p.enabled or self.path < p.min_path:
            return None
        hold = (p.heading_sigma / p.scale_sigma) ** 2 if p.scale_sigma > 0 else 1e12  # 1e12: b held at 0
        heading = self.heading.solve(np.array([0.0, hold]), p.heading_sigma**2)
        distance = self.distance.solve(np.zeros(1), p.distance_sigma**2)
        a, b = self._used(heading, 2)
        (c,) = self._used(distance, 1)
        return a, b, c

    def _used(self, fit: tuple[np.ndarray, np.ndarray] | None, size: int) -> list[float]:
        """The parameters of ``fit`` that exceed ``significance`` of their standard deviations, 0 for the others."""
        if fit is None:
            return [0.0] * size
        theta, covariance = fit
        k = self.params.significance
        return [float(theta[i]) if theta[i] ** 2 > k * k * covariance[i, i] else 0.0 for i in range(size)]

    def corrected(self, motion: np.ndarray) -> np.ndarray:
        """``motion`` (x, y, yaw; base_link at its start) with the drift used taken out (module
        docstring); unchanged where none is."""
        found = self.drift()
        if found is None or found == (0.0, 0.0, 0.0):
            return motion
        a, b, c = found
        x, y, turn_w = (float(v) for v in motion[:3])
        s = x / (1.0 + c)
        turn = (turn_w - a * s) / (1.0 + b)
        half = 0.5 * (turn - turn_w)
        cos, sin = math.cos(half) / (1.0 + c), math.sin(half) / (1.0 + c)
        return np.array([cos * x - sin * y, sin * x + cos * y, turn])
