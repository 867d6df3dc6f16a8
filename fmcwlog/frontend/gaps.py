"""Gaps in the sweeps: found, bridged by the motion prior, and matched from there with a wider search.

A USB hiccup or a driver restart leaves seconds of a log without sweeps while the wheel ticks go on;
a sweep whose every return is a no-return (an obstructed window, every target beyond range) is
dropped when the log is read and leaves the same hole. Across a gap the front end cannot hold its
last twist: the robot may have turned, stopped or started. A gap is bridged instead by

- the motion prior over it: the wheels' odometry (or an Odometry topic) integrated from the last
  sweep to this one, as the baseline's prior always is; without one, the last twist held (the fused
  Doppler and wheels', or the scan-matched one);
- an uncertainty that grows with the gap (:func:`bridge_covariance`): along the path a fraction of
  the distance (the wheels' radii), in yaw per metre travelled, across the path the heading's
  uncertainty times the distance; without a prior, the hold's speeds times the gap;
- the next sweep matched from the bridged pose with a correlative search over a window of a few of
  those standard deviations (:func:`gap_window`, at least the recovery's, at most ``max_linear_window``
  and ``max_angular_window_deg``), then the ICP, its soft prior that uncertainty
  (:func:`gap_prior_information`) instead of one sweep's Doppler motion;
- the back end: the bridged sweep's pose covariance carries the bridge's, so the odometry edge across
  the gap is as loose as the bridge is.

Measured on the 30 s corridor sample with the sweeps of a window across its corner removed (the ticks
continue): improved ATE 41, 204 and 199 cm for gaps of 2, 4 and 6 s with the last twist held across
the gap (0.9 cm without a gap); the numbers with the bridge are in the tests
(``tests/integration/test_sweep_gaps.py``).

A gap is a time between two sweeps longer than ``min_periods`` sweep periods (the calibration's
``scan_rate``, else the median of the recent intervals); it is counted and reported (a warning,
``run.json``'s ``gaps``, the report's header) whether or not it is bridged.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..config import Checked, param
from ..kernels.correlative import CorrelativeParams
from ..kernels.occupancy import OccupancyGrid
from .odometry_drift import OdometryDriftParams
from .twist_fusion import WheelNoise


@dataclass(frozen=True)
class GapParams(Checked):
    """min_periods: a time between two sweeps longer than this many sweep periods is a gap
        (sweep periods, > 1).
    bridge: bridge a gap by the motion prior and match the next sweep with a search that widens
        with it (False: the last twist is held across it, as between any two sweeps).
    window_sigmas: the search's half-width, in standard deviations of the bridge (> 0).
    max_linear_window: the search's half-width in x and y at most (m).
    max_angular_window_deg: and in yaw (deg).
    max_mahalanobis: a match further than this from the bridged pose, in the bridge's standard
        deviations (Mahalanobis distance over x, y, yaw), is another peak (a bare corridor's walls
        seen from a stretch the map does not hold yet): the bridged pose stands (> 0). The bridge's
        deviations are the wheel noise model's; a robot's odometry can be worse (the Intel subset's:
        at 4 its front end alone scores 0.586 m on the relations, at 8 0.115 m; the corridor
        sample's gaps the same at either).
    seen_only: the ICP after a gap bridged by the motion prior matches only the points that fall,
        at the bridged pose, where the occupancy grid has seen (:func:`seen_before`). The rest is
        ground the robot reached during the gap, and the nearest map points of a wall beyond the
        map's end are that end's: they pull the pose back along the wall, and the pose stays there
        (on the 30 s corridor sample with 4 s of sweeps removed at its corner, 11 cm back along the
        new corridor with every point, where the wheels' bridge was 3 cm from the truth: ATE 3.4
        cm, 0.9 cm with the seen points).
    drift: the motion prior's heading and distance drift, learnt while the scans match and taken
        out of the bridge (:class:`~.odometry_drift.OdometryDriftParams`).
    """

    min_periods: float = param(3.0, "sweep periods", gt=1.0, le=1000.0)
    bridge: bool = True
    window_sigmas: float = param(3.0, "", gt=0.0, le=20.0)
    max_linear_window: float = param(3.0, "m", gt=0.0, le=20.0)
    max_angular_window_deg: float = param(45.0, "deg", gt=0.0, le=180.0)
    max_mahalanobis: float = param(8.0, "standard deviations", gt=0.0, le=1000.0)
    seen_only: bool = True
    drift: OdometryDriftParams = field(default_factory=OdometryDriftParams)


BY_PRIOR = "the motion prior"
BY_HOLD = "the last twist held (no motion prior: a turn inside a gap is not known)"


@dataclass(frozen=True)
class SweepGap:
    """A gap: ``start`` (s, log time) where the first missing sweep was due (the last sweep's stamp
    plus one period), ``length`` (s) until the next sweep less that period, and what bridged it
    (:data:`BY_PRIOR` or :data:`BY_HOLD`)."""

    start: float
    length: float
    bridged_by: str = BY_PRIOR

    def to_json(self) -> dict[str, float | str]:
        return {"start_s": round(self.start, 6), "length_s": round(self.length, 6), "bridged_by": self.bridged_by}


class GapFinder:
    """Watches the sweeps' stamps, in order, for gaps. ``scan_rate``: sweeps per second (Hz) where
    the calibration gives it; else the period is the median of the last :attr:`RECENT` intervals
    (recomputed every :attr:`EVERY` sweeps once that many are in), and no gap is found before
    :attr:`MIN_SEEN` intervals are. Not their shortest: a log subsampled unevenly (a
    CARMEN log that kept a scan every few seconds, one sometimes 0.3 s after another) would make
    most of its intervals gaps, and bridge every sweep on its odometry (the Intel subset's
    relations 0.017 -> 0.67 m)."""

    RECENT = 101
    EVERY = 10
    MIN_SEEN = 5

    def __init__(self, min_periods: float, scan_rate: float | None = None, bridged_by: str = BY_PRIOR):
        self.min_periods = min_periods
        self.bridged_by = bridged_by
        self.period = 1.0 / scan_rate if scan_rate else math.inf  # s
        self._given = bool(scan_rate)
        self._last: float | None = None
        self._recent: deque[float] = deque(maxlen=self.RECENT)  # the last intervals (s), where no rate is given
        self._seen = 0  # intervals seen
        self.gaps: list[SweepGap] = []

    def observe(self, stamp: float) -> float:
        """The next sweep's ``stamp`` (s): the length (s) of the gap before it, 0 where there is none."""
        last, self._last = self._last, stamp
        if last is None:
            return 0.0
        dt = stamp - last
        gap = dt > self.min_periods * self.period and (self._given or self._seen >= self.MIN_SEEN)
        if gap:
            self.gaps.append(SweepGap(last + self.period, dt - self.period, self.bridged_by))
        if not self._given and dt > 0:
            self._recent.append(dt)
            self._seen += 1
            if self._seen <= self.RECENT or self._seen % self.EVERY == 0:
                self.period = statistics.median(self._recent)
        return dt - self.period if gap else 0.0

    def warning(self, scan_topic: str) -> str | None:
        """One line on the gaps found, None without any."""
        if not self.gaps:
            return None
        longest = max(self.gaps, key=lambda g: g.length)
        total = sum(g.length for g in self.gaps)
        return (f"{len(self.gaps)} gap{'s' if len(self.gaps) > 1 else ''} in the sweeps on {scan_topic} "
                f"(no sweep, or none with a usable point, for more than {self.min_periods:g} sweep periods; "
                f"{total:.1f} s in all, the longest {longest.length:.1f} s at {longest.start:.3f} s): "
                f"bridged by {self.bridged_by}; the poses across them are as good as that is")


def bridge_covariance(motion: np.ndarray | None, gap: float, noise: WheelNoise) -> np.ndarray:
    """Covariance (3, 3) over (along, across, yaw) of a pose bridged across ``gap`` (s), in the frame
    of the pose before it (m², rad²). ``motion``: the prior's motion over the gap (x, y, yaw; None
    without a prior, then the hold's ``hold_speed`` and ``hold_yaw_rate`` over the gap)."""
    gap = max(float(gap), 0.0)
    if motion is None:
        s_along = noise.hold_speed * gap
        s_yaw = noise.hold_yaw_rate * gap
        s_across = s_along
    else:
        d = float(np.hypot(motion[0], motion[1]))
        s_along = max(noise.speed_rel * d, noise.speed_min * gap)
        s_yaw = max(noise.yaw_rate_per_speed * d, noise.yaw_rate_min * gap)
        # the heading's error grows along the way: half of it, on average, over the distance
        s_across = max(0.5 * d * math.sin(min(s_yaw, 0.5 * math.pi)), noise.speed_min * gap)
    return np.diag([s_along**2, s_across**2, s_yaw**2])


def to_map(covariance: np.ndarray, yaw: float) -> np.ndarray:
    """A covariance over (along, across, yaw) of a frame turned by ``yaw`` (rad) as one over (x, y, yaw)."""
    c, s = math.cos(yaw), math.sin(yaw)
    a = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return a @ covariance @ a.T


def gap_prior_information(covariance_map: np.ndarray, residual_sigma: float) -> np.ndarray:
    """The ICP's soft prior (3, 3) on a bridged pose: the inverse of its covariance (map frame)
    in the units of the ICP's normal equations (scaled by ``residual_sigma²``, m²)."""
    return np.linalg.inv(covariance_map) * residual_sigma**2


def gap_window(covariance: np.ndarray, base: CorrelativeParams, p: GapParams) -> CorrelativeParams:
    """The correlative search after a gap: ``base`` (the recovery's) with its half-widths
    ``window_sigmas`` standard deviations of the bridge (the larger of along and across, and yaw),
    at least ``base``'s and at most ``max_linear_window`` / ``max_angular_window_deg``; a window of
    metres takes a third level of the branch and bound."""
    s_xy = math.sqrt(max(covariance[0, 0], covariance[1, 1]))
    s_yaw = math.sqrt(covariance[2, 2])
    linear = min(max(p.window_sigmas * s_xy, base.linear_window), max(p.max_linear_window, base.linear_window))
    angular = min(max(math.degrees(p.window_sigmas * s_yaw), base.angular_window_deg),
                  max(p.max_angular_window_deg, base.angular_window_deg))
    levels = max(base.levels, 3) if linear > 1.0 else base.levels
    return dataclasses.replace(base, linear_window=linear, angular_window_deg=angular, levels=levels)


def seen_before(points_map: np.ndarray, grid: OccupancyGrid) -> np.ndarray:
    """Which points (N, 2; map frame, m) fall where ``grid`` has seen, free or occupied: the point's
    cell or one of its 8 neighbours observed (the neighbours cover a pose a cell off)."""
    if not len(points_map) or grid.observed.size == 0:
        return np.zeros(len(points_map), bool)
    seen = grid.observed
    rc = grid.cell_of(points_map)
    out = np.zeros(len(points_map), bool)
    h, w = seen.shape
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r, c = rc[:, 0] + dr, rc[:, 1] + dc
            inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            out[inside] |= seen[r[inside], c[inside]]
    return out


def within_bridge(pose: np.ndarray, bridged: np.ndarray, covariance: np.ndarray, limit: float) -> bool:
    """Whether ``pose`` lies within ``limit`` standard deviations (Mahalanobis distance) of the
    ``bridged`` pose under the bridge's ``covariance`` (3, 3; map frame)."""
    e = np.array([pose[0] - bridged[0], pose[1] - bridged[1], math.remainder(float(pose[2] - bridged[2]), 2 * math.pi)])
    return float(e @ np.linalg.solve(covariance, e)) <= limit**2
