"""The LiDAR's mount from a log as ROS writes it: ``/tf_static`` instead of fmcwlog's calibration record.

The logs are a recorded fmcwlog log written again by mcap_ros2's ``Writer`` (not fmcwlog's) as a
ROS 2 driver stack would log it (tests/helpers.py ``ros_laser_log``): ``/scan`` a LaserScan in frame
``laser``, ``/odom`` the wheels' odometry, ``/tf_static`` base_link -> laser, no fmcwlog metadata.
The facts checked against: a calibration file holding the same mount (the trajectories byte for
byte), the ground truth (read with plain mcap, scored by helpers.ate_rmse), and the values written
into the logs here.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import helpers
import pytest
from helpers import SAMPLE_LOGS, ate_rmse, copy_log, ground_truth, metadata, ros_laser_log, run_cli_here, tf_entry, tum

from fmcwlog.api import ProcessOptions, calibrate, process, report

pytestmark = pytest.mark.slow  # end to end: process on logs

CORRIDOR = SAMPLE_LOGS / "corridor_30s.mcap"
MOUNT = [tf_entry("base_link", "laser", (0.35, 0.0, 0.2))]  # the corridor's true mount, 20 cm above base_link
TRAJECTORIES = ("improved.tum", "baseline.tum", "wheel_odometry.tum")
ROBOT = ("--scan-topic", "/scan", "--odom-topic", "/odom")


def _run(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())


@pytest.fixture(scope="module")
def robot(tmp_path_factory) -> dict[str, Path]:
    """The whole corridor as a ROS robot logs it, processed with the mount from tf, from a file, and with none."""
    root = tmp_path_factory.mktemp("tf_mount")
    logs = {"tf": ros_laser_log(CORRIDOR, root / "robot.mcap", tf_static=MOUNT),
            "none": ros_laser_log(CORRIDOR, root / "robot_without_tf.mcap")}
    calib = root / "calib.yaml"
    calib.write_text("lidar_x: 0.35\nlidar_y: 0.0\nlidar_yaw: 0.0\n")
    outs = {"tf": root / "out_tf", "file": root / "out_file", "none": root / "out_none"}
    for name, log, extra in (("tf", logs["tf"], ()), ("file", logs["tf"], ("--calibration", str(calib))),
                             ("none", logs["none"], ())):
        code, _, err = run_cli_here("process", str(log), "-o", str(outs[name]), *ROBOT, *extra)
        assert code == 0, err
        outs[f"{name}_stderr"] = err  # type: ignore[assignment]
    return {**outs, "calib": calib, "log": logs["tf"], "log_none": logs["none"]}


def test_the_mount_from_tf_gives_the_trajectories_of_the_same_mount_in_a_file(robot):
    for name in TRAJECTORIES:
        assert (robot["tf"] / name).read_bytes() == (robot["file"] / name).read_bytes(), name
    tf_run, file_run = _run(robot["tf"]), _run(robot["file"])
    assert tf_run["mount"] == file_run["mount"] == [0.35, 0.0, 0.0]
    assert tf_run["calibration_source"] == "tf /tf_static base_link->laser"
    assert tf_run["calibration_sources"] == {"mount": "tf /tf_static base_link->laser",
                                             "wheels": "not used (no wheel ticks read)"}
    assert file_run["calibration_source"] == str(robot["calib"])
    assert not [w for w in tf_run["warnings"] if "mount" in w]


def test_without_the_mount_the_estimates_are_worse_and_the_warning_says_how_to_give_it(robot):
    gt = ground_truth(CORRIDOR)
    ate = {name: ate_rmse(tum(robot[name] / "improved.tum"), gt) for name in ("tf", "none")}
    assert ate["tf"] < 0.06, ate  # measured 3.0 cm
    assert ate["none"] > 3 * ate["tf"], ate  # measured 15.4 cm
    run = _run(robot["none"])
    assert run["mount"] == [0.0, 0.0, 0.0] and run["calibration_source"] == "none (assumed 0, 0, 0)"
    said = [w for w in run["warnings"] if "mount" in w]
    assert said == [f"{robot['log_none']}: nothing gives the lidar's mount (no fmcwlog.calibration record; tf: it has "
                    "no /tf_static or /tf): taken as 0, 0, 0 (the lidar at base_link's origin, facing forward); give "
                    "it with --calibration calib.yaml, a file such as '{lidar_x: 0.35, lidar_y: 0.0, lidar_yaw: 0.0}' "
                    f"(m, m, rad in base_link), or estimate it with 'fmcwlog calibrate {robot['log_none']} -o "
                    "calib.yaml' (needs Doppler and wheel ticks)"]
    assert "nothing gives the lidar's mount" in robot["none_stderr"]


def test_report_reads_an_output_whose_mount_came_from_tf(robot):
    ev = report(robot["tf"])
    assert ev.result["methods"]["improved"]["ate_rmse_m"] < 0.06


@pytest.fixture(scope="module")
def short(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("tf_short")


def _process(log: Path, out: Path, **opts) -> tuple[dict, list[str]]:
    s = process(log, out, ProcessOptions(methods=("baseline",), backend="none", **opts), jobs=1)
    return _run(out), s.warnings


def test_a_chained_tf_gives_the_composed_mount(short):
    """base_link -> sensor_mount turned +90° and 30 cm up, sensor_mount -> laser turned back and 10 cm
    down: (0.2 - (-0.15), 0.1 + (-0.1), 90° - 90°) = (0.35, 0, 0)."""
    chain = [tf_entry("base_link", "sensor_mount", (0.2, 0.1, 0.3), (0, 0, math.pi / 2)),
             tf_entry("sensor_mount", "laser", (-0.1, -0.15, -0.1), (0, 0, -math.pi / 2))]
    log = ros_laser_log(CORRIDOR, short / "chain.mcap", tf_static=chain, until_s=3)
    run, _ = _process(log, short / "out_chain")
    assert run["mount"] == pytest.approx([0.35, 0.0, 0.0], abs=1e-12)
    assert run["calibration_source"] == "tf /tf_static base_link->sensor_mount->laser"


def test_the_base_frame_is_an_option(short):
    log = ros_laser_log(CORRIDOR, short / "footprint.mcap", until_s=3,
                        tf_static=[tf_entry("base_footprint", "base_link", (0.0, 0.0, 0.1)),
                                   tf_entry("base_footprint", "laser", (0.35, 0.0, 0.3))])
    run, _ = _process(log, short / "out_footprint", base_frame="base_footprint")
    assert run["mount"] == [0.35, 0.0, 0.0] and run["calibration_source"] == "tf /tf_static base_footprint->laser"
    run, _ = _process(log, short / "out_base_link")  # base_link is a child of base_footprint, beside the laser
    assert run["calibration_source"] == "tf /tf_static base_link<-base_footprint->laser"


def test_a_record_and_tf_that_disagree_are_said_with_both_values(short):
    record = dict(metadata(CORRIDOR)["fmcwlog.calibration"], lidar_x="0.30")
    log = ros_laser_log(CORRIDOR, short / "disagree.mcap", tf_static=MOUNT, calibration=record, until_s=3)
    run, warnings = _process(log, short / "out_disagree")
    assert run["mount"] == [0.30, 0.0, 0.0] and run["calibration_source"] == "log record fmcwlog.calibration"
    said = [w for w in warnings if "disagree on the lidar's mount" in w]
    assert said == [f"{log}: fmcwlog.calibration and tf disagree on the lidar's mount: the record has x 0.3 m, y 0 m, "
                    "yaw 0 rad, tf /tf_static base_link->laser has x 0.35 m, y 0 m, yaw 0 rad; used the record's "
                    "(--calibration FILE overrides both)"]


def test_ticks_without_the_wheels_fall_back_to_odom_and_without_odom_name_the_option(short):
    """A bag converted by a tool that keeps /wheel/ticks and drops fmcwlog's record."""
    log = ros_laser_log(CORRIDOR, short / "ticks.mcap", tf_static=MOUNT, ticks=True, until_s=3)
    s = process(log, short / "out_ticks", ProcessOptions(methods=("baseline",), backend="none"), jobs=1)
    run = _run(short / "out_ticks")
    assert s.prior == run["prior"] == "odometry (/odom)"
    said = [w for w in s.warnings if "/wheel/ticks" in w]
    assert len(said) == 1 and "used /odom as the motion prior instead" in said[0] and "--calibration" in said[0]
    assert run["calibration_sources"]["wheels"] == "not used (no wheel ticks read)"
    bare = ros_laser_log(CORRIDOR, short / "ticks_only.mcap", tf_static=MOUNT, ticks=True, odom=False, until_s=3)
    code, _, err = run_cli_here("process", str(bare), "-o", str(short / "out_bare"), "--scan-topic", "/scan")
    wheels = "{wheel_radius_left: 0.1, wheel_radius_right: 0.1, track_width: 0.45, ticks_per_revolution: 4096}"
    line = helpers.assert_one_line_error(code, err, "/wheel/ticks holds wheel ticks", "--calibration calib.yaml", wheels)
    assert "Traceback" not in line and not (short / "out_bare").exists()
    example = line.split("a file such as '")[1].split("'")[0]
    calib = short / "wheels.yaml"
    calib.write_text(example + "\n")  # the one-line example is a file --calibration takes
    code, _, err = run_cli_here("process", str(bare), "-o", str(short / "out_bare"), "--scan-topic", "/scan",
                                "--calibration", str(calib), "--method", "baseline", "--backend", "none")
    assert code == 0, err
    run = _run(short / "out_bare")
    assert run["prior"] == "wheel ticks (/wheel/ticks)"
    assert run["calibration_sources"] == {"mount": "tf /tf_static base_link->laser", "wheels": str(calib)}
    assert run["calibration_source"] == f"mount from tf /tf_static base_link->laser; wheels from {calib}"


