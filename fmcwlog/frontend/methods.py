"""The front ends: the paper's improved one and the classic ICP baseline, sweep by sweep.

For every sweep (stamp ``t_k`` = its first beam):

improved (paper §4, with NOTES.md's corrections)
  1. ego-motion from Doppler: the sensor's velocity fitted robustly to the
     static points' radial velocities (:mod:`.egomotion`), turned into the robot's
     ``(v, ω)`` with the rear axle's no-slide constraint;
  2. segmentation: DBSCAN over position and *ego-motion-compensated* velocity
     (eq. 17-19, :mod:`.segmentation`), and movers followed over time and seen in
     the map's free space (:mod:`.tracking`); moving points leave matching and the map;
  3. deskew every point to ``t_k`` with the Doppler twist (:mod:`.deskew`);
  4. prior: the previous pose moved by the Doppler twist over ``t_k - t_{k-1}``,
     also used as a soft constraint in the ICP so that a geometrically
     degenerate scene (a bare corridor) cannot slide along its axis;
  5. correspondences by nearest neighbour in the voxel map (:mod:`.local_map`),
     GMMSC rejection (eq. 20-21, :mod:`.gmmsc`), Huber-robust Gauss-Newton ICP
     (eq. 22-26, :mod:`.robust_icp`).

baseline (the paper's "before improvement")
  all points, deskewed with the wheel-odometry twist, the wheel-odometry prior,
  classic point-to-point ICP (unit weights, closed form, :mod:`.point_to_point_icp`)
  against a map built the same way from all its points.

Without Doppler (a LaserScan topic, or a cloud with no ``velocity`` field) the
improved method keeps GMMSC and the robust kernel and uses the odometry prior.

Both maps take a keyframe's points when the robot has moved or turned enough
since the last one, which also bounds the KD-tree rebuilds.

The two methods are two classes, :class:`ImprovedFrontEnd` and
:class:`BaselineFrontEnd`, over one :class:`FrontEnd` that holds what they
share (deskew, map, occupancy grid, keyframes); :data:`METHODS` names them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..geometry import between, compose, transform_points, wrap_angle
from ..io.calibration import Calibration
from ..io.inputs import SweepInput
from .deskew import deskew, se2_exp
from .egomotion import (
    base_twist_from_sensor_velocity,
    compensated_velocity,
    fit_sensor_velocity,
    sensor_velocity_from_base_twist,
)
from .gmmsc import DistanceMixture
from .icp import ICPResult
from .local_map import VoxelMap, voxel_downsample
from .occupancy import OccupancyGrid, OccupancyParams
from .params import FrontEndParams
from .point_to_point_icp import register_point_to_point
from .robust_icp import register
from .segmentation import segment_moving
from .tracking import MoverTracker

WHEEL_ODOMETRY = "wheel_odometry"  # the motion prior's own trajectory, written beside the methods'


@dataclass(frozen=True)
class PriorMotion:
    """What the motion prior (wheel ticks or an Odometry topic) says about one sweep.

    twist: ``(v, ω)`` of base_link over the sweep (m/s, rad/s); None without a prior.
    since_last: base_link's motion (x, y, yaw) from the previous sweep's stamp to
        this one's, in its frame at the previous stamp; None for the first sweep or
        without a prior.
    """

    twist: tuple[float, float] | None = None
    since_last: np.ndarray | None = None


@dataclass
class Doppler:
    """The Doppler stages' output for one sweep (improved method): the robot's twist from the
    sensor's velocity (m/s, rad/s; NaN where unobservable), its variances, and the moving mask."""

    v: float
    omega: float
    v_var: float
    omega_var: float
    moving: np.ndarray
    v_omega_cov: float = 0.0

    @property
    def usable(self) -> bool:
        return bool(np.isfinite(self.v) and np.isfinite(self.omega))


@dataclass
class MotionEstimate:
    """A method's view of one sweep's motion before matching.

    twist: ``(v, ω)`` used to deskew the sweep (m/s, rad/s).
    predicted: base_link's pose at the sweep's stamp before matching (map frame).
    moving: (N,) points judged moving, left out of matching and the map.
    doppler: the Doppler stages' output (improved method with Doppler), else None.
    segmented: ``moving`` is a segmentation's verdict (else no point was judged).
    twist_covariance: (2, 2) of ``twist`` when it was measured (the Doppler fit), else None.
    """

    twist: tuple[float, float]
    predicted: np.ndarray
    moving: np.ndarray
    doppler: Doppler | None = None
    segmented: bool = False
    twist_covariance: np.ndarray | None = None


