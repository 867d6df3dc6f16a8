"""Simulation parameters, with the paper's Table 1 as the sensor defaults.

Every field can be set from a TOML/YAML/JSON config file (``[sensor]``,
``[robot]``, ``[run]`` tables) or from the command line as
``--set sensor.range_sigma=0.03``. Units are SI: metres, seconds, radians
(angles in config files are in degrees where the name ends in ``_deg``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ..config import Checked, apply_to_dataclass, check_params, naming, param, parse_set_option, read_config_file, toml_table
from ..errors import ConfigError

# Ranges: what a planar robot LiDAR and a small ground robot can physically be, wide enough
# for any real one, and bounded on every side so that a typo cannot make the simulator run
# for days or allocate without limit (``--set sensor.scan_rate=1e6`` would make the default 30 s
# log 3e7 sweeps).
# points a sweep: an Ouster OS1-128 at 1024 columns is 131 072; 20 sweeps cast at once hold ~40
# arrays of this many float64s each (1.4 GB at the bound)
MAX_POINTS_PER_SWEEP = 150_000
MAX_SEED = 2**32 - 1  # numpy seeds any non-negative integer; 32 bits is what every tool prints and takes


@dataclass(frozen=True)
class SensorConfig(Checked):
    """The FMCW LiDAR (paper Table 1) and where it sits on the robot."""

    # 100 nm - 10 um: from UV to far-infrared lasers; only recorded in the calibration
    wavelength: float = param(1550e-9, "m", ge=1e-7, le=1e-5)
    fov_deg: float = param(270.0, "deg", gt=0.0, le=360.0)  # total field of view, centred on the sensor's x axis
    # beam spacing; 0.01 deg is 27 001 beams in 270 deg, denser than any planar scanner
    resolution_deg: float = param(0.25, "deg", ge=0.01, le=45.0)
    max_range: float = param(30.0, "m", gt=0.0, le=1000.0)  # beams with nothing closer give no return
    min_range: float = param(0.1, "m", ge=0.0, le=1000.0)  # closer returns are dropped (blind zone)
    range_sigma: float = param(0.02, "m", ge=0.0, le=10.0)  # Gaussian range noise
    range_resolution: float = param(0.02, "m", ge=0.0, le=10.0)  # reported ranges are multiples of this (0: exact)
    doppler_resolution: float = param(0.1, "m/s", ge=0.0, le=10.0)  # reported velocities are multiples of this
    doppler_sigma: float = param(0.02, "m/s", ge=0.0, le=10.0)  # noise added before quantisation
    # spinning scanners turn at 5-40 Hz; 100 Hz bounds the sweep count (duration x rate)
    scan_rate: float = param(10.0, "Hz", ge=0.1, le=100.0)
    dropout: float = param(0.002, "", ge=0.0, lt=1.0)  # probability that a beam with a target returns nothing
    mount_x: float = param(0.35, "m", ge=-10.0, le=10.0)  # lidar origin in base_link: on the robot
    mount_y: float = param(0.0, "m", ge=-10.0, le=10.0)
    mount_yaw_deg: float = param(0.0, "deg", ge=-180.0, le=180.0)
    # Multi-ring mode (rings > 1): each beam direction fires this many rings at once, evenly spaced in
    # elevation from ring_min_deg to ring_max_deg (a 3-D FMCW LiDAR: Aeva Aeries II, 16 rings like a
    # VLP-16's -15..+15 deg); they hit walls (vertical, of unbounded height), movers (people 1.75 m, carts
    # 1 m tall) and the floor mount_height below the sensor. 1: the planar sensor, z = 0, no ring field.
    rings: int = param(1, "", ge=1, le=128)
    ring_min_deg: float = param(-15.0, "deg", ge=-60.0, le=60.0)
    ring_max_deg: float = param(15.0, "deg", ge=-60.0, le=60.0)
    mount_height: float = param(0.5, "m", gt=0.0, le=10.0)  # the lidar's origin above the floor

    @property
    def n_beams(self) -> int:
        """Beams per sweep: the field of view over the beam spacing, both ends included (1081 by default)."""
        return int(round(self.fov_deg / self.resolution_deg)) + 1

    @property
    def sweep_duration(self) -> float:
        """Seconds one sweep takes: its share of the rotation period (270/360 of 100 ms)."""
        return (self.fov_deg / 360.0) / self.scan_rate

    @property
    def ring_elevations(self) -> tuple[float, ...]:
        """The rings' elevations above the sensor's plane, lowest first (rad); (0,) for the planar sensor."""
        if self.rings == 1:
            return (0.0,)
        step = (self.ring_max_deg - self.ring_min_deg) / (self.rings - 1)
        return tuple(math.radians(self.ring_min_deg + step * i) for i in range(self.rings))

    @property
    def mount(self) -> tuple[float, float, float]:
        """The lidar's pose in base_link, ``(x, y, yaw)`` in m, m and rad."""
        return (self.mount_x, self.mount_y, math.radians(self.mount_yaw_deg))


