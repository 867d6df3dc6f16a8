"""Simulation parameters, with the paper's Table 1 as the sensor defaults.

Every field can be set from a TOML/YAML/JSON config file (``[sensor]``,
``[robot]``, ``[run]`` tables) or from the command line as
``--set sensor.range_sigma=0.03``. Units are SI: metres, seconds, radians
(angles in config files are in degrees where the name ends in ``_deg``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from ..config import apply_to_dataclass
from ..errors import ConfigError


@dataclass(frozen=True)
class SensorConfig:
    """The FMCW LiDAR (paper Table 1) and where it sits on the robot."""

    wavelength: float = 1550e-9  # m
    fov_deg: float = 270.0  # total field of view, centred on the sensor's x axis
    resolution_deg: float = 0.25  # beam spacing
    max_range: float = 30.0  # m; beams with nothing closer give no return
    min_range: float = 0.1  # m; closer returns are dropped (blind zone)
    range_sigma: float = 0.02  # m, Gaussian range noise
    range_resolution: float = 0.02  # m, reported ranges are multiples of this
    doppler_resolution: float = 0.1  # m/s, reported velocities are multiples of this
    doppler_sigma: float = 0.02  # m/s, noise added before quantisation
    scan_rate: float = 10.0  # Hz
    dropout: float = 0.002  # probability that a beam with a target returns nothing
    mount_x: float = 0.35  # m, lidar origin in base_link
    mount_y: float = 0.0  # m
    mount_yaw_deg: float = 0.0

    @property
    def n_beams(self) -> int:
        return int(round(self.fov_deg / self.resolution_deg)) + 1

    @property
    def sweep_duration(self) -> float:
        """Seconds one sweep takes: its share of the rotation period (270/360 of 100 ms)."""
        return (self.fov_deg / 360.0) / self.scan_rate

    @property
    def mount(self) -> tuple[float, float, float]:
        return (self.mount_x, self.mount_y, math.radians(self.mount_yaw_deg))


@dataclass(frozen=True)
class RobotConfig:
    """Car-like chassis with encoders on the (unsteered) rear wheels."""

    speed: float = 1.0  # m/s cruise speed along the route
    acceleration: float = 0.5  # m/s^2 at start and stop
    wheelbase: float = 0.5  # m, rear to front axle
    track_width: float = 0.45  # m, between the rear wheels
    wheel_radius: float = 0.1  # m, the calibrated (nominal) radius
    wheel_radius_error_left: float = 0.005  # true radius = nominal * (1 + error)
    wheel_radius_error_right: float = 0.003
    slip_sigma: float = 0.002  # relative wheel slip per encoder interval (white)
    ticks_per_revolution: int = 4096
    encoder_rate: float = 50.0  # Hz, also the ground-truth odometry rate


@dataclass(frozen=True)
class RunConfig:
    duration: float = 30.0  # s
    seed: int = 0
    start_time_ns: int = 1_700_000_000_000_000_000  # the log's first stamp
    compression: str = "zstd"


@dataclass(frozen=True)
class SimConfig:
    sensor: SensorConfig = field(default_factory=SensorConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def validate(self) -> SimConfig:
        s, r, u = self.sensor, self.robot, self.run
        checks = [
            (u.duration > 0, "run.duration must be positive"),
            (0 < s.fov_deg <= 360, "sensor.fov_deg must be in (0, 360]"),
            (s.resolution_deg > 0, "sensor.resolution_deg must be positive"),
            (s.max_range > s.min_range >= 0, "sensor.max_range must exceed sensor.min_range >= 0"),
            (s.range_sigma >= 0 and s.doppler_sigma >= 0, "noise sigmas must be >= 0"),
            (s.range_resolution >= 0 and s.doppler_resolution >= 0, "resolutions must be >= 0"),
            (s.scan_rate > 0, "sensor.scan_rate must be positive"),
            (0 <= s.dropout < 1, "sensor.dropout must be in [0, 1)"),
            (r.speed > 0 and r.acceleration > 0, "robot.speed and robot.acceleration must be positive"),
            (r.track_width > 0 and r.wheel_radius > 0 and r.wheelbase > 0, "robot dimensions must be positive"),
            (r.ticks_per_revolution > 0, "robot.ticks_per_revolution must be positive"),
            (r.encoder_rate > 0, "robot.encoder_rate must be positive"),
            (u.compression in ("zstd", "lz4", ""), "run.compression must be zstd, lz4 or empty"),
        ]
        for ok, why in checks:
            if not ok:
                raise ConfigError(why)
        return self


_SECTIONS = ("sensor", "robot", "run")


def apply_overrides(cfg: SimConfig, overrides: dict[str, dict[str, Any]]) -> SimConfig:
    """A copy of ``cfg`` with ``{section: {name: value}}`` applied (values coerced and checked)."""
    parts = {"sensor": cfg.sensor, "robot": cfg.robot, "run": cfg.run}
    for section, values in overrides.items():
        if section not in _SECTIONS:
            raise ConfigError(f"unknown section [{section}] (known: {', '.join(_SECTIONS)})")
        if not isinstance(values, dict):
            raise ConfigError(f"[{section}] must be a table of parameters")
        parts[section] = apply_to_dataclass(parts[section], values, section)
    return SimConfig(**parts)
