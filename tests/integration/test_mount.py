"""Any mount: the lidar over the axle, sideways, yawed, behind and looking back — ``process`` never
fails, the twist it reports matches the ground truth within its own uncertainty, and Doppler is
credited with what the physics says it observes (docs/physics.md: ``v_s = v_b + ω × l``, ``v_by = 0``).

Each log is 14 s of a small ring corridor (tests/helpers.py ``small_ring``: a straight, a corner,
a bit of the next straight), recorded with ``sensor.mount_*`` set; ground truth is read with plain
``mcap`` (tests/helpers.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from helpers import ate_rmse, decoded, ground_truth, record_small_ring, tum

from fmcwlog.api import ProcessOptions, process

pytestmark = pytest.mark.slow  # end to end: logs recorded and processed at six mounts

# name -> (mount_x m, mount_y m, mount_yaw deg)
MOUNTS = {
    "ahead": (0.35, 0.0, 0.0),
    "over_axle": (0.0, 0.0, 0.0),
    "sideways": (0.0, 0.25, 0.0),
    "yawed_left": (0.35, 0.0, 90.0),
    "yawed_right": (0.2, -0.1, -90.0),
    "behind_looking_back": (-0.3, 0.0, 180.0),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """Each mount recorded (14 s, seed 0) and processed with both methods: name -> (log, out)."""
    root = tmp_path_factory.mktemp("mounts")
    out = {}
    for name, (x, y, yaw) in MOUNTS.items():
        log = record_small_ring(root / f"{name}.mcap", mount_x=x, mount_y=y, mount_yaw_deg=yaw)
        process(log, root / name, ProcessOptions())
        out[name] = (log, root / name)
    return out


def _twists(out: Path):
    """Stamps (s), (v, ω) and their standard deviations from /improved/odom in processed.mcap."""
    rows = []
    for _, _, message, m in decoded(out / "processed.mcap", ["/improved/odom"]):
        c = m.twist.covariance
        rows.append([message.log_time * 1e-9, m.twist.twist.linear.x, m.twist.twist.angular.z,
                     math.sqrt(c[0]), math.sqrt(c[35])])
    return np.array(rows)


def _true_twist(log: Path, t: np.ndarray) -> np.ndarray:
    """Ground-truth (v, ω) averaged over each sweep's 75 ms, read with plain mcap."""
    g = np.array([[msg_time * 1e-9, m.twist.twist.linear.x, m.twist.twist.angular.z]
                  for _, _, msg_time, m in ((s, c, mm.log_time, m) for s, c, mm, m in
                                            decoded(log, ["/ground_truth/odom"]))])
    span = np.linspace(0.0, 0.075, 8)
    return np.stack([np.mean([np.interp(t + s, g[:, 0], g[:, i]) for s in span], axis=0) for i in (1, 2)], -1)


@pytest.mark.parametrize("name", list(MOUNTS))
def test_every_mount_is_processed_by_every_method(runs, name):
    log, out = runs[name]
    run = json.loads((out / "run.json").read_text())
    for method in ("improved", "baseline", "wheel_odometry"):
        assert len(tum(out / f"{method}.tum")) == run["sweeps"] == 140
    assert run["mount"] == pytest.approx([MOUNTS[name][0], MOUNTS[name][1], math.radians(MOUNTS[name][2])])


@pytest.mark.parametrize("name", list(MOUNTS))
def test_reported_twist_matches_the_truth_within_its_uncertainty(runs, name):
    log, out = runs[name]
    tw = _twists(out)
    truth = _true_twist(log, tw[:, 0])
    moving = truth[:, 0] > 0.2
    z = (tw[moving, 1:3] - truth[moving]) / tw[moving, 3:5]
    inside = np.mean(np.abs(z) < 3.0, axis=0)
    assert np.all(inside > 0.95), (name, inside)  # measured 1.000 (v) and 0.985-1.000 (ω)


@pytest.mark.parametrize("name", list(MOUNTS))
def test_doppler_is_credited_with_what_it_observes(runs, name):
    """Doppler observes ω through the lever arm ``l_x`` only (det A = l_x); v wherever it looks.

    Sideways (l = (0, l_y)) it observes ``v - ω l_y``: that and the wheels' ``v`` say something
    of ω, so Doppler's share of ω is not zero there, but it is the wheels' that dominates.
    """
    _, out = runs[name]
    src = json.loads((out / "run.json").read_text())["motion_sources"]["improved"]
    assert src["doppler_share_v"] > 0.5
    x, y, _ = MOUNTS[name]
    if x == 0.0 and y == 0.0:
        assert src["doppler_share_omega"] < 0.01
        assert src["doppler_observes"].startswith("v only")
    elif x == 0.0:
        assert src["doppler_share_omega"] < 0.5
        assert src["doppler_observes"].startswith("only v - omega*lidar_y")
    else:
        assert src["doppler_share_omega"] > 0.5
    assert src["doppler_prior_sweeps"] > 100


@pytest.mark.parametrize("name", list(MOUNTS))
def test_improved_method_stays_accurate_at_every_mount(runs, name):
    log, out = runs[name]
    gt = ground_truth(log)
    ate = ate_rmse(tum(out / "improved.tum"), gt)
    assert ate < 0.013, (name, ate)  # measured 3.4-6.7 mm over these six mounts


@pytest.mark.parametrize("name", list(MOUNTS))
def test_calibration_check_agrees_with_a_right_calibration(runs, name):
    """The log's calibration is right: where the log fixes the mount, the check finds it within 1 cm / 0.5 deg."""
    log, out = runs[name]
    check = json.loads((out / "run.json").read_text())["calibration_check"]
    assert check["checked"]
    values = check["values"]
    for key, truth, tol in zip(("lidar_x", "lidar_y", "lidar_yaw"), MOUNTS[name][:2] + (math.radians(MOUNTS[name][2]),),
                               (0.01, 0.01, math.radians(0.5))):
        if key in values:
            assert abs(values[key]["estimate"] - truth) < tol, (key, values[key])
            assert not values[key]["disagrees"], (key, values[key])
