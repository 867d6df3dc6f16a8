"""The front ends: the paper's improved one and the classic ICP baseline, sweep by sweep.

For every sweep (stamp ``t_k`` = its first beam):

improved (paper §4, with the corrections in docs/physics.md)
  1. ego-motion from Doppler: the sensor's velocity fitted robustly to the
     static points' radial velocities (:mod:`.egomotion`), fused with the wheels'
     ``(v, ω)`` through the rear axle's no-slide constraint by weighted least squares
     (:mod:`.twist_fusion`): Doppler gives what it observes at the mount (over the
     axle, not ``ω``), the wheels the rest, and nothing is singular at any mount;
     Doppler and the wheels are checked against each other and the scans
     (:mod:`.sensor_checks`), and a source found faulty is dropped;
  2. segmentation: DBSCAN over position and *ego-motion-compensated* velocity
     (eq. 17-19, :mod:`.segmentation`), and movers followed over time and seen in
     the map's free space (:mod:`.tracking`); moving points leave matching and the map;
  3. deskew every point to ``t_k`` with the Doppler twist (:mod:`.deskew`);
  4. prior: the previous pose moved by the fused twist over ``t_k - t_{k-1}``,
     also used (with the fused covariance) as a soft constraint in the ICP so that
     a geometrically degenerate scene (a bare corridor) cannot slide along its axis;
  5. correspondences by nearest neighbour in the voxel map (:mod:`.keyframe_map`),
     GMMSC rejection (eq. 20-21, :mod:`.gmmsc`), Huber-robust Gauss-Newton ICP
     (eq. 22-26, :mod:`.robust_icp`).

baseline (the paper's "before improvement")
  all points, deskewed with the wheel-odometry twist, the wheel-odometry prior,
  classic point-to-point ICP (unit weights, closed form, :mod:`.point_to_point_icp`)
  against a map built the same way from all its points.

Without Doppler (a LaserScan topic, or a cloud with no ``velocity`` field) the
improved method keeps GMMSC and the robust kernel and uses the odometry prior.
Along the way it keeps per-sweep sums (Doppler velocity, wheel turns, scan-matched
heading changes) for the calibration check (:mod:`.self_calibration`), run once at
the end of the log.

Both maps take a keyframe's points when the robot has moved or turned enough
since the last one, which also bounds the KD-tree rebuilds.

Only registration's input is thinned, as KISS-ICP thins each deskewed frame: the first point
in beam order of each ``source_voxel`` (10 cm) voxel (:func:`fmcwlog.kernels.voxel.voxel_downsample`,
as the map keeps a keyframe's; ``source_thinning = "centroid"`` keeps each voxel's centroid),
for both methods (thinning the source is the classic ICP pipeline's practice too). The map,
the occupancy grid, segmentation, the Doppler fit and the published clouds keep every point.
The 10 cm voxel is an accuracy choice: coarser voxels cost the improved method's ATE +25 to
+111 % at 20 cm on six scenarios x 3 seeds x 20 s (``python bench/suite.py --quick --seeds 0 1 2``),
no thinning lets the near walls' dense points outweigh the far ones (the 30 s corridor sample:
0.92 -> 1.62 cm); the measurements are in docs/design/frontend-params.md.

The two methods are two classes, :class:`ImprovedFrontEnd` and
:class:`BaselineFrontEnd`, over one :class:`FrontEnd` that holds what they
share (deskew, map, occupancy grid, keyframes); :data:`METHODS` names them.
"""

from __future__ import annotations

import dataclasses
import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..geometry import _is_pose, between, between_floats, compose, transform_points, wrap_angle
from ..kernels import compiled
from ..kernels.correlative import LikelihoodGrid, correlative_match, grid_for
from ..kernels.occupancy import OccupancyGrid, OccupancyParams, Scan
from ..kernels.voxel import voxel_centroids, voxel_downsample
from ..types import BASELINE, IMPROVED, Calibration, SweepInput, SweepResult
from .deskew import advance, deskewed_source
from .deskew_wheels import SweepKnots, deskewed_source_wheels, wheel_profile
from .egomotion import EgoMotion, compensated_velocity, fit_sensor_velocity, refit_static, unit_bearings
from .gaps import bridge_covariance, gap_prior_information, gap_window, seen_before, to_map, within_bridge
from .gmmsc import DistanceMixture
from .icp import ICPResult
from .keyframe_map import KeyframeMap
from .mirror_check import EITHER, SCANNER, MountCheck
from .mirror_check import WHEELS as WHEELS_FAULT
from .odometry_drift import OdometryDrift
from .params import FrontEndParams
from .point_to_point_icp import register_point_to_point
from .recovery import inlier_fraction
from .relocalise import NEW_PIECE, RELOCALISED, JumpWatch
from .robust_icp import register
from .scan_prior import GRID_REUSE_KEYFRAMES, MidSweepHold, search_window
from .segmentation import segment_moving
from .self_calibration import CalibrationEstimate, CalibrationSamples, calibration_report, estimate_calibration
from .sensor_checks import DOPPLER, WHEELS, SensorChecks
from .sweep_geometry import SweepGeometry, sweep_geometry
from .tracking import MoverTracker
from .twist_fusion import (
    FusedTwist,
    ObservedNoise,
    TwistSources,
    base_variances,
    doppler_design,
    fuse_twist,
    fuse_twist_lists,
    hold_covariance,
    observability,
    wheel_covariance,
    wheel_variances,
)


@dataclass(frozen=True)
class PriorMotion:
    """What the motion prior (wheel ticks or an Odometry topic) says about one sweep.

    twist: ``(v, ω)`` of base_link over the sweep (m/s, rad/s); None without a prior.
    since_last: base_link's motion (x, y, yaw) from the previous sweep's stamp to
        this one's, in its frame at the previous stamp; None for the first sweep or
        without a prior.
    span: the interval ``[stamp, stamp + span]`` (s) that ``twist`` and ``turns`` cover.
    turns: how far each rear wheel turned over ``span`` (rad; left, right), from the
        ticks alone (no radii); None without ticks.
    turns_since_last: the same from the previous sweep's stamp to this one's.
    gap: the length (s) of the gap in the sweeps before this one (:mod:`.gaps`), 0 where none.
    within: the prior's track over ``span`` (:class:`~.deskew_wheels.SweepKnots`), None where it
        does not cover the sweep or without a prior.
    """

    twist: tuple[float, float] | None = None
    since_last: np.ndarray | None = None
    span: float = 0.0
    turns: tuple[float, float] | None = None
    turns_since_last: tuple[float, float] | None = None
    gap: float = 0.0
    within: SweepKnots | None = None


@dataclass
class Doppler:
    """The Doppler stages' output for one sweep (improved method): the lidar origin's velocity
    (lidar frame, m/s; NaN where the fit failed), its (2, 2) covariance, and the moving mask.
    The robot's twist is made from it and the wheels by :mod:`.twist_fusion`."""

    v_sensor: np.ndarray
    covariance: np.ndarray
    moving: np.ndarray

    @property
    def usable(self) -> bool:
        return _finite(self.v_sensor) and _finite(self.covariance)


