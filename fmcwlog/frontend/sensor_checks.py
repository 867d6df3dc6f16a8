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

Beside the per-sweep check the three sources vote over a sliding window (:class:`SensorVote`) of
the last ``vote_sweeps`` intervals between sweeps (1 s at 10 Hz): the distance the wheels say
(their ticks integrated between the two stamps, :mod:`.motion_prior`, which also takes ticks
republished faster than they are counted, a value repeated and then a jump, as valid input) and
the one Doppler says (its forward speed, the mean of the two sweeps' fits, times the interval).
Where they agree (within ``vote_distance`` plus ``vote_relative`` of the larger) nothing more is
done. Where they disagree, the scans are the third opinion: the window's last sweep is carried
into its first sweep's frame by each candidate motion, and the one that lands on the first
sweep's points (mean capped nearest-neighbour distance below ``witness_ratio`` of the other's)
wins; the other source is outvoted. It is not used (no Doppler fit, segmentation or fusion; or
no wheels in the fusion) for the sweeps while it is outvoted, which ends at the next window where
the two agree or the scans side with it. A window the scans cannot decide (a scene that fixes no
direction) keeps the last verdict. The per-sweep check still drops a flipped Doppler sign or
negated ticks for good, but only a source the vote does not back (outvoted in as many windows as
it agreed in, or, for the wheels, heading changes against the registered ones in turns), so that
held ticks are not dropped. A source outvoted in ``distrust_share`` of the judged windows is
distrusted: no calibration is estimated from the log (:mod:`.self_calibration`; ``fmcwlog
calibrate`` refuses, naming it), and the warning gives the counts ("scan matching agrees with
the wheel ticks in 160 of 194 checks; Doppler disagrees ..."). The vote costs a few Python float
operations a sweep; a KD-tree and two queries only in windows where the sources disagree.
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
    vote: whether the three sources vote over windows (:class:`SensorVote`); off, only the
        per-sweep check runs.
    vote_sweeps: intervals between sweeps in a vote's window (>= 2; long enough to span a hold
        of ticks republished faster than they are counted).
    vote_distance: two sources' distances over a window agree within this (m, >= 0) ...
    vote_yaw: ... their heading changes within this (rad, >= 0) ...
    vote_relative: ... plus this fraction of the larger of the two, in [0, 1].
    distrust_share: a source outvoted in at least this share of the judged windows (and in
        ``min_evidence`` of them) is distrusted for the calibration, in (0, 1].
    """

    min_speed: float = param(0.2, "m/s", ge=0, le=10)
    witness_ratio: float = param(0.7, "", gt=0, le=1)
    witness_min_gap: float = param(0.005, "m", ge=0, le=1)
    witness_cap: float = param(0.3, "m", gt=0, le=10)
    witness_points: int = param(256, "points", ge=10, le=1000000)
    min_evidence: int = param(10, "checks", ge=1, le=1000000)
    verdict_fraction: float = param(0.9, "", gt=0.5, le=1)
    max_checks: int = param(300, "checks", ge=0, le=1000000000)
    vote: bool = True
    vote_sweeps: int = param(10, "sweeps", ge=2, le=10000)
    vote_distance: float = param(0.05, "m", ge=0, le=100)
    vote_yaw: float = param(0.05, "rad", ge=0, le=10)
    vote_relative: float = param(0.25, "", ge=0, le=1)
    distrust_share: float = param(0.2, "", gt=0, le=1)



# dt (s), wheels' x, y, yaw (m, m, rad), Doppler's distance (m), the registered heading change (rad; NaN: none)
_Interval = tuple[float, float, float, float, float, float]


@dataclass
class SensorVote:
    """Doppler, the wheels and scan matching compared over sliding windows (module docstring).

    Each window spans the last ``vote_sweeps`` intervals between sweeps (at least half of them at a
    log's start or after a gap). Where the wheels' and Doppler's distances (and so their motions)
    agree, nothing more is done. Where they disagree, scan matching is the third opinion: the
    window's last sweep is carried into its first sweep's frame by each candidate motion, and the
    one whose points land closer to the first sweep's (:func:`_misfit` below ``witness_ratio`` of
    the other's) is the motion the scans agree with; the other source is outvoted for the sweeps
    until a window finds the two agreeing (or the scans side with it); a window the scans cannot
    decide keeps the last verdict (:meth:`_undecided`). Scan matching here is the sweeps themselves, not the improved
    method's registration, whose soft prior is the fused twist (a scaled Doppler would pull it along).

    :meth:`sweep` records a sweep's points and Doppler forward speed; :meth:`interval` each interval
    as the wheels saw it, and judges the window that ends there. ``outvoted`` is the source the last
    judged window outvoted (None: none). Python floats and numpy only, the same under both kernels.
    """

    mount: np.ndarray
    params: CheckParams = field(default_factory=CheckParams)
    outvoted: str | None = None
    judged: int = 0  # windows judged (moving, all three present)
    checks: int = 0  # ... where the wheels and Doppler disagreed and the scans were asked
    agree: dict[str, int] = field(default_factory=lambda: {DOPPLER: 0, WHEELS: 0})  # the scans sided with it
    against: dict[str, int] = field(default_factory=lambda: {DOPPLER: 0, WHEELS: 0})  # windows outvoted
    outvoted_s: dict[str, float] = field(default_factory=lambda: {DOPPLER: 0.0, WHEELS: 0.0})  # time outvoted (s)
    sweep_lean: int = 0  # per-sweep scan checks won by Doppler less those won by the wheels (SensorChecks)
    turns_against_wheels: int = 0  # turning windows where the wheels' heading change and the scans' disagree
    _sweeps: dict[float, tuple[float, np.ndarray]] = field(default_factory=dict)  # stamp -> (speed, points)
    _window: list[tuple[float, _Interval]] = field(default_factory=list)  # (start stamp, interval)

    def sweep(self, stamp: float, speed: float, xy: np.ndarray) -> None:
        """The base's forward speed (m/s) Doppler measured over the sweep at ``stamp`` (s), and its
        points (N, 2) in the lidar frame (m), a strided subset kept."""
        if math.isfinite(speed):
            self._sweeps[stamp] = (speed, xy[:: max(1, len(xy) // self.params.witness_points)])
        keep = self.params.vote_sweeps + 2
        while len(self._sweeps) > keep:
            del self._sweeps[min(self._sweeps)]

    def interval(self, t_prev: float, stamp: float, wheels: np.ndarray | None, scan_yaw: float | None) -> None:
        """The interval from the sweep at ``t_prev`` to the one at ``stamp`` (s), base_link's motion
        over it by the wheels (x, y, yaw in its frame at ``t_prev``; None: no ticks) and the heading
        change registration found (rad; None: not registered). Judges the window of consecutive
        intervals that ends here."""
        dt = stamp - t_prev
        a, b = self._sweeps.get(t_prev), self._sweeps.get(stamp)
        if wheels is None or a is None or b is None or not dt > 0:
            self._window.clear()  # a window spans consecutive intervals only
            self.outvoted = None
            return
        x, y, yaw = (float(w) for w in wheels[:3])
        turn = math.nan if scan_yaw is None else scan_yaw
        self._window.append((t_prev, (dt, x, y, yaw, 0.5 * (a[0] + b[0]) * dt, turn)))
        if len(self._window) > self.params.vote_sweeps:
            del self._window[0]
        if 2 * len(self._window) >= self.params.vote_sweeps:
            self.outvoted = self._judge(stamp)

    def _judge(self, stamp: float) -> str | None:
        """The source the window outvotes, if any; counts the verdict."""
        p = self.params
        dts, xs, _, yaws, dops, turns = zip(*(iv for _, iv in self._window))
        t, d_whl, d_dop = math.fsum(dts), math.fsum(xs), math.fsum(dops)
        if max(abs(d_dop), abs(d_whl)) < p.min_speed * t:
            return None
        self.judged += 1
        y_whl, y_scan = math.fsum(yaws), math.fsum(turns)  # NaN where a sweep was not registered
        if max(abs(y_whl), abs(y_scan)) > p.vote_yaw and not _near(y_whl, y_scan, p.vote_yaw, p.vote_relative):
            self.turns_against_wheels += 1  # e.g. left and right swapped: the distance agrees, the turn not
        if _near(d_whl, d_dop, p.vote_distance, p.vote_relative):
            self.agree[DOPPLER] += 1
            self.agree[WHEELS] += 1
            return None
        self.checks += 1
        first = self._sweeps.get(self._window[0][0])
        last = self._sweeps.get(stamp)
        if first is None or last is None or len(first[1]) < 10 or len(last[1]) < 10:
            return self._undecided()
        m_whl, m_dop = self._motions()
        from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
        tree = cKDTree(first[1])
        e_whl, e_dop = (self._misfit(tree, last[1], m) for m in (m_whl, m_dop))
        if e_dop < p.witness_ratio * e_whl and e_whl - e_dop > p.witness_min_gap:
            winner, loser = DOPPLER, WHEELS
        elif e_whl < p.witness_ratio * e_dop and e_dop - e_whl > p.witness_min_gap:
            winner, loser = WHEELS, DOPPLER
        else:
            return self._undecided()
        self.agree[winner] += 1
        self.against[loser] += 1
        self.outvoted_s[loser] += self._window[-1][1][0]
        return loser

    def _undecided(self) -> str | None:
        """The wheels and Doppler disagree but the scans cannot tell (a scene that fixes no direction):
        the source outvoted last stays outvoted, for these sweeps too; with none outvoted yet, the one
        outvoted more often so far, on a tie the one the per-sweep scan checks sided against more
        (``sweep_lean``), else Doppler (the wheels are the prior its fit is gated by, :mod:`.egomotion`).
        Counted as time outvoted, not as a window outvoted."""
        loser = self.outvoted
        if loser is None:
            lean = self.against[DOPPLER] - self.against[WHEELS] or -self.sweep_lean
            loser = WHEELS if lean < 0 else DOPPLER
        self.outvoted_s[loser] += self._window[-1][1][0]
        return loser

    def _motions(self) -> tuple[np.ndarray, np.ndarray]:
        """base_link's motion over the window (x, y, yaw in its frame at the window's start) by the
        wheels, and by Doppler's distances along the wheels' arcs."""
        m_whl, m_dop = np.zeros(3), np.zeros(3)
        for _, (dt, x, y, yaw, d, _) in self._window:
            m_whl = compose(m_whl, np.array([x, y, yaw]))
            m_dop = compose(m_dop, se2_exp(d / dt, 0.0, yaw / dt, np.array(dt)))
        return m_whl, m_dop

    def _misfit(self, tree: cKDTree, pts: np.ndarray, base: np.ndarray) -> float:
        """Mean distance (m), each capped at ``witness_cap``, from ``pts`` (the window's last sweep,
        lidar frame) carried by base_link's motion ``base`` into the first sweep's lidar frame, to
        the first sweep's points (as :meth:`SensorChecks._misfit`)."""
        lidar = compose(compose(inverse(self.mount), base), self.mount)
        cap = self.params.witness_cap
        d, _ = tree.query(transform_points(lidar, pts), k=1, distance_upper_bound=cap)
        return float(np.mean(np.minimum(d, cap)))

    def may_drop(self, source: str) -> bool:
        """Whether the per-sweep check may drop ``source`` for good: it was outvoted in as many windows
        as it agreed in (with the other source, or with the scans where they were asked), or, for the
        wheels, their heading changes disagreed with the scans' in turning windows."""
        if source == WHEELS and self.turns_against_wheels >= 3:
            return True
        return self.against[source] >= self.agree[source]

    def distrusted(self) -> str | None:
        """The source outvoted in ``distrust_share`` of the judged windows (and ``min_evidence`` of them)."""
        p = self.params
        for source in (DOPPLER, WHEELS):
            n = self.against[source]
            if n >= p.min_evidence and n >= p.distrust_share * self.judged:
                return source
        return None

    def evidence(self, source: str, prior_name: str) -> str:
        """The numbers against ``source``: with whom scan matching agreed, in how many checks."""
        other = WHEELS if source == DOPPLER else DOPPLER
        name = {DOPPLER: "Doppler", WHEELS: f"the {prior_name}"}
        won = self.against[source]
        return (f"scan matching agrees with {name[other]} in {won} of {self.checks} checks; {name[source]} "
                f"disagrees (outvoted in {won} of {self.judged} windows of {self.params.vote_sweeps} sweeps, "
                f"{self.outvoted_s[source]:.1f} s in all)")

    def summary(self) -> dict:
        """The vote's counts, for ``run.json``."""
        return {"windows": self.judged, "checks": self.checks, "doppler_outvoted": self.against[DOPPLER],
                "wheels_outvoted": self.against[WHEELS],
                "doppler_outvoted_s": round(self.outvoted_s[DOPPLER], 3),
                "wheels_outvoted_s": round(self.outvoted_s[WHEELS], 3)}


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
    vote: SensorVote = field(init=False)
    dropped_at: dict[str, float] = field(default_factory=dict)  # source -> seconds since the first sweep
    scanner_at_fault: bool = False  # the scans' frame is not the calibrated one (:meth:`exonerate_wheels`)
    scanner_alternative: str | None = None  # a scanner fault that explains the log as well as the wheels' (said with it)
    _t0: float | None = None
    _prev: tuple[float, np.ndarray] | None = None  # stamp (s) and points (lidar frame) of the last sweep
    _prev_tree: cKDTree | None = None

    def __post_init__(self) -> None:
        self.vote = SensorVote(self.mount, self.params)
        (a00, a01), (a10, a11) = self.design.tolist()
        self._columns = ((a00, a10), (a01, a11))  # the design's columns: the lidar velocity per unit v, per unit ω

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
        decision = self._judge_sweep(prev, stamp, xy, ego, wheel_twist, z_pred)
        if self.scanner_at_fault and decision == DOPPLER:
            decision = KEEP  # the scans that sided with Doppler share its frame's fault
        if not self.params.vote:
            return decision
        self.vote.sweep_lean = self.counts.won_doppler - self.counts.won_wheels
        self._vote_doppler(stamp, xy, ego, wheel_twist)
        if wheel_twist is None or not _finite(ego.v_sensor) or self.vote.outvoted is None:
            return decision
        return WHEELS if self.vote.outvoted == DOPPLER else DOPPLER  # for as long as the vote says so

    def _judge_sweep(self, prev: tuple[float, np.ndarray] | None, stamp: float, xy: np.ndarray, ego: EgoMotion,
                     wheel_twist: tuple[float, float] | None, z_pred: np.ndarray | None) -> str:
        """The per-sweep check (module docstring): :meth:`judge` without the vote."""
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

    def _vote_doppler(self, stamp: float, xy: np.ndarray, ego: EgoMotion,
                      wheel_twist: tuple[float, float] | None) -> None:
        """Doppler's forward speed over the sweep for the vote: the fit free of the wheels' gate, solved
        for ``v`` with the wheels' ``ω`` (0 without them) taking the lever arm's share."""
        fit = ego.unconstrained if ego.unconstrained is not None else ego
        zx, zy = fit.v_sensor.tolist()
        omega = float(wheel_twist[1]) if wheel_twist is not None else 0.0
        (c0x, c0y), (c1x, c1y) = self._columns
        norm = c0x * c0x + c0y * c0y
        if norm > 0.0:
            self.vote.sweep(stamp, (c0x * (zx - c1x * omega) + c0y * (zy - c1y * omega)) / norm, xy)

    def interval(self, t_prev: float, stamp: float, wheels: np.ndarray | None, scan_yaw: float | None) -> None:
        """The interval between two sweeps as the wheels (base_link's x, y, yaw) and registration (the
        heading change) saw it, for the vote (:meth:`SensorVote.interval`). Call once per sweep after
        :meth:`judge`, in time order."""
        if self.params.vote:
            self.vote.interval(t_prev, stamp, wheels if self.use_wheels else None, scan_yaw)
            if self.scanner_at_fault and self.vote.outvoted == WHEELS:
                self.vote.outvoted = None

    def calibration_veto(self, prior_name: str) -> str | None:
        """Why no calibration may be estimated from this log: scan matching contradicted one source
        in too many windows (:meth:`SensorVote.distrusted`); None when it did not."""
        source = self.vote.distrusted() if self.params.vote else None
        if source is None or (source == WHEELS and self.scanner_at_fault):
            return None
        name = "Doppler" if source == DOPPLER else f"the {prior_name}"
        return f"scan matching contradicts {name}, which it distrusts: {self.vote.evidence(source, prior_name)}"

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
        vote = not p.vote or self.vote.may_drop
        if (self.use_wheels and not self.scanner_at_fault
                and c.won_doppler >= p.min_evidence and c.won_doppler >= p.verdict_fraction * decided
                and c.gross_vs_wheels >= p.verdict_fraction * c.won_doppler and (vote is True or vote(WHEELS))):
            self.use_wheels = False
            self.dropped_at[WHEELS] = t
        if (self.use_doppler and c.won_wheels >= p.min_evidence and c.won_wheels >= p.verdict_fraction * decided
                and c.opposed_vs_doppler >= p.verdict_fraction * c.won_wheels and (vote is True or vote(DOPPLER))):
            self.use_doppler = False
            self.dropped_at[DOPPLER] = t

    def _vote_warnings(self, prior_name: str) -> list[str]:
        if not self.params.vote:
            return []
        return [w for w in _vote_warnings_of(self.vote, self.dropped_at, prior_name)
                if not (self.scanner_at_fault and w.startswith(f"the {prior_name} outvoted"))]

    # -- attribution: a scanner whose frame is not the calibrated one (:mod:`.mirror_check`) -------------
    def exonerate_wheels(self) -> None:
        """The scans fit the wheels' motion once read in another frame (mirrored, or turned by π):
        Doppler and the scans, measured in that frame, share its fault, so neither their per-sweep
        verdicts nor the vote may drop or outvote the wheels from now on; wheels dropped already are
        taken back (the counts keep what was seen); no warning blames the wheels."""
        self.scanner_at_fault = True
        self.use_wheels = True
        self.dropped_at.pop(WHEELS, None)
        if self.vote.outvoted == WHEELS:
            self.vote.outvoted = None

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
            "vote": self.vote.summary(),
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
                       f"improved method stopped using the {prior_name} (the baseline and wheel_odometry still do)"
                       + (f"; {self.scanner_alternative}" if self.scanner_alternative else ""))
        voted = self._vote_warnings(prior_name)
        out += voted
        if (not self.dropped_at and not voted and not self.scanner_at_fault and c.moving
                and c.disputed > max(0.05 * c.moving, 5)):
            out.append(f"Doppler and the {prior_name} disagreed by more than the gate in {c.disputed} of {c.moving} "
                       f"moving sweeps ({c.opposed} opposed); scan matching sided with Doppler in {c.won_doppler}, "
                       f"with the {prior_name} in {c.won_wheels}, undecided in {c.undecided}: check the mount "
                       "calibration and the sensors")
        return out


def _near(a: float, b: float, tol: float, relative: float) -> bool:
    """``a`` and ``b`` within ``tol`` plus ``relative`` of the larger magnitude (False with a NaN)."""
    return abs(a - b) <= tol + relative * max(abs(a), abs(b))


def _vote_warnings_of(vote: SensorVote, dropped: dict[str, float], prior_name: str) -> list[str]:
    """A line per source the vote outvoted in ``min_evidence`` windows (and not dropped for good)."""
    out = []
    for source in (DOPPLER, WHEELS):
        if vote.against[source] >= vote.params.min_evidence and source not in dropped:
            name = "Doppler" if source == DOPPLER else f"the {prior_name}"
            out.append(f"{name} outvoted: {vote.evidence(source, prior_name)}; the improved method did not use "
                       f"{name} where it was outvoted")
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
