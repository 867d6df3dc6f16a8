"""The robot's motion along its route and its rear-wheel encoders.

``base_link`` is the midpoint of the rear axle. On an Ackermann chassis the
rear wheels are not steered, so the rear axle moves like a differential
drive's (paper eq. 13): it never slides sideways, its yaw rate is
``ω = v·κ`` and the wheels at ``±b/2`` roll ``s ∓ (b/2)·Δθ``. Encoders count
``ticks_per_revolution`` per turn of a wheel (paper eq. 9); the wheels'
true radii differ from the calibrated ones and they slip a little, so
odometry integrated with the calibration drifts, as on a real robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import RobotConfig
from .route import Route, SpeedProfile


@dataclass(frozen=True)
class BodyState:
    """Ground truth of ``base_link`` at N times: pose in ``map`` and twist in ``base_link``."""

    t: np.ndarray  # (N,) s from the start of the log
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray  # unwrapped, rad
    v: np.ndarray  # forward speed, m/s
    omega: np.ndarray  # yaw rate, rad/s
    s: np.ndarray  # distance travelled along the route, m

    @property
    def poses(self) -> np.ndarray:
        """(N, 3) ``(x, y, yaw)`` of base_link in ``map`` (m, m, rad; yaw unwrapped)."""
        return np.stack([self.x, self.y, self.yaw], -1)


class Chassis:
    """Where the robot is at any time, and what its encoders read."""

    def __init__(self, route: Route, cfg: RobotConfig):
        self.route = route
        self.cfg = cfg
        self.profile = SpeedProfile(cfg.speed, cfg.acceleration, np.inf if route.loop else route.total_length)
        self._yaw0 = float(route.at(np.zeros(1))[2][0])

    def state(self, t: np.ndarray) -> BodyState:
        """Ground truth of base_link at times ``t`` (N,, s from the start of the log)."""
        t = np.asarray(t, dtype=float)
        s, v, _ = self.profile.distance_speed_accel(t)
        x, y, yaw, kappa = self.route.at(s)
        return BodyState(t, x, y, yaw, v, v * kappa, s)

    def wheel_travel(self, state: BodyState) -> tuple[np.ndarray, np.ndarray]:
        """Distance (m, (N,) each, left and right) each rear wheel's contact point has rolled since the start."""
        dyaw = state.yaw - self._yaw0
        half = 0.5 * self.cfg.track_width
        return state.s - half * dyaw, state.s + half * dyaw

    def encoder_counts(self, state: BodyState, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Cumulative int64 counts of the left and right encoders at ``state.t``.

        Each interval's wheel rotation is its rolled distance over the *true*
        radius, times ``1 + slip`` with white slip of ``slip_sigma``.
        """
        c = self.cfg
        r_left = c.wheel_radius * (1.0 + c.wheel_radius_error_left)
        r_right = c.wheel_radius * (1.0 + c.wheel_radius_error_right)
        counts = []
        for travel, radius in zip(self.wheel_travel(state), (r_left, r_right)):
            d = np.diff(travel, prepend=travel[:1])
            slip = 1.0 + c.slip_sigma * rng.standard_normal(d.shape)
            angle = np.cumsum(d * slip) / radius  # rad
            counts.append(np.floor(angle / (2.0 * np.pi) * c.ticks_per_revolution).astype(np.int64))
        return counts[0], counts[1]