def _finite(a: np.ndarray) -> bool:
    """``np.all(np.isfinite(a))`` of a small array (a twist, a 2x2 or 3x3 matrix): the same answer
    from its elements as Python numbers, without numpy's reduction machinery."""
    return all(map(math.isfinite, a.ravel().tolist()))


# Doppler's (v, ω) alone, the wheels', and the variances of (v, ω) Doppler's fit claimed (base_link)
_Pair = tuple[tuple[float, float], tuple[float, float], tuple[float, float]]


def _finite_pair(twist: tuple[float, float]) -> bool:
    """``all(np.isfinite(twist))`` of a ``(v, ω)`` pair of numbers."""
    return math.isfinite(twist[0]) and math.isfinite(twist[1])


@dataclass
class MotionEstimate:
    """A method's view of one sweep's motion before matching.

    twist: ``(v, ω)`` used to deskew the sweep (m/s, rad/s).
    predicted: base_link's pose at the sweep's stamp before matching (map frame).
    moving: (N,) points judged moving, left out of matching and the map.
    doppler: the Doppler stages' output (improved method with Doppler), else None.
    segmented: ``moving`` is a segmentation's verdict (else no point was judged).
    twist_covariance: (2, 2) of ``twist`` when it was measured (the Doppler fit), else None.
    fused: Doppler and the wheels fused (:mod:`.twist_fusion`), where Doppler was usable;
        with ``doppler_twist`` off it only sets the ICP's prior, not ``twist``.
    within: the wheels' track over the sweep (``PriorMotion.within``) where the wheels are in use
        (not dropped by the sensor checks), else None: what ``deskew_motion = "wheels"`` de-skews by.
    """

    twist: tuple[float, float]
    predicted: np.ndarray
    moving: np.ndarray
    doppler: Doppler | None = None
    segmented: bool = False
    twist_covariance: np.ndarray | None = None
    fused: FusedTwist | None = None
    within: SweepKnots | None = None


