"""The parameters of a front end: its own, and each stage's as a nested table.

Every numeric parameter declares its unit and range beside its default
(:func:`fmcwlog.config.param`); a value outside it is refused with one line naming it. The
parameters of a whole run (these and the back end's) and how config files and ``--set`` reach
them are :mod:`fmcwlog.pipeline.params`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..config import Checked, param
from .gaps import GapParams
from .icp import ICPParams
from .keyframe_map import LocalMapParams
from .mirror_check import MountCheckParams
from .recovery import RecoveryParams
from .relocalise import RelocaliseParams
from .segmentation import SegmentationParams
from .self_calibration import SelfCalibrationParams
from .sensor_checks import CheckParams
from .tracking import TrackingParams
from .twist_fusion import WheelNoise


@dataclass(frozen=True)
class FrontEndParams(Checked):
    """Everything a front end needs besides the log; all have documented defaults.

    min_range: returns closer than this (m) are dropped (the robot's own body).
    keyframe_distance, keyframe_angle_deg: a sweep enters the map after this much
        motion since the last keyframe (m, deg).
    grid_distance, grid_angle_deg: the same for the occupancy grid, whose ray
        casting costs more than a map update and gains little from dense sweeps.
    source_voxel: the sweep is thinned to one point per voxel of this size (m)
        before registration (the map keeps full density); 0 keeps every point.
    source_thinning: which point a ``source_voxel`` voxel keeps: ``first``, its first point in
        beam order (:func:`fmcwlog.kernels.voxel.voxel_downsample`), or ``centroid``, the mean of
        its points, whatever their order (:func:`fmcwlog.kernels.voxel.voxel_centroids`);
        docs/design/frontend-params.md has the measurements behind the default.
    voxel_size: map point spacing (m).
    map_resolution: occupancy grid cell size (m).
    prior_sigma_along, prior_sigma_across, prior_sigma_yaw: floor of the Doppler
        prior's standard deviation per sweep (m, m, rad), in the robot's frame.
    residual_sigma: scale of an ICP residual (m) that converts the prior's
        covariance into the units of the ICP's normal equations.
    doppler_prior_gate: the Doppler ego-velocity may differ from the odometry's
        prediction by at most this much (m/s; wheels slip and are miscalibrated
        by far less); see :meth:`fmcwlog.frontend.methods.ImprovedFrontEnd.doppler_stages`.
    seed: seed of the Doppler RANSAC (results are deterministic given it).
    doppler_sigma_min: added in quadrature to each component of a sweep's Doppler
        velocity before it is fused with the wheels (m/s): the fit's own covariance
        assumes independent points, which 0.1 m/s quantisation and speed changing within
        the sweep are not (measured: 2.5 mm/s rms error against 1.7 mm/s claimed).
    doppler_refit: where the sweep's Doppler residuals spread wider than the first fit's 0.15 m/s
        gate allows (a robust standard deviation above half of it: a coarse Doppler), fit the
        Doppler velocity again once the sweep is segmented, without the points judged moving and
        with a gate of ``doppler_refit_gate`` robust standard deviations
        (:func:`fmcwlog.frontend.egomotion.refit_static`). There
        the first fit leans toward movers close to static and toward the quantisation steps its
        narrow gate truncates: on the 60 s ``crowd`` log with bench/sensors/worse-doppler.toml
        (seed 0) its bias was +1.1 cm/s and +12 mrad/s, against +0.02 cm/s and +0.9 mrad/s for
        least squares on the truly static points. A Doppler as fine as the paper's keeps its first
        fit (refit there, the 60 s ``corridor`` logs' ATE went from 2.0 to 3.3 cm, mean of seeds 0-2).
    doppler_refit_gate: that gate in robust standard deviations (MAD), > 0.
    min_lever: a lever arm ``|lidar_x|`` below this (m) is reported as "Doppler does not
        observe ω" (the fusion itself needs no threshold).
    wheel_noise: how far the wheels' twist is trusted in the fusion
        (:class:`fmcwlog.frontend.twist_fusion.WheelNoise`).
    sensor_checks: Doppler against the wheels and the scans
        (:class:`fmcwlog.frontend.sensor_checks.CheckParams`).
    mount_check: whether the scans are mirrored or turned by π against the calibrated mount
        (:class:`fmcwlog.frontend.mirror_check.MountCheckParams`).
    self_calibration: the calibration check
        (:class:`fmcwlog.frontend.self_calibration.SelfCalibrationParams`).

    Stage switches of the improved method, for ablation studies (each True by default;
    ``icp.use_gmmsc`` and ``icp.use_huber`` switch GMMSC and the Huber kernel):
    segment: remove the points segmentation judges moving (eq. 17-19).
    deskew: move every point to the sweep's stamp; False matches them where they were seen.
    deskew_motion: the motion the points are moved by: ``"twist"`` the sweep's one twist
        ``(v, ω)``, held over it; ``"wheels"`` the motion prior's track within the sweep (its arcs
        between the ticks, their yaw rates as measured, their speeds scaled to the twist's mean
        speed) where the wheels are in use, the track covers the sweep and its yaw rate changes
        within it (``deskew_min_yaw_step``), else the twist (:mod:`fmcwlog.frontend.deskew_wheels`).
    deskew_min_yaw_step: with ``deskew_motion = "wheels"``, the least spread (largest less smallest)
        of the wheels' yaw rates within a sweep for it to be de-skewed by their motion; a steadier
        sweep takes the twist, which the ticks' quantisation does not shake.
    doppler_twist: deskew and predict with the Doppler twist; False uses the wheels'.
    doppler_prior: hold the ICP to the Doppler-predicted motion along the path.
    gaps: what a gap in the sweeps is and how it is bridged (:class:`fmcwlog.frontend.gaps.GapParams`).
    relocalise: sweeps that stop fitting the map where the prior puts them, a robot carried away
        (:class:`fmcwlog.frontend.relocalise.RelocaliseParams`).
    """

    segmentation: SegmentationParams = field(default_factory=SegmentationParams)
    tracking: TrackingParams = field(default_factory=TrackingParams)
    # Stop ICP at 0.5 mm / 0.1 mrad steps: on the 2-minute corridor log this takes the
    # improved front end from 5.5 to 4.3 ms per sweep at the same ATE (1.9 -> 1.5 cm).
    icp: ICPParams = field(default_factory=lambda: ICPParams(translation_tol=5e-4, rotation_tol=1e-4))
    min_range: float = param(0.3, "m", ge=0.0, le=10.0)
    keyframe_distance: float = param(0.2, "m", ge=0.0, le=100.0)  # 0: every sweep is a keyframe
    keyframe_angle_deg: float = param(5.0, "deg", ge=0.0, le=180.0)
    # 0.5 m: a coarser 1 m halves the ray casting but lets more static points be judged moving in
    # dense crowds (docs/design/frontend-params.md)
    grid_distance: float = param(0.5, "m", ge=0.0, le=100.0)
    grid_angle_deg: float = param(10.0, "deg", ge=0.0, le=180.0)
    source_voxel: float = param(0.1, "m", ge=0.0, le=10.0)
    source_thinning: str = param("first", "", choices=("first", "centroid"))
    # the map keeps a point per voxel, so its size follows the area seen over voxel_size²; 1 mm is
    # already finer than any planar LiDAR's range noise
    voxel_size: float = param(0.05, "m", ge=0.001, le=10.0)
    # a cell finer than 1 cm cannot be resolved by ranges quantised to 2 cm (Table 1), and costs
    # area / resolution² cells: 10 µm made a 100 m floor a grid of 1e14 cells
    map_resolution: float = param(0.05, "m", ge=0.01, le=10.0)
    # standard deviations: 0 would be an infinitely certain prior (a division by zero)
    prior_sigma_along: float = param(0.002, "m", gt=0.0, le=10.0)
    prior_sigma_across: float = param(0.005, "m", gt=0.0, le=10.0)
    prior_sigma_yaw: float = param(0.005, "rad", gt=0.0, le=math.pi)
    residual_sigma: float = param(0.03, "m", gt=0.0, le=10.0)
    doppler_prior_gate: float = param(0.3, "m/s", ge=0.0, le=100.0)
    seed: int = param(0, "", ge=0, le=2**32 - 1)
    doppler_sigma_min: float = param(0.002, "m/s", gt=0.0, le=10.0)
    doppler_refit: bool = True
    doppler_refit_gate: float = param(3.0, "", gt=0.0, le=100.0)
    min_lever: float = param(0.05, "m", gt=0.0, le=10.0)
    wheel_noise: WheelNoise = field(default_factory=WheelNoise)
    sensor_checks: CheckParams = field(default_factory=CheckParams)
    mount_check: MountCheckParams = field(default_factory=MountCheckParams)
    self_calibration: SelfCalibrationParams = field(default_factory=SelfCalibrationParams)
    segment: bool = True
    deskew: bool = True
    deskew_motion: str = param("wheels", "", choices=("twist", "wheels"))
    # 0.2 rad/s: ten times the spread one tick of yaw (0.34 mrad at 4096 ticks a turn) gives over a
    # 20 ms segment, a tenth of the yaw-rate step that enters or leaves a turn at speed
    deskew_min_yaw_step: float = param(0.2, "rad/s", ge=0.0, le=100.0)
    doppler_twist: bool = True
    doppler_prior: bool = True
    # the map scans are matched against, and the recovery from a poor prior (not in the paper)
    local_map: LocalMapParams = field(default_factory=LocalMapParams)
    recovery: RecoveryParams = field(default_factory=RecoveryParams)
    gaps: GapParams = field(default_factory=GapParams)
    relocalise: RelocaliseParams = field(default_factory=RelocaliseParams)
