"""The parameters of a front end, and how config files and ``--set`` reach them.

A config file (TOML, YAML or JSON) holds the same structure as
:class:`FrontEndParams`: the front end's own parameters at the top level (or in
a ``[frontend]`` table), each stage's in its own table (``[segmentation]``,
``[tracking]``, ``[icp]``, ``[icp.gmmsc]``). ``fmcwlog process --show-config`` prints exactly
that, and ``run.json`` records it under ``params``, so either can be fed back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..config import apply_to_dataclass
from ..errors import ConfigError
from .icp import ICPParams
from .segmentation import SegmentationParams
from .tracking import TrackingParams


@dataclass(frozen=True)
class FrontEndParams:
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
    min_range: float = 0.3
    keyframe_distance: float = 0.2
    keyframe_angle_deg: float = 5.0
    grid_distance: float = 0.5
    grid_angle_deg: float = 10.0
    source_voxel: float = 0.1
    voxel_size: float = 0.05
    map_resolution: float = 0.05
    prior_sigma_along: float = 0.002
    prior_sigma_across: float = 0.005
    prior_sigma_yaw: float = 0.005
    residual_sigma: float = 0.03
    doppler_prior_gate: float = 0.3
    seed: int = 0
    segment: bool = True
    deskew: bool = True
    doppler_twist: bool = True
    doppler_prior: bool = True


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
            source = dict(source["params"])
        own = source.pop("frontend", {})
        if not isinstance(own, dict):
            raise ConfigError("[frontend] must be a table of parameters")
        params = apply_to_dataclass(params, own, "frontend")
        params = apply_to_dataclass(params, source)
    return params