class FrontEnd(ABC):
    """One method's state: its pose, its voxel map, its occupancy grid; :meth:`step` per sweep.

    Subclasses say how a sweep's motion is estimated before matching
    (:meth:`estimate_motion`) and how it is matched against the map (:meth:`register`).
    """

    name: ClassVar[str]
    segments: ClassVar[bool] = False  # judges points moving or static (writes moving labels)
    bearings: ClassVar[bool] = False  # uses the points' unit bearings (the Doppler stages)

    def __init__(self, params: FrontEndParams, cal: Calibration):
        self.params = params
        self.cal = cal
        self.mount = np.asarray(cal.mount, dtype=float)
        self.map = KeyframeMap(params.voxel_size, params.local_map)
        self.grid = OccupancyGrid(OccupancyParams(resolution=params.map_resolution))
        self.pose: np.ndarray | None = None
        self.path_m = 0.0  # distance travelled by base_link, m
        self.last_stamp = 0.0  # s, of the last sweep; meaningful once ``pose`` is set
        self.last_key: np.ndarray | None = None
        self.last_grid: np.ndarray | None = None
        self.last_twist = (0.0, 0.0)
        self.hold = MidSweepHold()  # the constant-velocity hold where no motion prior is given
        # the geometry of the sweep in step
        self._sweep: SweepGeometry | None = None
        self._gap_information: np.ndarray | None = None  # the ICP's soft prior while a gap is bridged
        self._gap_by_prior = False  # the last gap was bridged by the motion prior (else by the hold)
        self.jumps = JumpWatch(params.relocalise)  # sweeps that stop fitting the map: a robot carried away
        self.drift = OdometryDrift(params.gaps.drift)  # the motion prior's drift, taken out of the gaps' bridges
        self._registered_prev = False  # the last sweep was matched (its pose is the scans')

    # --- what the methods do differently -------------------------------------------------
    @abstractmethod
    def estimate_motion(self, sweep: SweepInput, prior: PriorMotion) -> MotionEstimate:
        """The sweep's twist, predicted pose and moving mask, before matching."""

    @abstractmethod
    def register(self, source: np.ndarray, motion: MotionEstimate, stamp: float,
                 initial: np.ndarray | None = None) -> ICPResult:
        """Match ``source`` (base_link at the sweep's stamp) against the map, starting from
        ``initial`` (default ``motion.predicted``, which stays the prior either way)."""

    def after_step(self, pose: np.ndarray, stamp: float, registered: bool, prior: PriorMotion) -> None:  # noqa: B027 - an optional hook, not abstract
        """Called with the sweep's final pose before it replaces ``self.pose`` (nothing by default)."""

    def diagnostics(self, prior_name: str) -> tuple[dict, list[str]]:
        """What ``run.json`` should say about this method's sources, and warnings (none by default)."""
        return {}, []

    # --- what they share ------------------------------------------------------------------
    def prior_twist(self, prior: PriorMotion) -> tuple[float, float]:
        """The twist over the sweep from the motion prior, else the constant-velocity hold."""
        return prior.twist if prior.twist is not None else self.hold.twist

    def predict(self, stamp: float, prior: PriorMotion, twist: tuple[float, float]) -> np.ndarray:
        """The pose at ``stamp`` from the motion prior, else ``twist`` held since the last sweep."""
        if self.pose is None:
            return np.zeros(3)
        if prior.since_last is not None:
            return compose(self.pose, prior.since_last)
        return advance(self.pose, twist[0], twist[1], stamp - self.last_stamp)

    @staticmethod
    def _moved(last: np.ndarray | None, pose: np.ndarray, distance: float, angle_deg: float) -> bool:
        if last is None:
            return True
        # the same values as ``between``'s array, as floats
        d: tuple[float, float, float] | np.ndarray | None = between_floats(last, pose)
        if d is None:
            d = between(last, pose)
        # math.radians is numpy's deg2rad: x * (pi / 180)
        return bool(np.hypot(d[0], d[1]) >= distance or abs(d[2]) >= math.radians(angle_deg))

    def _update_maps(self, pose: np.ndarray, static_map: np.ndarray, skew_rad: float,
                     lidar: np.ndarray | None = None) -> bool:
        """A keyframe's points into the local map, and into the occupancy grid less often.

        ``skew_rad``: how much the twist changed across the sweep, as an angle (rad): a sweep
        whose twist changes within it (entering or leaving a turn) is deskewed with the wrong
        twist, so it waits (:class:`~.keyframe_map.LocalMapParams`). ``lidar``: ``pose ⊕ mount``
        if already composed."""
        p = self.params
        keyframe = self._moved(self.last_key, pose, p.keyframe_distance, p.keyframe_angle_deg) and (
            skew_rad <= math.radians(p.local_map.max_twist_skew_deg) or self.last_key is None)
        if keyframe:
            self.map.add(static_map, self.path_m)
            self.last_key = pose
        if self._moved(self.last_grid, pose, p.grid_distance, p.grid_angle_deg):
            self._into_grid(Scan((compose(pose, self.mount) if lidar is None else lidar)[:2], static_map))
            self.last_grid = pose
        return keyframe

    def _into_grid(self, scan: Scan) -> None:
        """A scan (static points in ``map``) into the occupancy grid."""
        self.grid.add(scan)

    def step(self, sweep: SweepInput, prior: PriorMotion) -> SweepResult:
        t0 = time.perf_counter()
        p = self.params
        ts = sweep.stamp_ns * 1e-9
        xy, t = sweep.xy, sweep.t
        # ranges and the body mask, the Doppler stages' bearings and the tracker's middle time where they
        # run, the last capture time: for this sweep's stages
        with_doppler = self.bearings and sweep.velocity is not None
        self._sweep = geometry = sweep_geometry(xy, t, p.min_range, with_doppler, with_doppler and p.tracking.enabled)
        near = geometry.near
        motion = self.estimate_motion(sweep, prior)
        bridge = None
        if prior.gap > 0 and p.gaps.bridge and self.pose is not None:
            motion, bridge = self._bridge(prior, motion)
        v, omega = motion.twist
        n_moving = int(np.count_nonzero(motion.moving))
        vel = sweep.velocity
        # the points used (neither inside the body mask nor moving) in base_link at t_k, deskewed, and
        # their thinning for registration
        centroid = p.source_thinning == "centroid"
        profile = (wheel_profile(motion.within, v, p.deskew_min_yaw_step) if p.deskew and p.deskew_motion == "wheels"
                   and motion.within is not None else None)
        if profile is not None:
            use, pts, source, vel_use = deskewed_source_wheels(xy, t, profile, self.mount, near,
                                                               motion.moving if n_moving else None, vel,
                                                               p.source_voxel, centroid)
        elif p.deskew:
            use, pts, source, vel_use = deskewed_source(xy, t, v, omega, self.mount, near,
                                                        motion.moving if n_moving else None, vel, p.source_voxel,
                                                        centroid)
        else:
            use = ~(near | motion.moving) if n_moving else ~near
            pts, vel_use = _transform(self.mount, xy[use]), None if vel is None else vel[use]
            source = (voxel_centroids if centroid else voxel_downsample)(pts, p.source_voxel)

        pose_cov = None
        searched = recovered = suspect = False
        jump: str | None = None
        if self.map.tree is None or min(len(self.map), len(source)) < p.icp.min_correspondences:
            # No map yet, or too few points left to match (the window covered, every return on a
            # mover or inside the body mask): the ICP could not reach its minimum of pairs and the
            # correlative search has nothing to place, so the motion prior stands for this sweep.
            pose, iterations, kept = motion.predicted, 0, 0
        else:
            if bridge is not None:
                res, searched, recovered = self._match_after_gap(source, motion, ts, bridge)
            elif self.scan_prior(prior, motion):
                res, searched, recovered = self._scan_to_map(source, motion, ts)
            else:
                res, searched, recovered = self._register_or_recover(source, motion, ts)
            pose, iterations, kept = res.pose, res.iterations, res.n_correspondences_kept
            pose_cov = registration_covariance(res.hessian, p.residual_sigma)
            if bridge is not None and not within_bridge(pose, motion.predicted, bridge, p.gaps.max_mahalanobis):
                pose, iterations, kept, pose_cov = motion.predicted, 0, 0, None  # another peak: the bridge stands
            elif bridge is None and p.relocalise.enabled:
                found, jump, suspect = self._watch_jumps(source, motion, ts, res)
                if found is not None:  # relocalised: the pose found over the whole local map
                    pose, iterations, kept = found.pose, found.iterations, found.n_correspondences_kept
                    pose_cov = registration_covariance(found.hessian, p.residual_sigma)
                    searched = True
                elif suspect or jump is not None:  # the prior's pose, not a match against another place
                    pose, iterations, kept, pose_cov = motion.predicted, 0, 0, None
        if bridge is not None:  # the back end's edge across the gap is as loose as the bridge
            pose_cov = bridge if pose_cov is None else pose_cov + bridge
        pose = _wrapped(pose)
        if self.pose is not None and jump is None:  # a jump was not driven
            self.path_m += _step_length(self.pose, pose)

        static_map = _transform(pose, pts)
        duration = geometry.last_time  # s, the sweep's last capture time
        skew = abs(omega - self.last_twist[1]) * duration if self.pose is not None else 0.0
        lidar = compose(pose, self.mount)
        if jump == NEW_PIECE:
            self._new_piece()
        if jump is not None:
            self.last_key = self.last_grid = None  # the sweep that ends a jump starts the map again from there
        keyframe = False if suspect else self._update_maps(pose, static_map, skew, lidar)
        registered = iterations > 0 and bridge is None and jump is None and not suspect
        if registered and self._registered_prev and prior.since_last is not None and self.pose is not None:
            self.drift.observe(prior.since_last, between_floats(self.pose, pose) or between(self.pose, pose))
        self._registered_prev = registered
        self.after_step(pose, ts, iterations > 0, prior)
        if prior.twist is None:
            self.hold.update(pose, ts, (v, omega), 0.5 * duration)
        self.pose, self.last_stamp, self.last_twist = pose, ts, (v, omega)
        if n_moving:
            moving = motion.moving > near  # moving and not near (True > False only)
            moving_xy = xy[moving]
            moving_map = _transform(lidar, moving_xy) if len(moving_xy) else np.empty((0, 2))
            moving_vel = None if vel is None else vel[moving]
        else:  # what those give with no point moving: empty, in the inputs' dtypes
            moving_map, moving_vel = np.empty((0, 2)), None if vel is None else vel[:0].copy()
        ms = (time.perf_counter() - t0) * 1e3
        back = self.jumps.jumps[-1].suspects - 1 if jump == RELOCALISED else 0
        return SweepResult(self.name, sweep.stamp_ns, pose, (v, omega), motion.twist_covariance, pose_cov,
                           iterations, kept, n_moving, ms, static_map, vel_use,
                           moving_map, moving_vel, motion.moving, motion.segmented, keyframe, searched, recovered,
                           jump, _wrapped(motion.predicted) if back else None, back)

    def _watch_jumps(self, source: np.ndarray, motion: MotionEstimate, stamp: float, res: ICPResult
                     ) -> tuple[ICPResult | None, str | None, bool]:
        """Whether this registered sweep fits the map where the prior put it (:mod:`.relocalise`).

        Returns the registration that relocalised it (else None), the kind of jump it ends
        (:data:`~.relocalise.RELOCALISED`, :data:`~.relocalise.NEW_PIECE`, or None) and whether it is
        suspect (it keeps the prior's pose and stays out of the map)."""
        assert self.map.tree is not None
        rp = self.params.recovery
        fit = inlier_fraction(source, res.pose, self.map.tree, rp.inlier_distance, res.search)
        suspect = self.jumps.suspect(fit)
        if not self.jumps.observe(stamp, suspect):
            return None, None, suspect
        wide = self.params.relocalise.search()
        grid = grid_for(self.map.points, wide)
        found = correlative_match(grid, source, motion.predicted, wide)
        peaks = [found.pose]
        if found.second_pose is not None and self.jumps.close(found.score, found.second_score):
            peaks.append(found.second_pose)  # a look-alike place (a hall's other end): the ICP's fits decide
        fits = []
        for peak in peaks:
            moved = dataclasses.replace(motion, predicted=peak)  # the ICP's soft prior there, not at the old place
            again = self.register(source, moved, stamp, initial=peak)
            fits.append((inlier_fraction(source, again.pose, self.map.tree, rp.inlier_distance, again.search), again))
        fits.sort(key=lambda f: -f[0])
        if self.jumps.confident(fits[0][0], fits[1][0] if len(fits) > 1 else 0.0):
            self.jumps.record(stamp, RELOCALISED, motion.predicted, fits[0][1].pose)
            return fits[0][1], RELOCALISED, False
        self.jumps.record(stamp, NEW_PIECE)
        return None, NEW_PIECE, False

    def _new_piece(self) -> None:
        """A fresh local map: the sweeps after a jump into a place the map does not hold."""
        self.map = KeyframeMap(self.params.voxel_size, self.params.local_map)

    @staticmethod
    def scan_prior(prior: PriorMotion, motion: MotionEstimate) -> bool:
        """Whether this sweep's guess is the scan-to-map search (:mod:`.scan_prior`): neither a
        motion prior nor a Doppler twist says where it was taken."""
        return prior.since_last is None and prior.twist is None and motion.fused is None

    def _scan_to_map(self, source: np.ndarray, motion: MotionEstimate, stamp: float
                     ) -> tuple[ICPResult, bool, bool]:
        """The correlative search around the constant-velocity prediction, then the ICP from its best
        pose (:mod:`.scan_prior`); a poor fit then takes the recovery's wider search as usual."""
        base = self.params.recovery.correlative
        grid = self.map.likelihood_grid(base, GRID_REUSE_KEYFRAMES)
        window = search_window(self.hold.twist, stamp - self.last_stamp, base)
        found = correlative_match(grid, source, motion.predicted, window, with_second=False)
        return self._register_or_recover(source, motion, stamp, found.pose)

    def gap_motion(self, prior: PriorMotion) -> np.ndarray | None:
        """The motion prior's motion (x, y, yaw) across a gap before this sweep; None without one."""
        return prior.since_last

    def _bridge(self, prior: PriorMotion, motion: MotionEstimate) -> tuple[MotionEstimate, np.ndarray]:
        """The sweep after a gap (:mod:`.gaps`): predicted by the motion prior's motion over the gap,
        its drift taken out (:mod:`.odometry_drift`; else the estimate's own hold), and the bridge's
        covariance (3, 3) in the map frame."""
        assert self.pose is not None
        since = self.gap_motion(prior)
        self._gap_by_prior = since is not None
        if since is not None:
            since = self.drift.corrected(since)
        predicted = motion.predicted if since is None else compose(self.pose, since)
        chord = 0.0 if since is None or not np.hypot(since[0], since[1]) > 0 else math.atan2(since[1], since[0])
        cov = to_map(bridge_covariance(since, prior.gap, self.params.wheel_noise), float(self.pose[2]) + chord)
        return MotionEstimate(motion.twist, predicted, motion.moving, motion.doppler, motion.segmented,
                              motion.twist_covariance, motion.fused, motion.within), cov

    def _match_after_gap(self, source: np.ndarray, motion: MotionEstimate, stamp: float,
                         covariance: np.ndarray) -> tuple[ICPResult, bool, bool]:
        """The sweep after a gap (:mod:`.gaps`), with the bridge's ``covariance`` (map frame) as the
        ICP's soft prior. Bridged by the motion prior: the ICP from the bridged pose on the points
        where the grid has seen (``gaps.seen_only``; every point where fewer than
        ``icp.min_correspondences`` are); where its fit is poor, as the recovery judges one, a
        correlative search around the bridged pose over a window that widens with the bridge, and the
        ICP on every point from its best pose, kept if it fits more of the sweep. Bridged by the hold
        (no prior: where the robot went is a guess) the search comes first, then the ICP from its best
        pose and the recovery as usual."""
        p, rp = self.params, self.params.recovery
        self._gap_information = gap_prior_information(covariance, p.residual_sigma)
        window = gap_window(covariance, rp.correlative, p.gaps)
        try:
            if not self._gap_by_prior:
                found = correlative_match(grid_for(self.map.points, window), source, motion.predicted, window,
                                          with_second=False)
                res, _, recovered = self._register_or_recover(source, motion, stamp, found.pose)
                return res, True, recovered
            matched = source
            if p.gaps.seen_only:
                seen = seen_before(_transform(motion.predicted, source), self.grid)
                if np.count_nonzero(seen) >= p.icp.min_correspondences:
                    matched = np.ascontiguousarray(source[seen])
            res = self.register(matched, motion, stamp)
            fit = self._fit(matched, res)
            if res.converged and fit >= rp.min_inlier_fraction:
                return res, True, False
            found = correlative_match(grid_for(self.map.points, window), source, motion.predicted, window,
                                      with_second=False)
            again = self.register(source, motion, stamp, initial=found.pose)
            return (again, True, True) if self._fit(source, again) > fit else (res, True, False)
        finally:
            self._gap_information = None

    def _fit(self, source: np.ndarray, res: ICPResult) -> float:
        """The share of ``source`` within the recovery's inlier distance of the map at ``res.pose``."""
        return inlier_fraction(source, res.pose, self.map.tree, self.params.recovery.inlier_distance, res.search)

    def _register_or_recover(self, source: np.ndarray, motion: MotionEstimate, stamp: float,
                             start: np.ndarray | None = None) -> tuple[ICPResult, bool, bool]:
        """The ICP from the prior; if its fit is poor, a correlative search around the prior and
        the ICP again from its best pose, kept if it fits better (:mod:`.recovery`).
        Returns the registration, whether the search ran and whether it replaced the first."""
        res = self.register(source, motion, stamp, initial=start)
        rp = self.params.recovery
        if not rp.enabled or self.map.tree is None:
            return res, False, False
        fit = inlier_fraction(source, res.pose, self.map.tree, rp.inlier_distance, res.search)
        if res.converged and fit >= rp.min_inlier_fraction:
            return res, False, False
        grid: LikelihoodGrid = self.map.likelihood_grid(rp.correlative)
        found = correlative_match(grid, source, motion.predicted, rp.correlative)
        again = self.register(source, motion, stamp, initial=found.pose)
        fit_again = inlier_fraction(source, again.pose, self.map.tree, rp.inlier_distance, again.search)
        return (again, True, True) if fit_again > fit else (res, True, False)


