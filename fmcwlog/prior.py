"""The motion prior as a track of poses that can be read at any time.

Fed incrementally, in log order, by wheel ticks (integrated with the
calibration, paper eq. 9 and 13, see :mod:`fmcwlog.odometry`) or by the poses
of an Odometry topic. Only the last few seconds are kept: memory does not grow
with the log.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .geometry import between, interpolate_poses
from .odometry import WheelCalibration, body_increments, integrate_arcs


class PoseTrack:
    """Time-stamped poses (odometry frame) with interpolation; stamps in seconds."""

    def __init__(self, keep_seconds: float = 5.0):
        self.keep = keep_seconds
        self._t: deque[float] = deque()
        self._p: deque[np.ndarray] = deque()
        self._ticks: tuple[int, int] | None = None
        self._arrays: tuple[np.ndarray, np.ndarray] | None = None  # cached for pose_at
        self.repeated_stamps = 0

    @property
    def latest_time(self) -> float:
        return self._t[-1] if self._t else -np.inf

    def __len__(self) -> int:
        return len(self._t)

    def add_pose(self, t: float, pose: np.ndarray) -> bool:
        """Append a pose; a stamp equal to the last is skipped (counted), one going back is an error."""
        if self._t and t <= self._t[-1]:
            if t == self._t[-1]:
                self.repeated_stamps += 1
                return False
            raise ValueError(f"motion prior stamps go backwards ({t:.9f} s after {self._t[-1]:.9f} s)")
        self._t.append(t)
        self._p.append(np.asarray(pose, dtype=float))
        self._arrays = None
        while len(self._t) > 2 and self._t[-1] - self._t[1] > self.keep:
            self._t.popleft()
            self._p.popleft()
        return True

    def add_ticks(self, t: float, left: int, right: int, calib: WheelCalibration) -> bool:
        """Integrate one encoder reading (cumulative counts) onto the last pose, exactly along an arc."""
        if self._ticks is None:
            self._ticks = (left, right)
            return self.add_pose(t, np.zeros(3))
        if self._t and t == self._t[-1]:
            self.repeated_stamps += 1
            return False
        ds, dth = body_increments(np.array([self._ticks[0], left]), np.array([self._ticks[1], right]), calib)
        pose = integrate_arcs(ds, dth, self._p[-1])[-1]
        ok = self.add_pose(t, pose)
        self._ticks = (left, right)
        return ok

    def pose_at(self, t: float | np.ndarray) -> np.ndarray:
        """Interpolated pose(s); clamped to the first/last pose outside the kept span."""
        if self._arrays is None:
            self._arrays = (np.fromiter(self._t, float, len(self._t)), np.stack(list(self._p)))
        return interpolate_poses(np.asarray(t, dtype=float), *self._arrays)

    def delta(self, t0: float, t1: float) -> np.ndarray:
        """Motion of the body from ``t0`` to ``t1`` in its frame at ``t0``."""
        p = self.pose_at(np.array([t0, t1]))
        return between(p[0], p[1])
