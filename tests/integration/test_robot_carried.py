"""A robot carried away (kidnapped, or pushed on a trolley): its sweeps and ground truth jump, its wheel
ticks do not. Recorded by the simulator with the chassis moved by a rigid 8 m (7.6 m along the crowd
hall, 2.5 m across) from 9 s on, while the encoders count the route's own motion.

Measured (this log, both methods): the jump is found 0.4 s after it, 8.00 m (improved) and 8.37 m
(baseline) from where the wheels put the robot. Without the watch (``frontend.relocalise.enabled=false``)
nothing is said and the trajectories end metres off.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, ate_rmse, ground_truth, run_cli_here, tum

pytestmark = pytest.mark.slow  # end to end: record, process and report, seconds each

T_JUMP, SHIFT = 9.0, (7.6, 2.5)  # s after the start; m in the hall's frame


def record_carried(out: Path, duration: float = 16.0, t_jump: float = T_JUMP, shift=SHIFT) -> Path:
    """The crowd scenario with the robot carried by ``shift`` (m) at ``t_jump`` (s): the LiDAR and the
    ground truth follow the carried chassis, the wheel encoders the route's own motion."""
    from fmcwlog.sim import recorder, scenarios
    from fmcwlog.sim.chassis import BodyState, Chassis
    from fmcwlog.sim.config import SimConfig, apply_overrides

    class Carried(Chassis):
        def state(self, t):
            b = super().state(t)
            after = np.asarray(t, float) >= t_jump
            return BodyState(b.t, np.where(after, b.x + shift[0], b.x), np.where(after, b.y + shift[1], b.y),
                             b.yaw, b.v, b.omega, b.s)

        def encoder_counts(self, state, rng):
            return super().encoder_counts(Chassis.state(self, state.t), rng)

    cfg = apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": 0}})
    original, recorder.Chassis = recorder.Chassis, Carried
    try:
        recorder.record(scenarios.SCENARIOS["crowd"](), cfg, out)
    finally:
        recorder.Chassis = original
    return out


@pytest.fixture(scope="module")
def carried(tmp_path_factory) -> Path:
    return record_carried(tmp_path_factory.mktemp("carried") / "carried.mcap")


def _run(log: Path, out: Path, *more: str) -> tuple[dict, dict]:
    code, _, err = run_cli_here("process", str(log), "-o", str(out), "--force", *more)
    assert code == 0, err
    code, _, err = run_cli_here("report", str(out))
    assert code == 0, err
    return json.loads((out / "run.json").read_text()), json.loads((out / "report.json").read_text())


def _pieces(out: Path, method: str, gt: np.ndarray, start: float, found: float) -> tuple[float, float]:
    """The ATE RMSE (m) of the trajectory before the jump and from the sweep that ended it on, each
    aligned on its own (the sweeps in between, which fit nowhere, kept the prior's pose)."""
    est = tum(out / f"{method}.tum")
    before, after = est[est[:, 0] < start - 1e-6], est[est[:, 0] >= found - 1e-6]
    return ate_rmse(before, gt), ate_rmse(after, gt)


def test_a_carried_robot_is_relocalised_and_said(carried, tmp_path):
    out = tmp_path / "out"
    run, report = _run(carried, out)
    gt = ground_truth(carried)
    t0 = gt[0, 0]
    for method in ("improved", "baseline"):
        jumps = run["jumps"][method]
        assert len(jumps) == 1, run["jumps"]
        j = jumps[0]
        assert j["kind"] == "relocalised"
        assert j["start_s"] - t0 == pytest.approx(T_JUMP, abs=0.15)
        assert j["distance_m"] == pytest.approx(math.hypot(*SHIFT), abs=0.6)
        said = [w for w in run["warnings"] if w.startswith(f"{method}: the robot was carried")]
        assert len(said) == 1 and "relocalised" in said[0], run["warnings"]
        ate_before, ate_after = _pieces(out, method, gt, j["start_s"], j["found_s"])
        limit = 0.015 if method == "improved" else 0.4  # measured 0.5 | 0.3 cm, 17.6 | 10.7 cm
        assert ate_before < limit and ate_after < limit, (method, ate_before, ate_after)
        # one trajectory, not two pieces: the pose after the jump is where the truth is, in the frame before it
        est = tum(out / f"{method}.tum")
        first_after = est[est[:, 0] >= j["found_s"] - 1e-6][0]
        truth = np.array([np.interp(first_after[0], gt[:, 0], gt[:, i]) for i in (1, 2)])
        start = np.array([np.interp(est[0, 0], gt[:, 0], gt[:, i]) for i in (1, 2)])
        assert np.hypot(*(first_after[1:3] - (truth - start))) < 0.3  # the hall's route starts heading +x
        # the sweeps between the carry and its finding, placed by the prior's motion back from the pose
        # found: the whole trajectory as good as its pieces (measured 0.5 cm improved, 18.3 cm baseline;
        # 125 and 130 cm where they kept the prior's poses, 8 m from where they were taken)
        whole = ate_rmse(est, gt)
        assert whole < (0.015 if method == "improved" else 0.4), (method, whole)
    header = (out / "report.md").read_text()
    assert "robot carried away (jumps)" in header and "relocalised" in header


def test_without_the_watch_a_carried_robot_goes_unsaid(carried, tmp_path):
    """The ablation: the jump is smeared into the trajectory, metres off, and nothing is said."""
    out = tmp_path / "out"
    run, report = _run(carried, out, "--set", "frontend.relocalise.enabled=false")
    assert run["jumps"] == {"improved": [], "baseline": []}
    assert not any("carried" in w for w in run["warnings"])
    for method in ("improved", "baseline"):
        assert report["methods"][method]["ate_rmse_m"] > 2.0


def test_a_robot_carried_where_nothing_fits_starts_a_new_piece(carried, tmp_path):
    """Where no place of the local map fits (here: no fit is asked to be good enough), the front end
    goes on from the prior with a fresh map and says that the poses after the jump are at an unknown
    offset; each piece is right on its own."""
    out = tmp_path / "out"
    run, _ = _run(carried, out, "--method", "improved", "--set", "frontend.relocalise.min_inlier_fraction=1.0")
    (j,) = run["jumps"]["improved"]
    assert j["kind"] == "new piece" and "distance_m" not in j
    assert any("unknown offset" in w for w in run["warnings"])
    ate_before, ate_after = _pieces(out, "improved", ground_truth(carried), j["start_s"], j["found_s"])
    assert ate_before < 0.015 and ate_after < 0.015, (ate_before, ate_after)  # measured 0.5 and 0.3 cm


@pytest.mark.parametrize("log", ["corridor_30s.mcap", "crowd_30s.mcap"])
def test_no_jump_on_a_clean_log(log, tmp_path):
    run, _ = _run(SAMPLE_LOGS / log, tmp_path / "out")
    assert run["jumps"] == {"improved": [], "baseline": []}
    assert not any("carried" in w for w in run["warnings"])