@dataclass
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


class FrontEnd:
    """One method's state: its pose, its voxel map, its occupancy grid; :meth:`step` per sweep.

    Subclasses say how a sweep's motion is estimated before matching
    (:meth:`estimate_motion`) and how it is matched against the map (:meth:`register`).
    """

    name: ClassVar[str]
    segments: ClassVar[bool] = False  # judges points moving or static (writes moving labels)

    def __init__(self, params: FrontEndParams, cal: Calibration):
        self.params = params
        self.cal = cal
        self.mount = np.asarray(cal.mount, dtype=float)
        self.map = VoxelMap(params.voxel_size)
        self.grid = OccupancyGrid(OccupancyParams(resolution=params.map_resolution))
        self.pose: np.ndarray | None = None
        self.last_stamp = 0.0  # s, of the last sweep; meaningful once ``pose`` is set
        self.last_key: np.ndarray | None = None
        self.last_grid: np.ndarray | None = None
        self.last_twist = (0.0, 0.0)

    # --- what the methods do differently -------------------------------------------------
    def estimate_motion(self, sweep: SweepInput, prior: PriorMotion) -> MotionEstimate:
        raise NotImplementedError  # pragma: no cover - abstract

    def register(self, source: np.ndarray, motion: MotionEstimate, stamp: float) -> ICPResult:
        """Match ``source`` (base_link at the sweep's stamp) against the map from ``motion.predicted``."""
        raise NotImplementedError  # pragma: no cover - abstract

    # --- what they share ------------------------------------------------------------------
    def prior_twist(self, prior: PriorMotion) -> tuple[float, float]:
        """The twist over the sweep from the motion prior, else the last one used."""
        return prior.twist if prior.twist is not None else self.last_twist

    def predict(self, stamp: float, prior: PriorMotion, twist: tuple[float, float]) -> np.ndarray:
        """The pose at ``stamp`` from the motion prior, else ``twist`` held since the last sweep."""
        if self.pose is None:
            return np.zeros(3)
        if prior.since_last is not None:
            return compose(self.pose, prior.since_last)
        return compose(self.pose, se2_exp(twist[0], 0.0, twist[1], np.array(stamp - self.last_stamp)))

    @staticmethod
    def _moved(last: np.ndarray | None, pose: np.ndarray, distance: float, angle_deg: float) -> bool:
        if last is None:
            return True
        d = between(last, pose)
        return bool(np.hypot(d[0], d[1]) >= distance or abs(d[2]) >= np.radians(angle_deg))

    def _update_maps(self, pose: np.ndarray, static_map: np.ndarray) -> bool:
        """A keyframe's points into the voxel map, and into the occupancy grid less often."""
        p = self.params
        keyframe = self._moved(self.last_key, pose, p.keyframe_distance, p.keyframe_angle_deg)
        if keyframe:
            self.map.add(static_map)
            self.last_key = pose
        if self._moved(self.last_grid, pose, p.grid_distance, p.grid_angle_deg):
            self.grid.integrate(compose(pose, self.mount)[:2], static_map)
            self.last_grid = pose
        return keyframe

    def step(self, sweep: SweepInput, prior: PriorMotion) -> SweepResult:
        t0 = time.perf_counter()
        p = self.params
        ts = sweep.stamp_ns * 1e-9
        xy, t = sweep.xy, sweep.t
        near = np.hypot(xy[:, 0], xy[:, 1]) < p.min_range
        motion = self.estimate_motion(sweep, prior)
        v, omega = motion.twist
        use = ~near & ~motion.moving
        seen = deskew(xy[use], t[use], v, omega, self.mount) if p.deskew else xy[use]
        pts = transform_points(self.mount, seen)  # base_link at t_k
        source = voxel_downsample(pts, p.source_voxel)

        pose_cov = None
        if self.map.tree is None or len(self.map) < p.icp.min_correspondences:
            pose, iterations, kept = motion.predicted, 0, 0
        else:
            res = self.register(source, motion, ts)
            pose, iterations, kept = res.pose, res.iterations, res.n_correspondences_kept
            pose_cov = registration_covariance(res.hessian, p.residual_sigma)
        pose = np.array([pose[0], pose[1], wrap_angle(pose[2])])

        static_map = transform_points(pose, pts)
        keyframe = self._update_maps(pose, static_map)
        self.pose, self.last_stamp, self.last_twist = pose, ts, (v, omega)
        moving = motion.moving & ~near
        moving_xy = xy[moving]
        moving_map = transform_points(compose(pose, self.mount), moving_xy) if len(moving_xy) else np.empty((0, 2))
        vel = sweep.velocity
        ms = (time.perf_counter() - t0) * 1e3
        return SweepResult(self.name, sweep.stamp_ns, pose, (v, omega), motion.twist_covariance, pose_cov,
                           iterations, kept, int(motion.moving.sum()), ms, static_map,
                           None if vel is None else vel[use], moving_map, None if vel is None else vel[moving],
                           motion.moving, motion.segmented, keyframe)


