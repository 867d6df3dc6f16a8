"""The parameters of a front end, and how config files and ``--set`` reach them.

A config file (TOML, YAML or JSON) holds the same structure as
:class:`FrontEndParams`: the front end's own parameters at the top level (or in
a ``[frontend]`` table), each stage's in its own table (``[segmentation]``,
``[tracking]``, ``[icp]``, ``[icp.gmmsc]``). ``fmcwlog process --show-config`` prints exactly
that as TOML (:func:`frontend_params_toml`, each parameter with its unit and valid range),
and ``run.json`` records it under ``params``, so either can be fed back. Every numeric
parameter declares its range beside its default (:func:`fmcwlog.config.param`); a value
outside it is refused with one line naming it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..backend.params import BackendParams
from ..config import Checked, apply_to_dataclass, param, toml_table
from ..errors import ConfigError
from .icp import ICPParams
from .keyframe_map import LocalMapParams
from .recovery import RecoveryParams
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
    min_lever: a lever arm ``|lidar_x|`` below this (m) is reported as "Doppler does not
        observe ω" (the fusion itself needs no threshold).
    wheel_noise: how far the wheels' twist is trusted in the fusion
        (:class:`fmcwlog.frontend.twist_fusion.WheelNoise`).
    sensor_checks: Doppler against the wheels and the scans
        (:class:`fmcwlog.frontend.sensor_checks.CheckParams`).
    self_calibration: the calibration check
        (:class:`fmcwlog.frontend.self_calibration.SelfCalibrationParams`).

    Stage switches of the improved method, for ablation studies (each True by default;
    ``icp.use_gmmsc`` and ``icp.use_huber`` switch GMMSC and the Huber kernel):
    segment: remove the points segmentation judges moving (eq. 17-19).
    deskew: move every point to the sweep's stamp; False matches them where they were seen.
    doppler_twist: deskew and predict with the Doppler twist; False uses the wheels'.
    doppler_prior: hold the ICP to the Doppler-predicted motion along the path.
    """

    segmentation: SegmentationParams = field(default_factory=SegmentationParams)
    tracking: TrackingParams = field(default_factory=TrackingParams)
    # Stop ICP at 0.5 mm / 0.1 mrad steps: on the 2-minute corridor log this takes the
    # improved front end from 5.5 to 4.3 ms per sweep at the same ATE (1.9 -> 1.5 cm).
    icp: ICPParams = field(default_factory=lambda: ICPParams(translation_tol=5e-4, rotation_tol=1e-4))
    min_range: float = param(0.3, "m", ge=0.0, le=10.0)
    keyframe_distance: float = param(0.2, "m", ge=0.0, le=100.0)  # 0: every sweep is a keyframe
    keyframe_angle_deg: float = param(5.0, "deg", ge=0.0, le=180.0)
    # 1 m (issue 14) was measured and not taken: it cuts the ray casting, shared by the grid and
    # the tracker's free space (recent_grid.py), the tracker's largest part (120 s corridor: 231 -> 134
    # casts, cast CPU 0.57 -> 0.40 s, front end 5.75 -> 5.50 s, min of 3 alternating; its moving F1
    # and ATE unchanged, as on the 200 s ring), but dense-crowd 20 s's F1 over seeds 0/1/2 went
    # 0.9813 / 0.9809 / 0.9748 -> 0.9724 / 0.9730 / 0.9794 with 3-5x the static points judged moving
    # (60 s: 0.9876 -> 0.9870), and the last published front-end map and the back end's redraw of the
    # same floor then differed by 14 % in observed cells (tests/test_outputs.py holds them within 5 %).
    grid_distance: float = param(0.5, "m", ge=0.0, le=100.0)
    grid_angle_deg: float = param(10.0, "deg", ge=0.0, le=180.0)
    source_voxel: float = param(0.1, "m", ge=0.0, le=10.0)
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
    min_lever: float = param(0.05, "m", gt=0.0, le=10.0)
    wheel_noise: WheelNoise = field(default_factory=WheelNoise)
    sensor_checks: CheckParams = field(default_factory=CheckParams)
    self_calibration: SelfCalibrationParams = field(default_factory=SelfCalibrationParams)
    segment: bool = True
    deskew: bool = True
    doppler_twist: bool = True
    doppler_prior: bool = True
    # the map scans are matched against, and the recovery from a poor prior (not in the paper)
    local_map: LocalMapParams = field(default_factory=LocalMapParams)
    recovery: RecoveryParams = field(default_factory=RecoveryParams)
    # the pose-graph back end both methods share (fmcwlog.backend)
    backend: BackendParams = field(default_factory=BackendParams)


def load_frontend_params(*sources: dict[str, Any] | None) -> FrontEndParams:
    """Front-end parameters from parsed config files and ``--set`` tables, applied in order.

    Each source has the structure of :class:`FrontEndParams` (``dataclasses.asdict``):
    top-level keys are the front end's own, ``segmentation``/``icp`` are tables. A
    ``[frontend]`` table is accepted as the front end's own keys, and a ``run.json``
    (a table with ``params`` and ``fmcwlog_version``) gives its ``params``.
    """
    params = FrontEndParams()
    for source in sources:
        source = dict(source or {})
        if "params" in source and "fmcwlog_version" in source:  # a run.json
            if not isinstance(source["params"], dict):
                raise ConfigError("a run.json's 'params' must be a table of parameters")
            source = dict(source["params"])
        own = source.pop("frontend", {})
        if not isinstance(own, dict):
            raise ConfigError("[frontend] must be a table of parameters")
        params = apply_to_dataclass(params, own, "frontend")
        params = apply_to_dataclass(params, source)
    return params


def frontend_params_toml(params: FrontEndParams) -> str:
    """Every parameter as TOML (``[frontend]``, then a table per stage: ``[segmentation]``, ``[icp]``, ...), each
    with its unit and range as a comment; :func:`load_frontend_params` takes it back unchanged."""
    head = ["# fmcwlog process parameters: every one, with its unit and valid range.",
            "# Use: fmcwlog process LOG --config FILE (or change one with --set TABLE.NAME=VALUE,",
            "# e.g. --set icp.huber_delta=0.04 or --set frontend.voxel_size=0.1).", ""]
    lines = head + toml_table("frontend", params, nested=False)
    for f in dataclasses.fields(params):  # each stage's table: [segmentation], [icp] (and [icp.gmmsc]), ...
        stage = getattr(params, f.name)
        if dataclasses.is_dataclass(stage):
            lines += toml_table(f.name, stage)
    return "\n".join(lines).rstrip() + "\n"