@dataclass(frozen=True)
class RobotConfig(Checked):
    """Car-like chassis with encoders on the (unsteered) rear wheels."""

    speed: float = param(1.0, "m/s", gt=0.0, le=10.0)  # cruise speed along the route (a ground robot indoors)
    acceleration: float = param(0.5, "m/s^2", gt=0.0, le=10.0)  # at start and stop (10 m/s^2 is about 1 g)
    wheelbase: float = param(0.5, "m", gt=0.0, le=10.0)  # rear to front axle
    track_width: float = param(0.45, "m", gt=0.0, le=10.0)  # between the rear wheels
    wheel_radius: float = param(0.1, "m", gt=0.0, le=5.0)  # the calibrated (nominal) radius
    # true radius = nominal * (1 + error); a wheel 50 % off its calibration is a broken robot
    wheel_radius_error_left: float = param(0.005, "", ge=-0.5, le=0.5)
    wheel_radius_error_right: float = param(0.003, "", ge=-0.5, le=0.5)
    slip_sigma: float = param(0.002, "", ge=0.0, le=0.5)  # relative wheel slip per encoder interval (white)
    ticks_per_revolution: int = param(4096, "", ge=1, le=2**24)  # up to a 24-bit absolute encoder
    encoder_rate: float = param(50.0, "Hz", ge=1.0, le=1000.0)  # also the ground-truth odometry rate


@dataclass(frozen=True)
class RunConfig(Checked):
    """The run: its length (s), seed, first stamp (ns since the epoch) and the log's compression."""

    # a day; the default sensor writes about 0.2 GB of log per hour (zstd)
    duration: float = param(30.0, "s", gt=0.0, le=86400.0)
    seed: int = param(0, "", ge=0, le=MAX_SEED)
    # ns since the epoch of the log's first stamp; ROS 2 stamps hold int32 seconds (2038), so the
    # start must leave room for the run: 2e18 ns is in 2033
    start_time_ns: int = param(1_700_000_000_000_000_000, "ns", ge=0, le=2_000_000_000_000_000_000)
    compression: str = param("zstd", choices=("zstd", "lz4", ""))  # "": none


@dataclass(frozen=True)
class SimConfig:
    """Every parameter of ``fmcwlog record``: the ``[sensor]``, ``[robot]`` and ``[run]`` tables."""

    sensor: SensorConfig = field(default_factory=SensorConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def as_dict(self) -> dict[str, Any]:
        """The tables as nested dicts, in the fields' units."""
        return asdict(self)

    def recorded(self) -> dict[str, Any]:
        """:meth:`as_dict` as the ``fmcwlog.sim`` record's ``config`` holds it: a planar sensor's
        without the ring parameters (:data:`RING_KEYS`), which it does not use, so that a planar log
        is the bytes it was before the simulator had rings."""
        doc = self.as_dict()
        if self.sensor.rings == 1:
            doc["sensor"] = {k: v for k, v in doc["sensor"].items() if k not in RING_KEYS}
        return doc

    def validate(self) -> SimConfig:
        """Each field's range (:func:`fmcwlog.config.check_params`) and what the fields must satisfy together."""
        check_params(self)
        if self.sensor.min_range >= self.sensor.max_range:
            raise ConfigError(f"sensor.min_range = {self.sensor.min_range:g} m must be below "
                              f"sensor.max_range = {self.sensor.max_range:g} m")
        s = self.sensor
        if s.rings > 1 and s.ring_min_deg >= s.ring_max_deg:
            raise ConfigError(f"sensor.ring_min_deg = {s.ring_min_deg:g} deg must be below sensor.ring_max_deg = "
                              f"{s.ring_max_deg:g} deg with sensor.rings = {s.rings}")
        if s.rings * s.n_beams > MAX_POINTS_PER_SWEEP:
            raise ConfigError(f"sensor.rings = {s.rings} x {s.n_beams} beams (sensor.fov_deg / sensor.resolution_deg) "
                              f"is {s.rings * s.n_beams} points a sweep, above {MAX_POINTS_PER_SWEEP}")
        if int(self.run.duration * self.sensor.scan_rate + 1e-9) < 1:  # the recorder's count of sweeps
            raise ConfigError(f"run.duration = {self.run.duration:g} s is shorter than one sweep "
                              f"(1 / sensor.scan_rate = {1 / self.sensor.scan_rate:g} s): the log would hold none")
        return self

    def toml(self) -> str:
        """Every parameter as TOML, each with its unit and range; ``record --config`` takes it back."""
        head = ["# fmcwlog record parameters: every one, with its unit and valid range.",
                "# Use: fmcwlog record --config FILE (or change one with --set SECTION.NAME=VALUE).", ""]
        return "\n".join(head + toml_table("sensor", self.sensor) + toml_table("robot", self.robot)
                         + toml_table("run", self.run)).rstrip() + "\n"


RING_KEYS = ("rings", "ring_min_deg", "ring_max_deg", "mount_height")
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


def simulation_config(config_file: Path | None = None, set_items: tuple[str, ...] = (), *, duration: float | None = None,
                      seed: int | None = None, speed: float | None = None) -> SimConfig:
    """The recording's parameters: the defaults, then ``config_file`` (TOML, YAML or JSON with
    ``[sensor]``, ``[robot]``, ``[run]`` tables), then ``duration`` (s), ``seed`` and ``speed`` (m/s)
    where given (None: not given), then each ``--set`` item (``TABLE.NAME=VALUE``); each value
    checked against its range. Raises :class:`~fmcwlog.errors.ConfigError`, naming the file for an
    error in its own values."""
    cfg = SimConfig()
    if config_file:
        with naming(config_file):  # each of the file's values checked against its range, so that an error names it
            cfg = check_params(apply_overrides(cfg, read_config_file(config_file)))
    flags: dict[str, dict] = {"run": {}, "robot": {}}
    if duration is not None:
        flags["run"]["duration"] = duration
    if seed is not None:
        flags["run"]["seed"] = seed
    if speed is not None:
        flags["robot"]["speed"] = speed
    cfg = apply_overrides(cfg, flags)
    return apply_overrides(cfg, parse_set_option(set_items)).validate()