def _transform(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """:func:`~fmcwlog.geometry.transform_points` of one pose: through the compiled
    ``rotate_translate`` where :func:`fmcwlog.kernels.compiled.core` selects it (one call; its
    expression in numpy's order, each operation rounded, no FMA: the same bits)."""
    core = compiled.core()
    if (core is not None and _is_pose(pose) and type(points) is np.ndarray and points.dtype == np.float64
            and points.ndim == 2 and points.shape[1] == 2 and points.flags.c_contiguous):
        x, y, yaw = pose.tolist()
        if math.isfinite(yaw):
            return core.rotate_translate(points, math.cos(yaw), math.sin(yaw), x, y)
    return transform_points(pose, points)


def _wrapped(pose: np.ndarray) -> np.ndarray:
    """A new pose array ``(x, y, wrap_angle(yaw))``: for a float64 pose from its elements as floats
    (the same values, three numpy indexings fewer)."""
    if _is_pose(pose):
        x, y, yaw = pose.tolist()
        return np.array([x, y, wrap_angle(yaw)])
    return np.array([pose[0], pose[1], wrap_angle(pose[2])])


def _step_length(last: np.ndarray, pose: np.ndarray) -> float:
    """Distance (m) between two poses' positions: ``np.hypot`` of the differences (as floats when
    both are float64 poses: the same subtractions and the same ``np.hypot``)."""
    if _is_pose(last) and _is_pose(pose):
        (x0, y0, _), (x1, y1, _) = last.tolist(), pose.tolist()
        return float(np.hypot(x1 - x0, y1 - y0))
    return float(np.hypot(*(pose[:2] - last[:2])))


def registration_covariance(hessian: np.ndarray, residual_sigma: float) -> np.ndarray | None:
    """Covariance (3, 3) of a registered pose: ``σ² H⁻¹`` with ``H = JᵀWJ`` (+ the prior's
    information, already in those units), residuals of standard deviation ``σ`` (m).
    None when ``H`` is singular (a scan that fixes no direction).

    Where :func:`fmcwlog.kernels.compiled.core` selects the compiled kernels, the inverse is the
    adjugate's on Python floats (:func:`_inv3_floats`; to rounding, ~1e-16 relative on a
    well-conditioned ``H``), else :func:`registration_covariance_numpy` (the reference)."""
    if compiled.core() is None or hessian.shape != (3, 3):
        return registration_covariance_numpy(hessian, residual_sigma)
    inv = _inv3_floats(hessian.tolist())
    if inv is None:
        return None
    s2 = residual_sigma**2
    cov = [s2 * q for q in inv]
    if not all(map(math.isfinite, cov)):
        return None
    return np.array([cov[0:3], cov[3:6], cov[6:9]])


def _inv3_floats(m: list[list[float]]) -> list[float] | None:
    """The inverse of a 3x3 nested list of floats by cofactors, row-major (9,); None where the
    determinant is 0 or not finite (numpy's ``inv`` raises on an exactly singular matrix)."""
    (a, b, c), (d, e, f), (g, h, i) = m
    c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g  # cofactors of the first row
    det = a * c00 + b * c01 + c * c02
    if det == 0.0 or not math.isfinite(det):
        return None
    r = 1.0 / det
    return [c00 * r, (c * h - b * i) * r, (b * f - c * e) * r,
            c01 * r, (a * i - c * g) * r, (c * d - a * f) * r,
            c02 * r, (b * g - a * h) * r, (a * e - b * d) * r]


def registration_covariance_numpy(hessian: np.ndarray, residual_sigma: float) -> np.ndarray | None:
    """:func:`registration_covariance` with ``np.linalg.inv``: the reference."""
    try:
        cov = residual_sigma**2 * np.linalg.inv(hessian)
    except np.linalg.LinAlgError:
        return None
    return cov if np.all(np.isfinite(cov)) else None


class ImprovedFrontEnd(FrontEnd):
    """The paper's front end (§4): Doppler ego-motion and segmentation, GMMSC, robust ICP.

    Its twist is Doppler's fused with the wheels' (:mod:`.twist_fusion`), which holds at any
    mount; :mod:`.sensor_checks` watches the two against each other and against the scans;
    the per-sweep sums for the calibration check (:mod:`.self_calibration`) are kept here.
    """

    name = IMPROVED
    segments = True
    bearings = True

    def __init__(self, params: FrontEndParams, cal: Calibration):
        super().__init__(params, cal)
        self.mixture: DistanceMixture | None = None  # the last GMMSC mixture, reused by the next sweep's ICP
        self.design = doppler_design(cal.mount)
        self.checks = SensorChecks(self.mount, self.design, params.sensor_checks, params.wheel_noise)
        self.mount_check = MountCheck(self.mount, params.mount_check, cal.upside_down)  # the scans mirrored or turned round?
        self.sources = TwistSources()
        self.samples = CalibrationSamples()
        self.scan_twist = (0.0, 0.0)  # (v, ω) scan matching measured over the last interval: the hold
        self._drop_wheels = False  # for this sweep: the scans sided with Doppler against the wheels
        self._raw_fit: EgoMotion | None = None  # this sweep's Doppler fit free of the wheels' gate
        self._fit_doppler = np.zeros(0)  # this sweep's Doppler as fit (m/s; NaN inside the body)
        self._registered_last = False
        self.tracker = MoverTracker(params.tracking, params.map_resolution)  # movers followed over this log's sweeps
        self._doppler_floor = np.eye(2) * params.doppler_sigma_min**2  # added to the fit's covariance (m²/s²)
        self._floor = float(self._doppler_floor[0, 0])  # its diagonal as a float
        self._design_rows = self.design.tolist()  # the design matrix as nested lists, for the float path
        noise = params.wheel_noise
        self.observed = ObservedNoise(noise.adapt_rate, noise.adapt_gate, noise.adapt_min_sweeps)  # the sources' errors
        self._pair: _Pair | None = None  # this sweep's, for the observed noise (_Pair)
        self._last_pair: _Pair | None = None  # the last sweep's
        # the sweeps compared, not yet judged by a whole window of the vote: Doppler's, the wheels' and the
        # scans' (v, ω), and Doppler's claimed variances
        self._pending: list[tuple[tuple[float, float], tuple[float, float], tuple[float, float], tuple[float, float]]] = []

    def _new_piece(self) -> None:
        """A fresh local map, and a fresh tracker: its tracks and free space are of the place left."""
        super()._new_piece()
        self.tracker = MoverTracker(self.params.tracking, self.params.map_resolution)

    def _into_grid(self, scan: Scan) -> None:
        """The grid, and the tracker's free space, which holds the last stretch of path only
        (:mod:`.recent_grid`): the same scan, cast once for both."""
        super()._into_grid(scan)
        if self.params.tracking.enabled:
            self.tracker.add_scan(scan, self.path_m)

    def prior_twist(self, prior: PriorMotion) -> tuple[float, float]:
        """The wheels' twist, else the constant-velocity hold."""
        return prior.twist if prior.twist is not None else self.hold.twist

    def doppler_stages(self, sweep: SweepInput, prior_twist: tuple[float, float] | None) -> Doppler | None:
        """Ego-motion and segmentation of one sweep; None without Doppler (or once it was dropped).

        ``prior_twist``: the odometry's ``(v, ω)`` over the sweep; the Doppler fit
        keeps within ``doppler_prior_gate`` of it, so that a crowd walking together
        cannot pass for the static world.
        """
        if sweep.velocity is None or not self.checks.use_doppler:
            return None
        found = self._sweep  # the step's bearings of this sweep, else computed here; for the fit and for ε
        bearings = found.bearings if found is not None and found.xy is sweep.xy and found.bearings is not None else (
            unit_bearings(sweep.xy))
        ego = self.doppler_fit(sweep, prior_twist, bearings)
        if ego is None:
            return Doppler(np.full(2, np.nan), np.full((2, 2), np.nan), np.zeros(len(sweep.xy), bool))
        eps = compensated_velocity(sweep.xy, sweep.velocity, ego.v_sensor, bearings)  # thresholded, not v_r (docs/physics.md)
        # the twist only places this sweep's points in the map for tracking: the wheels' (their
        # 0.5 % bias moves a point < 1 mm over a sweep), else the last scan-matched one
        twist = prior_twist if prior_twist is not None and _finite_pair(prior_twist) else self.scan_twist
        moving = self.segment(sweep, eps, twist)
        if self.params.doppler_refit:  # the fit again without the movers, its gate from the sweep's spread
            ego = refit_static(bearings, self._fit_doppler, ego, moving, scale_gate=self.params.doppler_refit_gate)
        return Doppler(ego.v_sensor, ego.covariance, moving)

    def doppler_fit(self, sweep: SweepInput, prior_twist: tuple[float, float] | None,
                    bearings: np.ndarray | None = None) -> EgoMotion | None:
        """The lidar's velocity from the sweep's Doppler (None if it cannot be fit, or the scans
        say it is wrong for this sweep); :mod:`.sensor_checks` decides when it disputes the wheels.
        ``bearings``: the points' unit bearings, if computed already."""
        assert sweep.velocity is not None
        p = self.params
        expected = None
        fast = compiled.core() is not None
        if prior_twist is not None and _finite_pair(prior_twist):
            if fast:  # the 2x2 product on floats (to rounding)
                (a00, a01), (a10, a11) = self._design_rows
                v, w = float(prior_twist[0]), float(prior_twist[1])
                expected = np.array([a00 * v + a01 * w, a10 * v + a11 * w])
            else:
                expected = self.design @ np.asarray(prior_twist, dtype=float)
        # returns inside the body mask are the robot itself (or a cover on the window): they move with
        # the sensor, Doppler 0 whatever the motion, so they are no evidence of it
        near = self._near_of(sweep.xy) if fast else None
        inside = (sweep.xy[:, 0] ** 2 + sweep.xy[:, 1] ** 2) < p.min_range**2 if near is None else near
        v_r = np.where(inside, np.nan, sweep.velocity) if inside.any() else sweep.velocity
        self._fit_doppler = v_r
        ego = fit_sensor_velocity(sweep.xy, v_r, random_state=p.seed, prior=expected,
                                  prior_gate=p.doppler_prior_gate, bearings=bearings)
        self._raw_fit = ego.unconstrained or ego
        decision = self.checks.judge(sweep.stamp_ns * 1e-9, sweep.xy, ego, prior_twist, expected)
        if decision == DOPPLER and ego.unconstrained is not None:
            self._drop_wheels = True
            ego = ego.unconstrained
        elif decision == WHEELS:
            return None
        return ego if _finite(ego.v_sensor) else None

    def fuse(self, doppler: Doppler, wheels: PriorMotion) -> FusedTwist:
        """Doppler's two equations and the wheels' (or the hold's) ``(v, ω)`` by weighted least squares."""
        p = self.params
        if compiled.core() is not None and type(doppler.v_sensor) is np.ndarray and doppler.v_sensor.shape == (2,):
            return self._fuse_floats(doppler, wheels)
        if wheels.twist is not None:
            x_w, c_w = np.asarray(wheels.twist, dtype=float), wheel_covariance(wheels.twist, p.wheel_noise)
        else:
            x_w, c_w = np.asarray(self.scan_twist, dtype=float), hold_covariance(p.wheel_noise)
        c_d = doppler.covariance + self._doppler_floor
        if wheels.twist is not None and self.observed.rate > 0:
            cd, (s_v, s_w) = self._observed_weights(doppler, (float(x_w[0]), float(x_w[1])), c_d.tolist(),
                                                    (float(c_w[0, 0]), float(c_w[1, 1])))
            c_d, c_w = np.array(cd), np.array([[s_v, 0.0], [0.0, s_w]])
        return fuse_twist(doppler.v_sensor, c_d, self.design, x_w, c_w)

    def _observed_weights(self, doppler: Doppler, x_w: tuple[float, float], c_d: list[list[float]],
                          wheel_var: tuple[float, float]) -> tuple[list[list[float]], tuple[float, float]]:
        """Doppler's covariance (lidar frame) and the wheels' variances for this sweep's fusion, from what
        the recent sweeps show (:class:`~.twist_fusion.ObservedNoise`), and this sweep kept for it.

        Only where the sensor checks keep both sources: no source outvoted, none dropped, and (with the
        vote on) after its first judged window; elsewhere the nominal ones, and the sweep is not
        counted, so that the estimate is not taken from a source the checks found faulty."""
        checks = self.checks
        vote = checks.vote
        if vote.outvoted is not None or not (checks.use_doppler and checks.use_wheels):
            return c_d, wheel_var
        base = base_variances(c_d, self._design_rows)
        self._pair = (self._doppler_base(doppler), x_w, (math.nan, math.nan) if base is None else (base[0], base[2]))
        if checks.params.vote and vote.judged == 0:
            return c_d, wheel_var
        return self.observed.weights(c_d, self._design_rows, wheel_var, self.params.wheel_noise)

    def _doppler_base(self, doppler: Doppler) -> tuple[float, float]:
        """Doppler's ``(v, ω)`` of base_link alone, ``A⁻¹ z`` (NaN where ``A`` is singular)."""
        (a00, a01), (a10, a11) = self._design_rows
        det = a00 * a11 - a01 * a10
        if not abs(det) > 1e-9:
            return (math.nan, math.nan)
        z0, z1 = float(doppler.v_sensor[0]), float(doppler.v_sensor[1])
        return ((a11 * z0 - a01 * z1) / det, (a00 * z1 - a10 * z0) / det)

    def _fuse_floats(self, doppler: Doppler, wheels: PriorMotion) -> FusedTwist:
        """:meth:`fuse` on Python floats (:func:`~.twist_fusion.fuse_twist_lists`, what :func:`fuse_twist`
        computes where the compiled kernels run): the wheels' or the hold's diagonal covariance and the
        floor added to the fit's covariance as numbers, the design matrix read once per log."""
        p = self.params
        if wheels.twist is not None:
            x_w = [float(wheels.twist[0]), float(wheels.twist[1])]
            s_v, s_w = wheel_variances(wheels.twist, p.wheel_noise)
        else:
            x_w = [float(self.scan_twist[0]), float(self.scan_twist[1])]
            s_v, s_w = p.wheel_noise.hold_speed**2, p.wheel_noise.hold_yaw_rate**2  # hold_covariance's
        (c00, c01), (c10, c11) = doppler.covariance.tolist()
        floor = self._floor
        c_d = [[c00 + floor, c01 + 0.0], [c10 + 0.0, c11 + floor]]  # + the floor's eye(2) * σ²
        if wheels.twist is not None and self.observed.rate > 0:  # as fuse
            c_d, (s_v, s_w) = self._observed_weights(doppler, (x_w[0], x_w[1]), c_d, (s_v, s_w))
        return fuse_twist_lists(doppler.v_sensor.tolist(), c_d, self._design_rows, x_w, [[s_v, 0.0], [0.0, s_w]])

    def segment(self, sweep: SweepInput, eps: np.ndarray, twist: tuple[float, float] | None) -> np.ndarray:
        """Moving mask (N,): DBSCAN and the Doppler verdict (eq. 17-19) and, with tracking on, the
        movers followed from earlier sweeps and the map's free space (:mod:`.tracking`). ``eps``:
        compensated Doppler (m/s); ``twist``: ``(v, ω)`` over the sweep, to place its points in the map."""
        p = self.params
        if not p.tracking.enabled:
            return segment_moving(sweep.xy, eps, p.segmentation)
        v, omega = twist if twist is not None and _finite_pair(twist) else (0.0, 0.0)
        ts = sweep.stamp_ns * 1e-9
        base, yaw_error = np.zeros(3), 0.0
        if self.pose is not None:  # the last sweep's twist spans most of the time since it (yaw error 3x smaller)
            dt = ts - self.last_stamp
            base = advance(self.pose, self.last_twist[0], self.last_twist[1], dt)
            yaw_error = abs(omega - self.last_twist[1]) * dt  # a step in ω since the last sweep (a corner's end)
        found = self._sweep  # the step's ranges and middle time of this sweep, else the tracker computes them
        ranges, middle = (found.ranges, found.middle_time) if found is not None and found.xy is sweep.xy else (None, None)
        return self.tracker.segment(sweep.xy, sweep.t, eps, ts, base, (v, omega), self.mount, self.grid,
                                    p.segmentation, yaw_error, ranges, middle)

    def _near_of(self, xy: np.ndarray) -> np.ndarray | None:
        """The step's ``near`` mask (ranges below ``min_range``) of ``xy`` if this is the sweep in
        :meth:`step`, else None. The same points as ``x² + y² < min_range²`` but for a point within
        a rounding of the circle (``np.hypot`` against the squares)."""
        found = self._sweep
        return found.near if found is not None and found.xy is xy else None

    def estimate_motion(self, sweep: SweepInput, prior: PriorMotion) -> MotionEstimate:
        ts = sweep.stamp_ns * 1e-9
        wheels = prior if self.checks.use_wheels else PriorMotion()
        self._drop_wheels, self._raw_fit, self._pair = False, None, None
        self.mount_check.sweep(ts, sweep.xy)
        doppler = self.doppler_stages(sweep, wheels.twist)
        if self._drop_wheels or self.checks.vote.outvoted == WHEELS:
            wheels = PriorMotion()
        self._keep_doppler_sample(ts, wheels)
        segmented = doppler is not None and self.params.segment
        moving = doppler.moving.copy() if doppler is not None and segmented else np.zeros(len(sweep.xy), bool)
        fused = self.fuse(doppler, wheels) if doppler is not None and doppler.usable else None
        self.sources.count(doppler is not None, fused, wheels.twist is not None, self.params.doppler_twist)
        if fused is None or not self.params.doppler_twist:
            twist = self.prior_twist(wheels)
            return MotionEstimate(twist, self.predict(ts, wheels, twist), moving, doppler, segmented, fused=fused,
                                  within=wheels.within)
        twist = (float(fused.twist[0]), float(fused.twist[1]))
        if self.pose is None:
            predicted = np.zeros(3)
        else:  # the twist at the middle of the interval since the last sweep
            v_mid, w_mid = 0.5 * (twist[0] + self.last_twist[0]), 0.5 * (twist[1] + self.last_twist[1])
            predicted = advance(self.pose, v_mid, w_mid, ts - self.last_stamp)
        return MotionEstimate(twist, predicted, moving, doppler, segmented, fused.covariance, fused, wheels.within)

    def register(self, source: np.ndarray, motion: MotionEstimate, stamp: float,
                 initial: np.ndarray | None = None) -> ICPResult:
        prior_info = None
        f = motion.fused
        if self._gap_information is not None:
            prior_info = self._gap_information
        elif f is not None and self.params.doppler_prior:
            prior_info = doppler_prior_information(motion.predicted[2], f.covariance[0, 0], f.covariance[1, 1],
                                                   stamp - self.last_stamp, self.params)
            if initial is None:  # a recovery's second ICP is the same sweep
                self.sources.prior_sweeps += 1
        start = motion.predicted if initial is None else initial
        rp = self.params.recovery
        res = register(source, self.map.tree, self.map.points, start, self.params.icp,
                       mixture=self.mixture, prior_pose=motion.predicted if prior_info is not None else None,
                       prior_information=prior_info, inlier_distance=rp.inlier_distance if rp.enabled else None)
        self.mixture = res.mixture
        return res

    def _keep_doppler_sample(self, stamp: float, wheels: PriorMotion) -> None:
        """This sweep's Doppler velocity and wheel turns, for the calibration check."""
        fit = self._raw_fit
        if fit is not None and wheels.turns is not None and wheels.span > 0 and _finite(fit.covariance):
            self.samples.add_doppler(stamp, fit.v_sensor, fit.covariance, wheels.turns, wheels.span)

    def after_step(self, pose: np.ndarray, stamp: float, registered: bool, prior: PriorMotion) -> None:
        if self.pose is None:
            return
        dt = stamp - self.last_stamp
        d = between_floats(self.pose, pose) or between(self.pose, pose)
        if dt > 0:
            self.scan_twist = (float(d[0] / dt), float(d[2] / dt))
            if self._last_pair is not None and registered:  # the scans' motion over the last sweep's interval
                x_d, x_w, claim = self._last_pair
                self._pending.append((x_d, x_w, self.scan_twist, claim))
        self._last_pair = self._pair
        # the vote's window spans consecutive sweeps only: a gap (no wheels given) starts it anew
        self.checks.interval(self.last_stamp, stamp, None if prior.gap else prior.since_last,
                             float(d[2]) if registered else None)
        self._check_mount(stamp, prior)
        self._pass_pending()
        if (registered and self._registered_last and prior.turns_since_last is not None and self.checks.use_wheels
                and not prior.gap):
            self.samples.add_yaw(stamp, float(d[2]), prior.turns_since_last, dt)
        self._registered_last = registered

    def _pass_pending(self) -> None:
        """The sweeps compared for the observed noise go to it once a whole window of the vote
        (``vote_sweeps``) has judged them with no source outvoted; a window that outvotes one (or a
        source dropped) discards them: the onset of a fault, before the vote sees it, is not
        evidence of the other source's noise. Without the vote they go at once."""
        checks = self.checks
        if checks.vote.outvoted is not None or not (checks.use_doppler and checks.use_wheels):
            self._pending.clear()
            return
        keep = checks.params.vote_sweeps if checks.params.vote else 0
        while len(self._pending) > keep:
            self.observed.add(*self._pending.pop(0))

    def gap_motion(self, prior: PriorMotion) -> np.ndarray | None:
        """The wheels' motion across a gap, unless the sensor checks dropped them as faulty."""
        return prior.since_last if self.checks.use_wheels else None

    def _check_mount(self, stamp: float, prior: PriorMotion) -> None:
        """The interval for :mod:`.mirror_check`; where the scans fit the wheels only in another frame,
        and better than any wheel fault that mimics it, the sensor checks stop blaming the wheels."""
        check = self.mount_check
        if check.settled:
            return
        check.interval(self.last_stamp, stamp, None if prior.gap else prior.since_last)
        if check.found_at is not None and check.blame() == SCANNER and not self.checks.scanner_at_fault:
            self.checks.exonerate_wheels()

    def _mount_fault(self, prior_name: str) -> str | None:
        """The mount check's warning, where the scans blame the scanner (or cannot tell it from the wheels)."""
        return self.mount_check.warning(prior_name) if self.mount_check.blame() not in (None, WHEELS_FAULT) else None

    def calibration_estimate(self) -> CalibrationEstimate | None:
        """The mount and wheels the log shows (:mod:`.self_calibration`); None when it cannot say
        (no wheel ticks or Doppler, too little motion, or a source dropped as faulty)."""
        if (self.checks.dropped_at or self.cal.wheels is None or self.checks.calibration_veto("") is not None
                or self._mount_fault("") is not None):
            return None
        return estimate_calibration(self.samples, self.cal, self.params.self_calibration)

    def diagnostics(self, prior_name: str) -> tuple[dict, list[str]]:
        """Where the twist came from, what the sensor checks found, and warnings about either."""
        p = self.params
        seen = observability(self.cal.mount, p.min_lever)
        out = {"doppler_observes": seen, **self.sources.summary(), "sensor_checks": self.checks.summary(),
               "mount_check": self.mount_check.summary()}
        mount = self._mount_fault(prior_name)
        if mount is not None and self.mount_check.blame() == EITHER and WHEELS in self.checks.dropped_at:
            self.checks.scanner_alternative, mount = self.mount_check.alternative(prior_name), None  # said with the wheels' line
        warnings = self.sources.warnings(seen, prior_name) + self.checks.warnings(prior_name) + ([mount] if mount else [])
        check, check_warnings = calibration_report(self.calibration_estimate(), self.cal, p.self_calibration,
                                                   self._why_no_calibration(prior_name))
        out["calibration_check"] = check
        return out, warnings + check_warnings

    def _why_no_calibration(self, prior_name: str = "wheel ticks") -> str | None:
        """Why there can be no calibration estimate; None when only too little motion would explain it."""
        if self.cal.wheels is None:
            return "needs wheel ticks (and the calibration's wheels)"
        mount = self._mount_fault(prior_name)
        if mount is not None:
            return mount
        if self.checks.dropped_at:
            return f"a source was dropped as faulty ({', '.join(sorted(self.checks.dropped_at))})"
        veto = self.checks.calibration_veto(prior_name)
        if veto is not None:
            return veto
        if not self.samples.doppler:
            return "needs Doppler and wheel ticks in the same sweeps"
        return None


def doppler_prior_information(yaw: float, v_var: float, omega_var: float, dt: float,
                              p: FrontEndParams) -> np.ndarray:
    """The ICP's soft prior on the predicted pose (3, 3), in the units of its normal equations.

    Along the path the Doppler speed integrated over ``dt`` (s) has standard deviation
    ``√v_var·dt`` (m); across it the rear axle does not slide; in yaw ``√ω_var·dt`` (rad);
    each floored by ``prior_sigma_*``. Rotated into ``map`` by the predicted ``yaw`` and
    scaled by ``residual_sigma²`` to weigh against the point residuals.

    Where :func:`fmcwlog.kernels.compiled.core` selects the compiled kernels, on Python floats with
    the inverse in closed form, ``R diag(1/σ_along², 1/σ_across²) Rᵀ`` (the same to rounding),
    else :func:`doppler_prior_information_numpy` (the reference).
    """
    if compiled.core() is None or not (v_var >= 0.0 and omega_var >= 0.0 and math.isfinite(yaw)):
        return doppler_prior_information_numpy(yaw, v_var, omega_var, dt, p)  # (math's raise where numpy's give NaN)
    s_along = max(math.sqrt(v_var) * dt, p.prior_sigma_along)
    s_yaw = max(math.sqrt(omega_var) * dt, p.prior_sigma_yaw)
    c, s = math.cos(yaw), math.sin(yaw)
    i_along, i_across = 1.0 / s_along**2, 1.0 / p.prior_sigma_across**2
    i_xy = c * s * (i_along - i_across)
    w = p.residual_sigma**2
    return np.array([[(c * c * i_along + s * s * i_across) * w, i_xy * w, 0.0],
                     [i_xy * w, (s * s * i_along + c * c * i_across) * w, 0.0],
                     [0.0, 0.0, w / s_yaw**2]])


def doppler_prior_information_numpy(yaw: float, v_var: float, omega_var: float, dt: float,
                                    p: FrontEndParams) -> np.ndarray:
    """:func:`doppler_prior_information` in numpy: the reference."""
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
    """The classic ICP baseline: all points, the wheel-odometry prior, point-to-point ICP (its source
    thinned to a point per ``source_voxel`` voxel, as classic ICP pipelines do; module docstring)."""

    name = BASELINE

    def estimate_motion(self, sweep: SweepInput, prior: PriorMotion) -> MotionEstimate:
        twist = self.prior_twist(prior)
        return MotionEstimate(twist, self.predict(sweep.stamp_ns * 1e-9, prior, twist), np.zeros(len(sweep.xy), bool),
                              within=prior.within)

    def register(self, source: np.ndarray, motion: MotionEstimate, stamp: float,
                 initial: np.ndarray | None = None) -> ICPResult:
        start = motion.predicted if initial is None else initial
        rp = self.params.recovery
        return register_point_to_point(source, self.map.tree, self.map.points, start, self.params.icp,
                                       rp.inlier_distance if rp.enabled else None)


METHODS: dict[str, type[FrontEnd]] = {cls.name: cls for cls in (ImprovedFrontEnd, BaselineFrontEnd)}
