"""Sanity checks of the sensors against each other: Doppler, the wheels, and the scans as arbiter.

Not in the paper. The faults looked for are the sensors' own: a Doppler sign flipped on every
point, wheel ticks counting the wrong way (left and right swapped, or negated), a mount far off.
Each leaves the log self-consistent in one source and at odds with the others:

- The Doppler fit is held within ``doppler_prior_gate`` of the wheels' prediction
  (:func:`fmcwlog.frontend.egomotion.fit_sensor_velocity`); when the gate throws away a
  larger static consensus than the one it keeps, Doppler and the wheels *dispute* the
  sweep. A flipped Doppler sign (or wheels counting backwards) makes every moving sweep a
  dispute, with the two velocities opposed; swapped wheels dispute every sharp turn.
- Who is right is decided by the static structure: the sweep's points are carried into
  the previous sweep's frame by each candidate motion (the wheels', and the one Doppler's
  unconstrained fit gives) and the candidate whose points land closer to the previous
  sweep's (mean capped nearest-neighbour distance below ``witness_ratio`` times the other's)
  wins. Scan matching measures the motion independently of both sensors; a scene that
  fixes no direction (a bare corridor) leaves the check undecided.
- Per sweep, the winner is used (the unconstrained Doppler fit without the wheels, or the
  wheels without Doppler); when one source has lost ``verdict_fraction`` of at least
  ``min_evidence`` decided checks, and the disagreements are gross (opposite signs, or
  more than half the magnitude off; for Doppler, the forward velocity reversed: the only
  Doppler fault with that signature is its sign), the improved method stops using that
  source for the rest of the log, and says so once with the numbers. A Doppler that
  loses without a reversed velocity points at the mount instead; that is for the
  calibration check (:mod:`.self_calibration`), not a reason to drop Doppler.

The cost is nothing on sweeps without a dispute; a dispute costs one KD-tree over the
previous sweep and two queries, and at most ``max_checks`` per log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..config import Checked, param
from ..geometry import compose, inverse, transform_points
from .deskew import se2_exp
from .egomotion import EgoMotion
from .twist_fusion import WheelNoise, fuse_twist, wheel_covariance

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree

KEEP, DOPPLER, WHEELS = "keep", "doppler", "wheels"  # per-sweep decisions


@dataclass(frozen=True)
class CheckParams(Checked):
    """Parameters of the sensor checks.

    min_speed: sweeps where neither the wheels nor Doppler say the robot (or the lidar)
        moves faster than this are not judged (m/s, >= 0; a standing robot says nothing
        about signs).
    witness_ratio: a candidate motion wins the scan check when its mean (capped)
        nearest-neighbour distance is below this fraction of the other's, in (0, 1].
    witness_min_gap: ... and below it by at least this much (m, >= 0).
    witness_cap: each nearest-neighbour distance counts at most this much (m, > 0).
    witness_points: at most this many of the sweep's points are carried (a strided subset, >= 10).
    min_evidence: decided scan checks against a source before it is dropped (>= 1).
    verdict_fraction: the share of decided checks a source must lose to be dropped, in (0.5, 1].
    max_checks: scan checks per log at most (>= 0; bounds the cost on a log full of disputes).
    """

    min_speed: float = param(0.2, "m/s", ge=0, le=10)
    witness_ratio: float = param(0.7, "", gt=0, le=1)
    witness_min_gap: float = param(0.005, "m", ge=0, le=1)
    witness_cap: float = param(0.3, "m", gt=0, le=10)
    witness_points: int = param(256, "points", ge=10, le=1000000)
    min_evidence: int = param(10, "checks", ge=1, le=1000000)
    verdict_fraction: float = param(0.9, "", gt=0.5, le=1)
    max_checks: int = param(300, "checks", ge=0, le=1000000000)



@dataclass
class _Counts:
    moving: int = 0  # sweeps judged (moving, both sources present)
    disputed: int = 0  # ... where the gate hid a larger consensus
    opposed: int = 0  # ... where Doppler's velocity points against the wheels' prediction
    won_doppler: int = 0  # scan checks won by Doppler's motion
    won_wheels: int = 0
    undecided: int = 0
    gross_vs_wheels: int = 0  # Doppler won and the wheels were grossly off (sign or magnitude)
    opposed_vs_doppler: int = 0  # the wheels won and Doppler's velocity was reversed


@dataclass
class SensorChecks:
    """Doppler against the wheels, sweep by sweep (see the module docstring).

    ``mount`` (lidar in base_link: m, m, rad), ``design`` = :func:`.twist_fusion.doppler_design`.
    ``use_doppler`` / ``use_wheels`` turn False when a source is dropped.
    """

    mount: np.ndarray
    design: np.ndarray
    params: CheckParams = field(default_factory=CheckParams)
    noise: WheelNoise = field(default_factory=WheelNoise)
    use_doppler: bool = True
    use_wheels: bool = True
    counts: _Counts = field(default_factory=_Counts)
    dropped_at: dict[str, float] = field(default_factory=dict)  # source -> seconds since the first sweep
    _t0: float | None = None
    _prev: tuple[float, np.ndarray] | None = None  # stamp (s) and points (lidar frame) of the last sweep
    _prev_tree: cKDTree | None = None

    def judge(self, stamp: float, xy: np.ndarray, ego: EgoMotion, wheel_twist: tuple[float, float] | None,
              z_pred: np.ndarray | None = None) -> str:
        """Which source to believe for this sweep: :data:`KEEP` (the gated fit), :data:`DOPPLER`
        (``ego.unconstrained``, without the wheels) or :data:`WHEELS` (without Doppler).

        ``stamp`` (s): the sweep's; ``xy`` (N, 2): its points in the lidar frame (m), kept as the
        next call's previous sweep; ``ego``: its Doppler fit with the wheels' prior
        (:func:`.egomotion.fit_sensor_velocity`); ``wheel_twist``: the wheels' ``(v, ω)`` over the
        sweep (m/s, rad/s), None without wheels. ``z_pred``: ``design @ wheel_twist`` (the lidar's velocity
        the wheels predict) where the caller has it already. Call once per sweep, in time order."""
        prev, self._prev, self._prev_tree = self._prev, (stamp, xy), None
        if self._t0 is None:
            self._t0 = stamp
        if wheel_twist is None or not _finite(ego.v_sensor):
            return KEEP
        x_w = np.asarray(wheel_twist, dtype=float)
        if z_pred is None:
            z_pred = self.design @ x_w
        free = ego.unconstrained
        seen = ego.v_sensor if free is None else free.v_sensor
        n_pred = _norm(z_pred)
        if max(abs(x_w[0]), n_pred, _norm(seen)) < self.params.min_speed:
            return KEEP
        c = self.counts
        c.moving += 1
        if free is None or not _finite(free.v_sensor):
            return KEEP
        c.disputed += 1
        opposed = bool(free.v_sensor @ z_pred < -0.5 * _norm(free.v_sensor) * n_pred)
        c.opposed += opposed
        if prev is None or c.won_doppler + c.won_wheels + c.undecided >= self.params.max_checks:
            return KEEP if ego.n_inliers >= 0.5 * free.n_inliers else WHEELS
        x_d = self._doppler_twist(free, x_w)
        winner = self._witness(prev, stamp, xy, x_w, x_d)
        if winner == DOPPLER:
            c.won_doppler += 1
            c.gross_vs_wheels += _gross(x_w, x_d)
        elif winner == WHEELS:
            c.won_wheels += 1
            c.opposed_vs_doppler += opposed
        else:
            c.undecided += 1
        self._verdicts(stamp)
        if winner == DOPPLER:
            return DOPPLER
        if ego.n_inliers >= 0.5 * free.n_inliers:
            return KEEP  # the gated fit is a static consensus of its own (a crowd outvoted it)
        return WHEELS  # the gate kept a poor fit: no Doppler for this sweep

    def _doppler_twist(self, free: EgoMotion, x_w: np.ndarray) -> np.ndarray:
        """``(v, ω)`` from Doppler alone where it observes them, the wheels (barely weighted) elsewhere."""
        c_d = free.covariance + np.eye(2) * 1e-6
        return fuse_twist(free.v_sensor, c_d, self.design, x_w, wheel_covariance(x_w, self.noise) * 1e4).twist

    def _witness(self, prev: tuple[float, np.ndarray], stamp: float, xy: np.ndarray,
                 x_w: np.ndarray, x_d: np.ndarray) -> str | None:
        """The candidate twist whose motion carries this sweep onto the previous one; None if unclear."""
        t_prev, xy_prev = prev
        dt = stamp - t_prev
        if len(xy_prev) < 10 or len(xy) < 10 or not dt > 0:
            return None
        if self._prev_tree is None:
            from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
            self._prev_tree = cKDTree(xy_prev)
        pts = xy[:: max(1, len(xy) // self.params.witness_points)]
        d_w, d_d = (self._misfit(pts, x, dt) for x in (x_w, x_d))
        p = self.params
        if d_d < p.witness_ratio * d_w and d_w - d_d > p.witness_min_gap:
            return DOPPLER
        if d_w < p.witness_ratio * d_d and d_d - d_w > p.witness_min_gap:
            return WHEELS
        return None

    def _misfit(self, pts: np.ndarray, twist: np.ndarray, dt: float) -> float:
        """Mean distance (m), each capped at ``witness_cap``, from ``pts`` carried into the previous
        lidar frame to the previous sweep. Capped, so that movers and newly seen structure
        weigh no more than a clear miss; a mean, not a median, because in a corridor most
        points lie on walls along the motion and fit either candidate: what tells them apart
        is the minority across it (door recesses, far walls)."""
        base = se2_exp(float(twist[0]), 0.0, float(twist[1]), np.array(dt))
        lidar = compose(compose(inverse(self.mount), base), self.mount)
        assert self._prev_tree is not None
        cap = self.params.witness_cap
        d, _ = self._prev_tree.query(transform_points(lidar, pts), k=1, distance_upper_bound=cap)
        return float(np.mean(np.minimum(d, cap)))

    def _verdicts(self, stamp: float) -> None:
        c, p = self.counts, self.params
        decided = c.won_doppler + c.won_wheels
        t = stamp - (self._t0 or stamp)
        if (self.use_wheels and c.won_doppler >= p.min_evidence and c.won_doppler >= p.verdict_fraction * decided
                and c.gross_vs_wheels >= p.verdict_fraction * c.won_doppler):
            self.use_wheels = False
            self.dropped_at[WHEELS] = t
        if (self.use_doppler and c.won_wheels >= p.min_evidence and c.won_wheels >= p.verdict_fraction * decided
                and c.opposed_vs_doppler >= p.verdict_fraction * c.won_wheels):
            self.use_doppler = False
            self.dropped_at[DOPPLER] = t

    def summary(self) -> dict:
        """The counts and verdicts, for ``run.json``."""
        c = self.counts
        return {
            "moving_sweeps": c.moving,
            "disputed_sweeps": c.disputed,
            "opposed_sweeps": c.opposed,
            "scan_checks": {"sided_with_doppler": c.won_doppler, "sided_with_wheels": c.won_wheels,
                            "undecided": c.undecided},
            "doppler_dropped_at_s": self.dropped_at.get(DOPPLER),
            "wheels_dropped_at_s": self.dropped_at.get(WHEELS),
        }

    def warnings(self, prior_name: str) -> list[str]:
        """One line per finding, with its numbers; none when the sources agree. ``prior_name``
        names the wheels' source (``wheel ticks``, ``odometry``)."""
        c = self.counts
        checked = c.won_doppler + c.won_wheels + c.undecided
        out = []
        if DOPPLER in self.dropped_at:
            out.append(f"the Doppler sign looks flipped: in {c.opposed} of {c.moving} moving sweeps until "
                       f"{self.dropped_at[DOPPLER]:.1f} s the static world's Doppler put the lidar's velocity "
                       f"against the prediction of the {prior_name}, and scan matching sided with the {prior_name} in "
                       f"{c.won_wheels} of {checked} checks; from then on the improved method stopped using "
                       "Doppler (no Doppler ego-motion or segmentation)")
        if WHEELS in self.dropped_at:
            out.append(f"the {prior_name} disagree with Doppler and with the scans (counting the wrong way, or left "
                       f"and right swapped?): in {c.disputed} of {c.moving} moving sweeps until "
                       f"{self.dropped_at[WHEELS]:.1f} s they disputed Doppler ({c.opposed} opposed), and scan "
                       f"matching sided with Doppler in {c.won_doppler} of {checked} checks; from then on the "
                       f"improved method stopped using the {prior_name} (the baseline and wheel_odometry still do)")
        if not self.dropped_at and c.moving and c.disputed > max(0.05 * c.moving, 5):
            out.append(f"Doppler and the {prior_name} disagreed by more than the gate in {c.disputed} of {c.moving} "
                       f"moving sweeps ({c.opposed} opposed); scan matching sided with Doppler in {c.won_doppler}, "
                       f"with the {prior_name} in {c.won_wheels}, undecided in {c.undecided}: check the mount "
                       "calibration and the sensors")
        return out


def _gross(loser: np.ndarray, winner: np.ndarray) -> bool:
    """The loser's ``(v, ω)`` has a sign opposite to the winner's, or is off by more than half of it."""
    (va, wa), (vb, wb) = loser, winner
    opposite = (va * vb < 0 and min(abs(va), abs(vb)) > 0.1) or (wa * wb < 0 and min(abs(wa), abs(wb)) > 0.1)
    off = abs(va - vb) > 0.5 * max(abs(va), abs(vb), 0.2) or abs(wa - wb) > 0.5 * max(abs(wa), abs(wb), 0.3)
    return bool(opposite or off)


def _finite(v: np.ndarray) -> bool:
    """``np.all(np.isfinite(v))`` of a small array, from its elements as Python numbers."""
    return all(map(math.isfinite, v.ravel().tolist()))


def _norm(v: np.ndarray) -> float:
    """``np.linalg.norm`` of a float64 vector: its operations (``sqrt(v · v)``) without its dispatch."""
    return math.sqrt(v.dot(v))
