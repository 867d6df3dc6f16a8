"""A LiDAR-only robot: logs with neither wheel ticks nor odometry, and clouds without a ``velocity`` field.

The logs are the simulator's, rewritten without ``/wheel/ticks`` and the clouds' Doppler (their
points and times unchanged), so that the ground truth still scores them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import ate_rmse, copy_log, ground_truth, record_scenario, run_cli, tum

from fmcwlog.api import ProcessOptions, process
from fmcwlog.backend import pipeline as backend_pipeline

PRIOR = "scan-to-map correlative search (no odometry, no wheel ticks, no Doppler in /fmcw/points)"


def lidar_only(log: Path, out: Path) -> Path:
    """``log`` without its wheel ticks, odometry and Doppler."""

    def no_doppler(topic, i, msg):
        if topic == "/fmcw/points":
            msg.fields = [f for f in msg.fields if f.name != "velocity"]

    copy_log(log, out, drop_topics=("/wheel/ticks", "/odom"), edit=no_doppler)
    return out


@pytest.fixture(scope="module")
def processed(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """The crowd (90 s) and the corridor (110 s), each a lap and some more, LiDAR-only, processed with
    both methods and their back ends."""
    out = {}
    for scenario, duration in (("crowd", 90.0), ("corridor", 110.0)):
        log = lidar_only(record_scenario(tmp_path_factory, scenario, duration),
                         tmp_path_factory.mktemp(scenario) / "lidar_only.mcap")
        process(log, log.parent / "out", ProcessOptions())
        out[scenario] = (log, log.parent / "out")
    return out


# ATE RMSE (m) measured on these logs, seed 0: improved, improved front end alone, baseline, its front end
MEASURED = {"crowd": (0.018, 0.062, 0.182, 0.389), "corridor": (0.027, 0.079, 0.335, 1.269)}


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["crowd", "corridor"])
def test_without_odometry_or_doppler_the_prior_holds_and_the_back_end_never_makes_it_worse(processed, scenario):
    log, out = processed[scenario]
    gt = ground_truth(log)
    run = json.loads((out / "run.json").read_text())
    assert run["prior"] == PRIOR and run["doppler"] is False
    ate = {name: ate_rmse(tum(out / f"{name}.tum"), gt)
           for name in ("improved", "improved_frontend", "baseline", "baseline_frontend")}
    for name, measured in zip(ate, MEASURED[scenario]):
        assert ate[name] < 2 * measured, (name, ate)
    for method in ("improved", "baseline"):  # the same trajectory where the back end was not used
        assert ate[method] <= ate[f"{method}_frontend"] + 1e-6, ate


@pytest.mark.slow
def test_a_back_end_bent_by_wrong_closures_is_not_used_and_says_so(processed, tmp_path, monkeypatch):
    """Every closure moved 0.5 m off what was verified: the optimised trajectory draws the revisited
    places apart, so the outputs keep the front end's trajectory and map, with a warning giving the
    numbers; the same closures let through would have made the trajectory worse than the front end's."""
    log, _ = processed["crowd"]
    gt = ground_truth(log)
    verify = backend_pipeline.verify

    def bent(*args, **kwargs):
        verdict = verify(*args, **kwargs)
        if verdict.accepted and verdict.relative is not None:
            verdict.relative = verdict.relative + np.array([0.5, 0.0, 0.0])
        return verdict

    monkeypatch.setattr(backend_pipeline, "verify", bent)
    opts = ProcessOptions(methods=("improved",))
    summary = process(log, tmp_path / "kept", opts, jobs=1)
    kept = tmp_path / "kept"
    said = [w for w in summary.warnings if "the outputs keep the front end's trajectory and map" in w]
    assert len(said) == 1 and said[0].startswith("improved: with its "), summary.warnings
    assert (kept / "improved.tum").read_bytes() == (kept / "improved_frontend.tum").read_bytes()
    graph = json.loads((kept / "improved_backend.json").read_text())["summary"]
    distances = graph["kept_front_end"]["revisit_distance_m"]
    assert distances["optimised"] > distances["front_end"]

    monkeypatch.setattr(backend_pipeline, "worse", lambda r: False)  # the same closures, let through
    process(log, tmp_path / "used", opts, jobs=1)
    used = tmp_path / "used"
    assert ate_rmse(tum(used / "improved.tum"), gt) > ate_rmse(tum(kept / "improved.tum"), gt)


@pytest.mark.slow
def test_the_terminal_says_which_prior_ran_and_why(tmp_path_factory, tmp_path):
    log = lidar_only(record_scenario(tmp_path_factory, "crowd", 4.0), tmp_path / "lidar_only.mcap")
    res = run_cli("process", str(log), "-o", str(tmp_path / "out"), "--backend", "none")
    assert res.returncode == 0, res.stderr
    assert f"prior: {PRIOR}; Doppler: off" in res.stdout + res.stderr