def test_our_own_log_with_its_mount_in_tf_only_gives_the_same_estimates(crowd_log, tmp_path):
    """A recorded log whose record lost the mount keys keeps /tf_static base_link -> lidar: the same
    estimates as with the record's mount; and calibrate starts from the tf's."""
    record = metadata(crowd_log)["fmcwlog.calibration"]
    log = tmp_path / "tf_only.mcap"
    copy_log(crowd_log, log, drop_metadata=("fmcwlog.calibration",),
             extra_metadata={"fmcwlog.calibration": {k: v for k, v in record.items() if not k.startswith("lidar_")}})
    run, warnings = _process(log, tmp_path / "out")
    ref, _ = _process(crowd_log, tmp_path / "ref")
    assert (tmp_path / "out" / "baseline.tum").read_bytes() == (tmp_path / "ref" / "baseline.tum").read_bytes()
    assert run["mount"] == ref["mount"] and not [w for w in warnings if "mount" in w]
    assert run["calibration_source"] == "mount from tf /tf_static base_link->lidar; wheels from log record fmcwlog.calibration"
    assert ref["calibration_source"] == "log record fmcwlog.calibration"
    calib = tmp_path / "calib.yaml"
    calibrate(log, calib, ProcessOptions(methods=("improved",)))
    text = calib.read_text()
    assert "starting from the mount of tf /tf_static base_link->lidar and the wheels of log record" in text
    values = {line.split(":")[0]: line.split(": ")[1] for line in text.splitlines() if not line.startswith("#")}
    assert {"lidar_x", "lidar_y", "lidar_yaw", "wheel_radius_left", "track_width"} <= set(values)
