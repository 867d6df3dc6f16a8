"""Each stage of the improved method, switched off alone, makes some log measurably worse.

ATE here is the tests' own (2-D Kabsch after interpolating the ground truth read with plain
``mcap``), not fmcwlog's metrics. The factors asserted are about half of those measured
(the README lists the measured ones), so a stage that stops working fails its test.

GMMSC is the exception at the level of a whole log: on every log we built (the sample logs,
three seeds of a dense crowd, crowd logs without Doppler, the long corridor) switching it off
alone moves the ATE by less than the spread between seeds, because Doppler segmentation has
already removed the movers it would reject and the Huber kernel bounds what is left. Its effect
shows where unsegmented clutter sits next to the walls: ``test_gmmsc_rejects_clutter_the_kernel_cannot``.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, ate_rmse, ground_truth, tum

from fmcwlog.api import ProcessOptions, process
from fmcwlog.pipeline.params import load_params

pytestmark = pytest.mark.slow  # end to end: each component ablated on a recorded log, seconds each


@cache
def _improved_ate(log: Path, out: Path, switches: tuple[tuple[str, object], ...]) -> float:
    tables: dict = {}
    for key, value in switches:
        head, _, name = key.partition(".")
        if name:
            tables.setdefault(head, {})[name] = value
        else:
            tables[head] = value
    process(log, out, ProcessOptions(methods=("improved",), params=load_params(tables)), force=True)
    return ate_rmse(tum(out / "improved.tum"), ground_truth(log))


@pytest.fixture(scope="module")
def ate(tmp_path_factory):
    """``ate(log, **switches)``: the improved method's ATE (m) on ``log`` with those stage switches."""
    root = tmp_path_factory.mktemp("ablation")

    def run(log: Path, **switches) -> float:
        key = tuple(sorted((k.replace("__", "."), v) for k, v in switches.items()))
        out = root / (log.stem + "".join(f"_{k}={v}" for k, v in key))
        return _improved_ate(log, out, key)

    return run


CROWD = SAMPLE_LOGS / "crowd_30s.mcap"
CORRIDOR = SAMPLE_LOGS / "corridor_30s.mcap"


def test_segmentation_keeps_walkers_out_of_the_map(ate):
    full, off = ate(CROWD), ate(CROWD, segment=False)
    assert off > 3 * full, (full, off)  # measured 0.5 -> 4.1 cm


def test_deskew_takes_out_the_sweeps_motion(ate):
    full, off = ate(CROWD), ate(CROWD, deskew=False)
    assert off > 2.5 * full, (full, off)  # measured 0.5 -> 2.7 cm


def test_huber_kernel_bounds_the_residuals(ate):
    # With point-to-point residuals: on this log, with the default point-to-line residuals, the kernel
    # shows no effect (1.18 cm with it, 0.92 without): a residual along a wall's normal is not pulled
    # by where along the wall the map's sample sits, which is most of what the kernel bounded here.
    p2p = "point_to_point"
    full, off = ate(CORRIDOR, icp__residual=p2p), ate(CORRIDOR, icp__residual=p2p, icp__use_huber=False)
    assert off > 2 * full, (full, off)  # measured 0.89 -> 8.3 cm


@pytest.fixture(scope="module")
def worn_wheels_corridor_log(tmp_path_factory) -> Path:
    """60 s of the bare corridor with both wheels 2 % larger than calibrated."""
    from fmcwlog.sim import scenarios
    from fmcwlog.sim.config import SimConfig, apply_overrides
    from fmcwlog.sim.recorder import record

    cfg = apply_overrides(SimConfig(), {"run": {"duration": 60.0, "seed": 0},
                                        "robot": {"wheel_radius_error_left": 0.02, "wheel_radius_error_right": 0.02}})
    out = tmp_path_factory.mktemp("worn") / "long-corridor.mcap"
    record(scenarios.long_corridor(), cfg, out)
    return out


def test_doppler_twist_beats_the_wheels_in_a_bare_corridor(ate, worn_wheels_corridor_log):
    # With the default wheels (0.3-0.5 % off) the local map of recent keyframes now holds the
    # along-axis position from the wheels' twist too (1.15 cm with Doppler, 1.08 cm without, on the
    # 60 s long corridor; the first-point-per-voxel map it replaced gave 1.85 and 15.9 cm), so the
    # stage shows where the wheels are further off: both 2 % large.
    log = worn_wheels_corridor_log
    full, off = ate(log), ate(log, doppler_twist=False)
    assert off > 4 * full, (full, off)  # measured 0.59 -> 26.5 cm


def test_doppler_prior_holds_the_position_along_a_bare_corridor(ate, long_corridor_log):
    full, off = ate(long_corridor_log), ate(long_corridor_log, doppler_prior=False)
    assert off > 1.0 > 20 * full, (full, off)  # measured 1.6 cm -> 17 m: it slides


@pytest.fixture(scope="module")
def brisk_static_log(tmp_path_factory) -> Path:
    """30 s of the static scene at 1.13 m/s: the map's keyframes 20 cm apart are a few sweeps old."""
    from helpers import record_scenario

    return record_scenario(tmp_path_factory, "static", 30.0, 0, robot={"speed": 1.13})


def test_point_to_line_takes_out_the_pull_of_the_maps_samples(ate, brisk_static_log):
    # point-to-point pulls each scan point toward its voxel's one sample, anywhere along the wall
    # (tests/unit/frontend/test_point_to_line.py shows the pull on known geometry)
    full, off = ate(brisk_static_log), ate(brisk_static_log, icp__residual="point_to_point")
    assert off > 1.4 * full and full < 0.024, (full, off)  # measured 1.18 -> 2.38 cm


def test_gmmsc_rejects_clutter_the_kernel_cannot():
    """Component level: a ray-cast room with 20 % clutter beside its walls (tests/test_robust_icp.py)."""
    from test_robust_icp import TARGET, TREE, _err, _outliers, _raycast, _truth

    from fmcwlog.frontend.icp import ICPParams
    from fmcwlog.frontend.robust_icp import register

    for seed in range(3):
        rng = np.random.default_rng(seed)
        truth = _truth(rng)
        scan = _raycast(truth, rng)
        src = np.concatenate([scan, _outliers(rng, truth, len(scan) // 4)])
        init = truth + np.array([0.12, -0.08, 0.04])
        with_gmmsc = _err(register(src, TREE, TARGET, init, ICPParams()).pose, truth)[0]
        without = _err(register(src, TREE, TARGET, init, ICPParams(use_gmmsc=False)).pose, truth)[0]
        assert without > 10 * with_gmmsc and without > 0.005, (with_gmmsc, without)  # measured 0.2 -> 15 mm


def test_registration_without_source_thinning_still_runs(ate):
    """``frontend.source_voxel = 0`` registers every point of the sweep (no thinning): it still runs
    and registers. With point-to-point residuals the thinned sweep is the better of the two on the
    corridor (uniform density weighs every wall alike instead of the near ones: 0.89 cm against
    1.64); with point-to-line residuals (the default) the unthinned one is (0.49 cm against 1.18)."""
    full, off = ate(CORRIDOR), ate(CORRIDOR, source_voxel=0.0)
    assert off < 0.01 and full < 0.024, (full, off)  # measured 1.18 (10 cm voxels) and 0.49 cm
