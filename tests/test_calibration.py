"""A wrong mount calibration is caught, ``fmcwlog calibrate`` recovers the truth, and processing with it
brings the accuracy back.

The log is recorded with the true mount, then its ``fmcwlog.calibration`` record is rewritten with
``lidar_x`` 0.3 m off (tests/helpers.py ``copy_log``). The truth the tests check against is the
simulator's own record (``fmcwlog.sim``: its config and the true wheel radii), read with plain
``mcap``; the code under test never sees it. The calibration file is read back with plain ``yaml``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml
from helpers import ate_rmse, copy_log, ground_truth, record_small_ring, run_cli, tum
from mcap.reader import make_reader

from fmcwlog.api import ProcessOptions, process

OFF = 0.3  # m added to lidar_x in the rewritten record


def _metadata(log: Path) -> dict[str, dict[str, str]]:
    with open(log, "rb") as fh:
        return {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}


def _truth(log: Path) -> dict[str, float]:
    sim = _metadata(log)["fmcwlog.sim"]
    cfg = json.loads(sim["config"])
    return {"lidar_x": cfg["sensor"]["mount_x"], "lidar_y": cfg["sensor"]["mount_y"],
            "lidar_yaw": math.radians(cfg["sensor"]["mount_yaw_deg"]),
            "wheel_radius_left": float(sim["true_wheel_radius_left"]),
            "wheel_radius_right": float(sim["true_wheel_radius_right"]), "track_width": cfg["robot"]["track_width"]}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("calibration")
    right = record_small_ring(root / "right.mcap")
    record = _metadata(right)["fmcwlog.calibration"]
    wrong = root / "wrong.mcap"
    copy_log(right, wrong, drop_metadata=("fmcwlog.calibration",),
             extra_metadata={"fmcwlog.calibration": {**record, "lidar_x": repr(float(record["lidar_x"]) + OFF)}})
    return {"right": right, "wrong": wrong, "root": root}


@pytest.fixture(scope="module")
def outs(logs) -> dict[str, Path]:
    out = {}
    for name in ("right", "wrong"):
        out[name] = logs["root"] / f"out_{name}"
        process(logs[name], out[name], ProcessOptions())
    return out


@pytest.fixture(scope="module")
def calib(logs) -> Path:
    path = logs["root"] / "calib.yaml"
    res = run_cli("calibrate", str(logs["wrong"]), "-o", str(path))
    assert res.returncode == 0, res.stderr
    return path


def test_a_wrong_mount_is_flagged_with_numbers(outs):
    run = json.loads((outs["wrong"] / "run.json").read_text())
    check = run["calibration_check"]
    assert "lidar_x" in check["disagrees"]
    assert check["values"]["lidar_x"]["difference"] == pytest.approx(-OFF, abs=0.02)
    said = [w for w in run["warnings"] if "calibration disagrees" in w]
    assert len(said) == 1 and "lidar_x" in said[0] and "650.0 mm" in said[0]


def test_a_right_mount_is_not_flagged(outs):
    check = json.loads((outs["right"] / "run.json").read_text())["calibration_check"]
    assert check["checked"] and not {"lidar_x", "lidar_y", "lidar_yaw", "track_width"} & set(check["disagrees"])


def test_calibrate_recovers_the_mount_and_the_radii(logs, calib):
    truth = _truth(logs["right"])
    record = _metadata(logs["right"])["fmcwlog.calibration"]
    got = yaml.safe_load(calib.read_text())
    assert set(got) == set(record)  # the record's keys, no more, no fewer
    assert abs(got["lidar_x"] - truth["lidar_x"]) < 0.01
    assert abs(got["lidar_y"] - truth["lidar_y"]) < 0.01
    assert abs(got["lidar_yaw"] - truth["lidar_yaw"]) < math.radians(0.5)
    # The radii: the log's calibration has them 0.5 % and 0.3 % short and their ratio 0.2 % off
    # (measured here: each within 0.2 % of the truth, the ratio within 0.03 %).
    for side in ("left", "right"):
        key = f"wheel_radius_{side}"
        assert got[key] == pytest.approx(truth[key], rel=0.004)
    ratio = got["wheel_radius_left"] / got["wheel_radius_right"]
    assert ratio == pytest.approx(truth["wheel_radius_left"] / truth["wheel_radius_right"], rel=5e-4)
    assert got["track_width"] == pytest.approx(truth["track_width"], rel=0.01)


def test_processing_with_the_recovered_calibration_restores_the_accuracy(logs, outs, calib):
    out = logs["root"] / "out_recalibrated"
    res = run_cli("process", str(logs["wrong"]), "-o", str(out), "--calibration", str(calib))
    assert res.returncode == 0, res.stderr
    gt = ground_truth(logs["right"])
    ate = {name: ate_rmse(tum(o / "improved.tum"), gt) for name, o in (*outs.items(), ("recalibrated", out))}
    assert ate["wrong"] > 2 * ate["right"]  # measured: see the commit message
    assert ate["recalibrated"] < 1.5 * ate["right"] + 0.002, ate
    wheels = {name: ate_rmse(tum(o / "wheel_odometry.tum"), gt) for name, o in (("right", outs["right"]),
                                                                                ("recalibrated", out))}
    assert wheels["recalibrated"] < 0.7 * wheels["right"], wheels  # the radii, not only the mount
    run = json.loads((out / "run.json").read_text())
    assert run["calibration_source"] == str(calib)
    assert not {"lidar_x", "lidar_y", "lidar_yaw"} & set(run["calibration_check"]["disagrees"])


def test_a_bad_calibration_file_is_one_line_naming_it(logs, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("lidar_x: [1, 2]\n")
    for path in (bad, tmp_path / "missing.yaml"):
        res = run_cli("process", str(logs["right"]), "-o", str(tmp_path / "out"), "--calibration", str(path))
        assert res.returncode == 2 and "Traceback" not in res.stderr
        assert res.stderr.count("\n") == 1 and str(path) in res.stderr
        assert not (tmp_path / "out").exists()


def test_calibrate_does_not_overwrite_without_force(logs, tmp_path):
    target = tmp_path / "calib.yaml"
    target.write_text("mine\n")
    res = run_cli("calibrate", str(logs["right"]), "-o", str(target))
    assert res.returncode == 2 and "--force" in res.stderr and target.read_text() == "mine\n"


def test_the_report_says_where_the_motion_came_from_and_what_the_check_found(outs, logs):
    """report.json carries run.json's motion sources and calibration check; the page and the
    Markdown show the wrong lidar_x as disagreeing and the right ones as agreeing."""
    from fmcwlog.evaluation.evaluate import evaluate
    from fmcwlog.evaluation.pages import render_markdown

    ev = evaluate(outs["wrong"], logs["wrong"])
    run = json.loads((outs["wrong"] / "run.json").read_text())
    assert ev.result["calibration_check"] == run["calibration_check"]
    assert ev.result["motion_sources"] == run["motion_sources"]
    md = render_markdown(ev)
    rows = {ln.split("|")[1].strip(): ln for ln in md.splitlines() if ln.startswith("| lidar_")}
    assert "disagrees" in rows["lidar_x"] and "disagrees" not in rows["lidar_yaw"]
    assert "| improved | v and omega" in md


def test_calibration_samples_kept_in_numpy_are_the_tuples_values():
    """The per-sweep samples are float64 rows, not tuples of Python floats: the same numbers as
    ``np.array`` of the tuples the estimate used to convert (numpy scalars, ints, many rows)."""
    import numpy as np

    from fmcwlog.frontend.self_calibration import CalibrationSamples

    rng = np.random.default_rng(8)
    samples, doppler, yaw = CalibrationSamples(), [], []
    for k in range(2500):
        z, cov = rng.normal(size=2), np.diag(rng.exponential(size=2))
        turns = (np.float64(rng.normal()), float(rng.normal()))
        stamp = 1.7e9 + 0.1 * k
        samples.add_doppler(stamp, z, cov, turns, 0.1)
        doppler.append((float(z[0]), float(z[1]), float(cov[0, 0]), float(cov[1, 1]), *turns, 0.1, stamp))
        samples.add_yaw(stamp, float(rng.normal()), turns, k % 3)
        yaw.append((samples.yaw.values[-1, 0], *turns, k % 3, stamp))
    assert samples.doppler.values.tobytes() == np.array(doppler, dtype=float).reshape(-1, 8).tobytes()
    assert samples.yaw.values.tobytes() == np.array(yaw, dtype=float).reshape(-1, 5).tobytes()
    assert not CalibrationSamples().doppler and samples.doppler
