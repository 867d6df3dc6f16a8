"""The motion prior as a track of poses that can be read at any time.

Fed incrementally, in log order, by wheel ticks (integrated with the
calibration, paper eq. 9 and 13, see :mod:`fmcwlog.frontend.odometry`) or by the poses
of an Odometry topic. Only the last few seconds are kept (in a buffer shifted
when full): memory does not grow with the log.

Ticks counted at a lower rate than they are published (an encoder read at 10 Hz, republished at
50 Hz: a count repeated, then a jump) are valid input: a reading that repeats the last stored
counts less than ``hold_seconds`` after it is a sample held, not a measurement of standing still,
and is not stored, so the motion between two counts is spread over the time between them. A robot
that stands keeps its pose: a repeat ``hold_seconds`` after the last stored reading is stored.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import between, compose, interpolate_poses, inverse, unwrapped_yaw
from ..types import WheelCalibration
from .deskew_wheels import yaw_rate_spread
from .odometry import body_increments, integrate_arc, ticks_step

MAX_HOLD_S = 120.0  # s: the longest gap in the sweeps the track is kept for (:attr:`PoseTrack.hold_from`)


class PoseTrack:
    """Time-stamped poses (odometry frame) with interpolation; stamps in seconds."""

    def __init__(self, keep_seconds: float = 5.0, hold_seconds: float = 0.25):
        self.keep = keep_seconds
        self.hold_from = np.inf  # s: poses from this time on are kept too (the last sweep's stamp, across a gap); inf: none
        self.hold = hold_seconds
        self._t = np.empty(256)
        self._p = np.empty((256, 3))
        self._k = np.full((256, 2), np.nan)  # cumulative ticks (left, right) at each pose; NaN from poses
        self._n = 0
        self._ticks: tuple[int, int] | None = None
        self.repeated_stamps = 0
        self._yaw: np.ndarray | None = None  # unwrapped yaw of the stored poses (pose_at), None: to compute

    @property
    def latest_time(self) -> float:
        return float(self._t[self._n - 1]) if self._n else -np.inf

    def __len__(self) -> int:
        return self._n

    def add_pose(self, t: float, pose: np.ndarray | tuple[float, float, float]) -> bool:
        """Append a pose (3 values); a stamp equal to the last is skipped (counted), one going back is an error."""
        n = self._n
        if n and t <= self._t[n - 1]:
            if t == self._t[n - 1]:
                self.repeated_stamps += 1
                return False
            raise ValueError(f"motion prior stamps go backwards ({t:.9f} s after {self._t[n - 1]:.9f} s)")
        if n == len(self._t):  # full: drop what is older than the kept window, or grow
            old = int(np.searchsorted(self._t[:n], self._keep_from())) - 1
            if old > 0:
                self._t[: n - old] = self._t[old:n]
                self._p[: n - old] = self._p[old:n]
                self._k[: n - old] = self._k[old:n]
                n -= old
            else:
                self._t = np.concatenate([self._t, np.empty(n)])
                self._p = np.concatenate([self._p, np.empty((n, 3))])
                self._k = np.concatenate([self._k, np.full((n, 2), np.nan)])
        self._t[n] = t
        self._p[n] = pose
        self._yaw = None
        self._k[n] = np.nan
        self._n = n + 1
        return True

    def _keep_from(self) -> float:
        """The time (s) from which the poses are kept: the last ``keep`` seconds, and from
        :attr:`hold_from` on (at most :data:`MAX_HOLD_S` back), so that a gap in the sweeps longer than
        ``keep`` can still be bridged from the last sweep before it."""
        latest = float(self._t[self._n - 1])
        return min(latest - self.keep, max(self.hold_from, latest - MAX_HOLD_S))

    def add_ticks(self, t: float, left: int, right: int, calib: WheelCalibration) -> bool:
        """Integrate one encoder reading (cumulative counts) onto the last pose, exactly along an arc."""
        if self._ticks is None:
            self._ticks = (left, right)
            ok = self.add_pose(t, np.zeros(3))
        else:
            if self._n and t == self._t[self._n - 1]:
                self.repeated_stamps += 1
                return False
            if (left, right) == self._ticks and self._n >= 2 and t - self._t[self._n - 1] < self.hold:
                # the same counts again within a hold (module docstring)
                return False
            x0, y0, th0 = self._p[self._n - 1].tolist()
            step = ticks_step(x0, y0, th0, int(left) - int(self._ticks[0]), int(right) - int(self._ticks[1]), calib)
            if step is None:  # counts beyond int64, or a pose not finite: the array functions' own cases
                ds, dth = body_increments(np.array([self._ticks[0], left]), np.array([self._ticks[1], right]), calib)
                ok = self.add_pose(t, integrate_arc(ds[0], dth[0], self._p[self._n - 1]))
            else:
                ok = self.add_pose(t, step)
            self._ticks = (left, right)
        if ok:
            self._k[self._n - 1] = (left, right)
        return ok

    def ticks_between(self, t0: float, t1: float) -> tuple[float, float] | None:
        """Ticks each wheel turned from ``t0`` to ``t1`` (interpolated linearly; left, right),
        None without ticks there. Counts are exact below 2**53 ticks."""
        n = self._n
        if n < 2 or self._ticks is None:  # no ticks fed (poses from an Odometry topic)
            return None
        k = np.interp([t0, t1], self._t[:n], self._k[:n, 0]), np.interp([t0, t1], self._t[:n], self._k[:n, 1])
        return float(k[0][1] - k[0][0]), float(k[1][1] - k[1][0])

    def pose_at(self, t: float | np.ndarray) -> np.ndarray:
        """Interpolated pose(s); clamped to the first/last pose outside the kept span."""
        if self._yaw is None:  # the track's unwrapped yaw, kept until the next pose comes
            self._yaw = unwrapped_yaw(self._p[: self._n])
        return interpolate_poses(np.asarray(t, dtype=float), self._t[: self._n], self._p[: self._n], self._yaw)

    def knots(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The track over ``[t0, t1]`` (s), as base_link's motion from ``t0``: times (K,) s after ``t0``
        (0, the stored stamps strictly inside, ``t1 - t0``) and poses (K, 3) (m, m, rad) in the body
        frame at ``t0``. None where the track does not cover the interval (it starts after ``t0`` or
        ends before ``t1``) or ``t1 <= t0``."""
        n = self._n
        if n < 2 or not (t1 > t0) or self._t[0] > t0 or self._t[n - 1] < t1:
            return None
        stamps = self._t[:n]
        inner = stamps[int(np.searchsorted(stamps, t0, side="right")):int(np.searchsorted(stamps, t1, side="left"))]
        times = np.concatenate([[t0], inner, [t1]])
        poses = self.pose_at(times)
        return times - t0, compose(inverse(poses[0]), poses)

    def yaw_rate_spread(self, t0: float, t1: float) -> float:
        """The spread (largest less smallest, rad/s) of the yaw rates between the stored poses from
        the last at or before ``t0`` to the first at or after ``t1``; infinity where two share a time
        or fewer than two are stored. :meth:`knots` interpolates within those intervals, so its
        segments' rates are among these: a spread below a threshold here is below it there."""
        n = self._n
        if n < 2:
            return math.inf
        stamps = self._t[:n]
        i0 = max(int(np.searchsorted(stamps, t0, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(stamps, t1, side="left")), n - 1)
        return yaw_rate_spread(stamps[i0:i1 + 1].tolist(), self._p[i0:i1 + 1, 2].tolist())

    def delta(self, t0: float, t1: float) -> np.ndarray:
        """Motion of the body from ``t0`` to ``t1`` in its frame at ``t0``."""
        p = self.pose_at(np.array([t0, t1]))
        return between(p[0], p[1])
