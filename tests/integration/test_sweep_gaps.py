"""Gaps in the sweeps (a USB hiccup, a driver restart): seconds of a log without sweeps, or with sweeps
whose every return is a no-return, while the wheel ticks go on. Built from the 30 s corridor sample by
removing (or emptying) the sweeps of a window across its corner (the robot turns at 23-24 s), so that
holding the last twist across the gap goes straight on where the robot turned.

Measured (improved method, ATE RMSE, this sample, point-to-point residuals): clean 0.9 cm (1.2 with
the default point-to-line); sweeps of 22-24, 21-25, 20-26 s
removed: 1.0, 1.0, 1.2 cm bridged (41, 204, 199 cm with the last twist held; 1.0, 2.2, 2.1 cm with
the wheels' drift left in the bridge; 1.0, 3.3, 39 cm bridged but matching every point of the
sweep after the gap; wheel odometry 16 cm); 60 empty sweeps (20-26 s): 1.2 cm. The target is twice
the clean log's ATE.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import copy_log, run_cli_here

pytestmark = pytest.mark.slow  # end to end: process and report on edited logs, seconds each

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_logs" / "corridor_30s.mcap"
SCAN = "/fmcw/points"


def _gapped(dst: Path, start: float, end: float, empty: bool = False) -> Path:
    """The sample with the sweeps stamped in [start, end) s after its first removed, or, with
    ``empty``, every point of theirs made a no-return (x infinite)."""
    first: list[float] = []

    def edit(topic, i, msg):
        if topic != SCAN:
            return None
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if not first:
            first.append(stamp)
        if not start <= stamp - first[0] < end:
            return None
        if not empty:
            return False
        off = {f.name: f.offset for f in msg.fields}["x"]
        rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(-1, msg.point_step).copy()
        rows[:, off:off + 4] = np.full((len(rows), 1), np.inf, "<f4").view(np.uint8)
        msg.data = rows.tobytes()
        return None

    copy_log(SAMPLE, dst, edit=edit)
    return dst


def _run(log: Path, out: Path, *more: str) -> tuple[float, dict]:
    """The improved method's ATE RMSE (m) on ``log`` and its run.json."""
    code, _, err = run_cli_here("process", str(log), "-o", str(out), "--force", "--method", "improved", *more)
    assert code == 0, err
    code, _, err = run_cli_here("report", str(out))
    assert code == 0, err
    report = json.loads((out / "report.json").read_text())
    return report["methods"]["improved"]["ate_rmse_m"], json.loads((out / "run.json").read_text())


@pytest.fixture(scope="module")
def clean_ate(tmp_path_factory) -> float:
    ate, run = _run(SAMPLE, tmp_path_factory.mktemp("clean") / "out")
    assert run["gaps"] == []
    assert not any("gap" in w for w in run["warnings"])
    return ate


@pytest.mark.parametrize("seconds", [2, 4, 6])
def test_a_gap_is_bridged_and_reported(tmp_path, clean_ate, seconds):
    start = 23.0 - seconds / 2
    log = _gapped(tmp_path / "gap.mcap", start, start + seconds)
    ate, run = _run(log, tmp_path / "out")
    assert ate < 2 * clean_ate, f"{seconds} s gap: ATE {100 * ate:.1f} cm (clean {100 * clean_ate:.1f} cm)"
    assert len(run["gaps"]) == 1
    gap = run["gaps"][0]
    assert gap["length_s"] == pytest.approx(seconds, abs=0.05)
    assert gap["start_s"] % 1000 == pytest.approx(start, abs=0.05)  # the sample's stamps start at a whole 1000 s
    said = [w for w in run["warnings"] if "gap" in w]
    assert len(said) == 1 and f"{seconds:.1f} s" in said[0], run["warnings"]
    header = (tmp_path / "out" / "report.md").read_text()
    assert "gaps in the sweeps: 1," in header


def test_without_the_bridge_the_last_twist_goes_astray(tmp_path):
    """The ablation: the gap held across on the last twist is metres off (measured 199 cm), and still reported."""
    log = _gapped(tmp_path / "gap.mcap", 20.0, 26.0)
    ate, run = _run(log, tmp_path / "out", "--set", "frontend.gaps.bridge=false")
    assert ate > 0.5
    assert len(run["gaps"]) == 1


# The two ablations below match point to point: with point-to-line residuals (the default) the scans
# after the gap take out what either fault leaves on this sample (drift left in: 1.0 cm, every point
# matched: 1.1 cm, clean 1.2), and the stages show where the scans cannot.
POINT_TO_POINT = ("--set", "frontend.icp.residual=point_to_point")


@pytest.fixture(scope="module")
def clean_ate_point_to_point(tmp_path_factory) -> float:
    return _run(SAMPLE, tmp_path_factory.mktemp("clean_p2p") / "out", *POINT_TO_POINT)[0]


def test_the_wheels_drift_left_in_the_bridge_turns_the_rest(tmp_path, clean_ate_point_to_point):
    """The ablation of ``drift``: the wheels' radii turn their heading 4.4 mrad per metre; left in the
    bridge of the 6 s across the corner, 19 mrad of heading stays in every pose after it (measured
    2.1 cm against 1.2, clean 0.9, point to point)."""
    log = _gapped(tmp_path / "gap.mcap", 20.0, 26.0)
    ate, _ = _run(log, tmp_path / "out", "--set", "frontend.gaps.drift.enabled=false", *POINT_TO_POINT)
    clean = clean_ate_point_to_point
    assert ate > 2 * clean, f"ATE {100 * ate:.1f} cm (clean {100 * clean:.1f} cm)"


def test_matching_every_point_after_a_gap_slides_back(tmp_path):
    """The ablation of ``seen_only``: the sweep after a 4 s gap at the corner, matched with the points
    of the new corridor the map has not seen, slides back along it (measured 3.3 cm against 0.9,
    point to point)."""
    log = _gapped(tmp_path / "gap.mcap", 21.0, 25.0)
    ate, _ = _run(log, tmp_path / "out", "--set", "frontend.gaps.seen_only=false", *POINT_TO_POINT)
    assert ate > 0.025, f"ATE {100 * ate:.1f} cm"


def test_sixty_empty_sweeps_are_a_gap(tmp_path):
    log = _gapped(tmp_path / "empty.mcap", 20.0, 26.0, empty=True)
    ate, run = _run(log, tmp_path / "out")
    assert ate < 0.025, f"ATE {100 * ate:.1f} cm"
    assert run["skipped_sweeps"] == 60
    assert len(run["gaps"]) == 1 and run["gaps"][0]["length_s"] == pytest.approx(6.0, abs=0.05)
    assert any("gap" in w for w in run["warnings"]) and any("skipped 60 sweeps" in w for w in run["warnings"])
