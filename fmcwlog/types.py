"""The data that crosses layers: what a log's sensors give, what the robot is, what a method makes.

Plain frozen dataclasses and constants, no I/O: the readers in :mod:`fmcwlog.io` make the inputs,
the front ends (:mod:`fmcwlog.frontend`) turn them into :class:`SweepResult`, the back end and the
output writers take those. Frames follow ROS REP 105: ``base_link`` (the rear axle's middle,
x forward), ``lidar`` (the sensor, placed in ``base_link`` by ``Calibration.mount``), and each
method's own ``<method>/odom``. Units are SI throughout: m, rad, s (ns for stamps), m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The trajectories fmcwlog writes, by name.
IMPROVED = "improved"
BASELINE = "baseline"
WHEEL_ODOMETRY = "wheel_odometry"  # the motion prior's own trajectory, written beside the methods'
METHOD_NAMES = (IMPROVED, BASELINE)  # the methods: each builds a map
SEGMENTING_METHODS = (IMPROVED,)  # the methods that judge points moving or static

MAX_CLOCK_GAP_S = 60.0  # s: the scan and motion-prior clocks may differ by driver start-up, not more


@dataclass(frozen=True)
class WheelCalibration:
    """Rear-axle calibration.

    wheel_radius_left, wheel_radius_right: rolling radii ``r_L``, ``r_R`` (m).
    track_width: distance ``b`` between the rear wheels' contact points (m), eq. 10.
    ticks_per_revolution: encoder pulses per wheel revolution ``k`` (eq. 9).
    """

    wheel_radius_left: float
    wheel_radius_right: float
    track_width: float
    ticks_per_revolution: int


@dataclass(frozen=True)
class Calibration:
    """What processing knows of the robot: wheels (None if not given) and the lidar mounting.

    max_range: the sensor's rated range (m), scan_rate: sweeps per second (Hz); None where the
    record does not give them (``scan_rate`` 0 counts as not given). upside_down: the sensor is
    rolled by π about its x axis (``lidar_upside_down``): its scan is mirrored, each point (x, y) of
    its frame is (x, -y) in an upright sensor frame at the same x, y, yaw, where processing reads it
    (:class:`fmcwlog.io.inputs.LogInputs`); Doppler and point times are unchanged.
    """

    wheels: WheelCalibration | None
    mount: tuple[float, float, float]  # lidar pose in base_link: m, m, rad
    doppler_resolution: float | None  # m/s
    range_sigma: float | None  # m
    max_range: float | None = None  # m
    scan_rate: float | None = None  # Hz
    upside_down: bool = False  # rolled by pi about its x axis: its scan mirrored (y -> -y)


@dataclass(frozen=True)
class SweepInput:
    """One sweep in the sensor frame (``lidar``): points where the sensor saw them, at their own time.

    stamp_ns: the first beam's time (ns, the log's clock). xy: (N, 2) m in ``lidar``. t: (N,) s after
    ``stamp_ns``, each point's own time (0 where the log gives none). velocity: (N,) m/s radial
    Doppler velocity, positive away from the sensor; None without Doppler. intensity: (N,) as the
    sensor reports it, or None.
    """

    stamp_ns: int  # first beam
    xy: np.ndarray  # (N, 2) m, frame lidar
    t: np.ndarray  # (N,) s after stamp_ns
    velocity: np.ndarray | None  # (N,) m/s radial Doppler, None without Doppler
    intensity: np.ndarray | None


@dataclass(frozen=True)
class TicksInput:
    """One wheel-encoder reading: cumulative tick counts of the left and right rear wheels at
    ``stamp_ns`` (ns), with 32-bit wraps already unwrapped."""

    stamp_ns: int
    left: int
    right: int


@dataclass(frozen=True)
class OdomInput:
    """One pose of an Odometry topic used as the motion prior, at ``stamp_ns`` (ns)."""

    stamp_ns: int
    pose: np.ndarray  # (3,) x, y, yaw in the odometry frame


@dataclass(frozen=True)
class InputTopics:
    """The topics one run reads: a scan topic and at most one motion-prior topic."""

    scan: str
    ticks: str | None
    odom: str | None

    @property
    def prior(self) -> str | None:
        return self.ticks or self.odom


@dataclass(frozen=True)
class SweepResult:
    """What one method made of one sweep.

    pose: base_link in the method's own frame (``<method>/odom``) at the sweep's stamp.
    twist: ``(v, ω)`` of base_link over the sweep (m/s, rad/s), as used to deskew it.
    twist_covariance: (2, 2) of ``twist`` where it was measured (Doppler), else None.
    pose_covariance: (3, 3) over (x, y, yaw) of the scan-to-map registration (m², rad²):
        how well this sweep is pinned to the method's map, not the drift accumulated since
        the start; None where no registration ran (the first sweeps).
    static_map_xy, static_velocity: the points it kept (map frame, deskewed) and their
        radial Doppler velocity (m/s; None without Doppler).
    moving_map_xy, moving_velocity: the same for the points it judged moving.
    moving_mask: (N,) over the sweep's points; ``segmented`` says whether it is a verdict.
    """

    method: str
    stamp_ns: int
    pose: np.ndarray
    twist: tuple[float, float]
    twist_covariance: np.ndarray | None
    pose_covariance: np.ndarray | None
    iterations: int
    correspondences: int
    moving_points: int
    ms: float
    static_map_xy: np.ndarray
    static_velocity: np.ndarray | None
    moving_map_xy: np.ndarray
    moving_velocity: np.ndarray | None
    moving_mask: np.ndarray
    segmented: bool
    keyframe: bool
    searched: bool = False  # the ICP's fit was poor, so a correlative search ran (:mod:`fmcwlog.frontend.recovery`)
    recovered: bool = False  # ... and its match replaced the ICP's from the prior
    # this sweep ends a jump (a robot carried away, :mod:`fmcwlog.frontend.relocalise`): "relocalised" or
    # "new piece"; the back end gives the odometry edge across it no weight
    jump: str | None = None
    # where relocalised: the pose (x, y, yaw) the motion prior gave this sweep, on the chain of the
    # ``jump_back`` suspect sweeps just before it (which kept the prior's poses): the back end moves
    # those by the prior's motion from this sweep's pose found, back to the place they were taken
    jump_prior: np.ndarray | None = None
    jump_back: int = 0