def registration_covariance(hessian: np.ndarray, residual_sigma: float) -> np.ndarray | None:
    """Covariance (3, 3) of a registered pose: ``σ² H⁻¹`` with ``H = JᵀWJ`` (+ the prior's
    information, already in those units), residuals of standard deviation ``σ`` (m).
    None when ``H`` is singular (a scan that fixes no direction)."""
    try:
        cov = residual_sigma**2 * np.linalg.inv(hessian)
    except np.linalg.LinAlgError:
        return None
    return cov if np.all(np.isfinite(cov)) else None


class ImprovedFrontEnd(FrontEnd):
    """The paper's front end (§4): Doppler ego-motion and segmentation, GMMSC, robust ICP."""

    name = "improved"
    segments = True

    def __init__(self, params: FrontEndParams, cal: Calibration):
        super().__init__(params, cal)
        self.mixture: DistanceMixture | None = None  # the last GMMSC mixture, reused by the next sweep's ICP
        self.tracker = MoverTracker(params.tracking)  # movers followed over this log's sweeps

    def doppler_stages(self, sweep: SweepInput, prior_twist: tuple[float, float] | None) -> Doppler | None:
        """Ego-motion and segmentation of one sweep; None without Doppler.

        ``prior_twist``: the odometry's ``(v, ω)`` over the sweep; the Doppler fit
        keeps within ``doppler_prior_gate`` of it, so that a crowd walking together
        cannot pass for the static world.
        """
        if sweep.velocity is None:
            return None
        p = self.params
        expected = None
        if prior_twist is not None and all(np.isfinite(prior_twist)):
            expected = sensor_velocity_from_base_twist(prior_twist[0], prior_twist[1], *self.cal.mount)
        ego = fit_sensor_velocity(sweep.xy, sweep.velocity, random_state=p.seed, prior=expected,
                                  prior_gate=p.doppler_prior_gate)
        if not np.all(np.isfinite(ego.v_sensor)):
            return Doppler(float("nan"), float("nan"), float("nan"), float("nan"), np.zeros(len(sweep.xy), bool))
        eps = compensated_velocity(sweep.xy, sweep.velocity, ego.v_sensor)  # NOTES: threshold this, not v_r
        tw = base_twist_from_sensor_velocity(ego.v_sensor, *self.cal.mount, covariance=ego.covariance)
        moving = self.segment(sweep, eps, (tw.v, tw.omega) if np.isfinite(tw.omega) else prior_twist)
        return Doppler(tw.v, tw.omega, float(tw.covariance[0, 0]), float(tw.covariance[1, 1]), moving,
                       float(tw.covariance[0, 1]))

    def segment(self, sweep: SweepInput, eps: np.ndarray, twist: tuple[float, float] | None) -> np.ndarray:
        """Moving mask (N,): DBSCAN and the Doppler verdict (eq. 17-19) and, with tracking on, the
        movers followed from earlier sweeps and the map's free space (:mod:`.tracking`). ``eps``:
        compensated Doppler (m/s); ``twist``: ``(v, ω)`` over the sweep, to place its points in the map."""
        p = self.params
        if not p.tracking.enabled:
            return segment_moving(sweep.xy, eps, p.segmentation)
        v, omega = twist if twist is not None and all(np.isfinite(twist)) else (0.0, 0.0)
        ts = sweep.stamp_ns * 1e-9
        base, yaw_error = np.zeros(3), 0.0
        if self.pose is not None:  # the last sweep's twist spans most of the time since it (yaw error 3x smaller)
            dt = ts - self.last_stamp
            base = compose(self.pose, se2_exp(self.last_twist[0], 0.0, self.last_twist[1], np.array(dt)))
            yaw_error = abs(omega - self.last_twist[1]) * dt  # a step in ω since the last sweep (a corner's end)
        return self.tracker.segment(sweep.xy, sweep.t, eps, ts, base, (v, omega), self.mount, self.grid,
                                    p.segmentation, yaw_error)

    def estimate_motion(self, sweep: SweepInput, prior: PriorMotion) -> MotionEstimate:
        ts = sweep.stamp_ns * 1e-9
        doppler = self.doppler_stages(sweep, prior.twist)
        segmented = doppler is not None and self.params.segment
        moving = doppler.moving.copy() if doppler is not None and segmented else np.zeros(len(sweep.xy), bool)
        if doppler is None or not doppler.usable or not self.params.doppler_twist:
            twist = self.prior_twist(prior)
            return MotionEstimate(twist, self.predict(ts, prior, twist), moving, doppler, segmented)
        twist = (doppler.v, doppler.omega)
        twist_cov = np.array([[doppler.v_var, doppler.v_omega_cov], [doppler.v_omega_cov, doppler.omega_var]])
        if self.pose is None:
            predicted = np.zeros(3)
        else:  # the twist at the middle of the interval since the last sweep
            v_mid, w_mid = 0.5 * (twist[0] + self.last_twist[0]), 0.5 * (twist[1] + self.last_twist[1])
            predicted = compose(self.pose, se2_exp(v_mid, 0.0, w_mid, np.array(ts - self.last_stamp)))
        return MotionEstimate(twist, predicted, moving, doppler, segmented, twist_cov)

    def register(self, source: np.ndarray, motion: MotionEstimate, stamp: float) -> ICPResult:
        prior_info = None
        d = motion.doppler
        if d is not None and np.isfinite(d.v) and self.params.doppler_prior:
            prior_info = doppler_prior_information(motion.predicted[2], d.v_var, d.omega_var,
                                                   stamp - self.last_stamp, self.params)
        res = register(source, self.map.tree, self.map.points, motion.predicted, self.params.icp,
                       mixture=self.mixture, prior_pose=motion.predicted if prior_info is not None else None,
                       prior_information=prior_info)
        self.mixture = res.mixture
        return res


def doppler_prior_information(yaw: float, v_var: float, omega_var: float, dt: float,
                              p: FrontEndParams) -> np.ndarray:
    """The ICP's soft prior on the predicted pose (3, 3), in the units of its normal equations.

    Along the path the Doppler speed integrated over ``dt`` (s) has standard deviation
    ``√v_var·dt`` (m); across it the rear axle does not slide; in yaw ``√ω_var·dt`` (rad);
    each floored by ``prior_sigma_*``. Rotated into ``map`` by the predicted ``yaw`` and
    scaled by ``residual_sigma²`` to weigh against the point residuals.
    """
    s_along = max(np.sqrt(v_var) * dt, p.prior_sigma_along)
    s_yaw = max(np.sqrt(omega_var) * dt, p.prior_sigma_yaw)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s], [s, c]])
    cov_xy = rot @ np.diag([s_along**2, p.prior_sigma_across**2]) @ rot.T
    info = np.zeros((3, 3))
    info[:2, :2] = np.linalg.inv(cov_xy)
    info[2, 2] = 1.0 / s_yaw**2
    return info * p.residual_sigma**2


class BaselineFrontEnd(FrontEnd):
    """The classic ICP baseline: all points, the wheel-odometry prior, point-to-point ICP."""

    name = "baseline"

    def estimate_motion(self, sweep: SweepInput, prior: PriorMotion) -> MotionEstimate:
        twist = self.prior_twist(prior)
        return MotionEstimate(twist, self.predict(sweep.stamp_ns * 1e-9, prior, twist), np.zeros(len(sweep.xy), bool))

    def register(self, source: np.ndarray, motion: MotionEstimate, stamp: float) -> ICPResult:
        return register_point_to_point(source, self.map.tree, self.map.points, motion.predicted, self.params.icp)


METHODS: dict[str, type[FrontEnd]] = {cls.name: cls for cls in (ImprovedFrontEnd, BaselineFrontEnd)}
METHOD_NAMES = tuple(METHODS)
