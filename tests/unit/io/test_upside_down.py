"""A LiDAR mounted upside down (rolled by π about its x axis, its scan mirrored): the key
``lidar_upside_down`` in a calibration file and the log's record, the same from the log's tf
(fmcwlog.io.tf_tree), the order of those sources (fmcwlog.io.calibration.load_calibration), the
sweeps mirrored back as read (fmcwlog.io.sweeps.mirrored) and the roll published for viewers.

The facts checked against are geometry worked here by hand: the rotation a tf entry's roll, pitch
and yaw make, composed from elementary 3x3 matrices (not the code's quaternion), carries a point
of the sensor's plane to where the planar mount puts the mirrored point.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from helpers import tf_entry
from test_tf_tree import RECORD, FakeReader

from fmcwlog.errors import CalibrationError, LogError
from fmcwlog.frontend.mirror_check import MIRRORED, MIRRORED_TURNED, TURNED, _fix
from fmcwlog.io.calibration import RECORD_SOURCE, load_calibration
from fmcwlog.io.calibration_file import read_calibration_file
from fmcwlog.io.messages import transform_dict
from fmcwlog.io.sweeps import mirrored
from fmcwlog.io.tf_tree import mount_from_tf
from fmcwlog.types import Calibration, SweepInput

DEG = math.pi / 180
TF_SOURCE = "tf /tf_static base_link->laser"


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _planar(mount, xy):
    """Points (N, 2) of the lidar's frame in base_link by a planar mount (x, y, yaw)."""
    c, s = math.cos(mount[2]), math.sin(mount[2])
    return xy @ np.array([[c, s], [-s, c]]) + np.array(mount[:2])


def _found(rpy, xyz=(0.3, -0.1, 0.5)):
    return mount_from_tf(FakeReader([tf_entry("base_link", "laser", xyz, rpy)]), "/scan", "base_link")


@pytest.mark.parametrize("rpy, yaw", [
    ((math.pi, 0.0, 0.0), 0.0),
    ((math.pi, 0.0, 0.7), 0.7),  # rolled: Rz(yaw) Rx(π)
    ((math.pi, 0.0, -2.0), -2.0),
    ((0.0, math.pi, 0.0), math.pi),  # pitched by π: Rz(yaw + π) Rx(π), the sensor facing back
    ((0.0, math.pi, 0.7), 0.7 - math.pi),
])
def test_a_sensor_turned_over_is_upside_down_at_the_heading_of_its_x_axis(rpy, yaw):
    found, notes = _found(rpy)
    assert found.upside_down and notes == []
    assert found.mount[:2] == pytest.approx((0.3, -0.1), abs=1e-12)
    assert math.remainder(found.mount[2] - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    # where the sensor's points land in 3-D (elementary rotations, by hand) is the planar mount of the mirror
    r = _rz(rpy[2]) @ _ry(rpy[1]) @ _rx(rpy[0])
    xy = np.array([[2.0, 0.0], [1.0, 1.5], [-0.5, -3.0]])
    in_3d = (np.column_stack([xy, np.zeros(3)]) @ r.T)[:, :2] + [0.3, -0.1]
    assert _planar(found.mount, xy * [1, -1]) == pytest.approx(in_3d, abs=1e-12)
    assert not np.allclose(_planar(found.mount, xy), in_3d)  # unmirrored, it would be wrong


@pytest.mark.parametrize("rpy", [(1 * DEG, 0, 0.4), (0, -1.5 * DEG, 0.4), (1 * DEG, 1 * DEG, 0.4)])
def test_small_tilts_stay_upright_and_unsaid(rpy):
    found, notes = _found(rpy)
    assert not found.upside_down and notes == []
    assert found.mount == pytest.approx((0.3, -0.1, 0.4), abs=1e-12)


@pytest.mark.parametrize("roll, upside_down, said", [
    (178.5, True, None), (181.5, True, None),  # within 2° of upside down: level
    (170.0, True, "laser, upside down, by 10.0 degrees"), (100.0, True, "laser, upside down, by 80.0 degrees"),
    (80.0, False, "laser by 80.0 degrees"), (10.0, False, "laser by 10.0 degrees"),
])
def test_a_tilt_between_upright_and_upside_down_is_still_said(roll, upside_down, said):
    found, notes = _found((roll * DEG, 0, 0))
    assert found.upside_down == upside_down
    if said is None:
        assert notes == []
    else:
        assert len(notes) == 1 and f"tf tilts {said} from base_link's plane" in notes[0], notes
        assert "not horizontal" in notes[0]


# ----------------------------------------------------------------------------- the key and its sources

def _load(reader, path=None, need_wheels=False):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = load_calibration(reader, reader.path, "/scan", need_wheels, path)
    return loaded, [str(w.message) for w in caught]


UPSIDE_DOWN_TF = [tf_entry("base_link", "laser", (0.3, 0.0, 0.2), (math.pi, 0, 0.5))]


def test_tf_that_gives_the_mount_gives_upside_down_with_a_note():
    loaded, said = _load(FakeReader(UPSIDE_DOWN_TF))
    assert loaded.cal.upside_down and loaded.cal.mount == pytest.approx((0.3, 0.0, 0.5))
    assert loaded.sources.to_json() == {"mount": TF_SOURCE, "wheels": "not used (no wheel ticks read)",
                                        "upside_down": TF_SOURCE}
    assert loaded.sources.describe() == TF_SOURCE
    assert loaded.values["lidar_upside_down"] == "true"  # what calibrate writes into its file
    assert len(said) == 1 and "tf turns the lidar upside down" in said[0] and "lidar_upside_down: true" in said[0]
    assert "cannot" not in said[0]


def test_an_upright_tf_says_nothing_of_it():
    loaded, said = _load(FakeReader([tf_entry("base_link", "laser", (0.3, 0.0, 0.2))]))
    assert not loaded.cal.upside_down and said == []
    assert "upside_down" not in loaded.sources.to_json() and "lidar_upside_down" not in loaded.values


def test_the_records_mount_goes_before_tf_and_the_roll_is_a_disagreement():
    loaded, said = _load(FakeReader(UPSIDE_DOWN_TF, record=dict(RECORD, lidar_x="0.3", lidar_yaw="0.5")))
    assert not loaded.cal.upside_down and loaded.sources.describe() == RECORD_SOURCE
    assert len(said) == 1 and "disagree on the lidar's mount" in said[0], said
    assert "the record has x 0.3 m, y 0 m, yaw 0.5 rad, tf" in said[0] and "yaw 0.5 rad, upside down; used the record's" in said[0]
    loaded, said = _load(FakeReader(UPSIDE_DOWN_TF, record=dict(RECORD, lidar_x="0.3", lidar_yaw="0.5",
                                                                lidar_upside_down="true")))
    assert loaded.cal.upside_down and said == []  # the record says it too: they agree
    assert loaded.sources.to_json()["upside_down"] == RECORD_SOURCE


def test_the_key_in_a_file_goes_before_the_record_and_tf(tmp_path):
    calib = tmp_path / "calib.yaml"
    calib.write_text("lidar_upside_down: true\n")  # the key alone: the mount stays the record's
    loaded, said = _load(FakeReader(record=RECORD), path=calib)
    assert loaded.cal.upside_down and loaded.cal.mount == (0.35, 0.0, 0.0) and said == []
    assert loaded.sources.describe() == f"mount from {RECORD_SOURCE}; lidar_upside_down from {calib}"
    assert loaded.values["lidar_upside_down"] == "true" and loaded.values["lidar_x"] == "0.35"
    calib.write_text("lidar_upside_down: false\n")
    loaded, _ = _load(FakeReader(UPSIDE_DOWN_TF), path=calib)
    assert not loaded.cal.upside_down and loaded.cal.mount == pytest.approx((0.3, 0.0, 0.5))
    assert loaded.sources.to_json()["upside_down"] == str(calib)


@pytest.mark.parametrize("text, value", [("true", True), ("false", False), ("True", True), ("'true'", True),
                                         ("FALSE", False)])
def test_a_file_takes_true_or_false(tmp_path, text, value):
    calib = tmp_path / "calib.yaml"
    calib.write_text(f"lidar_x: 0.35\nlidar_upside_down: {text}\n")
    assert read_calibration_file(calib)["lidar_upside_down"] == str(value).lower()
    loaded, _ = _load(FakeReader(), path=calib)
    assert loaded.cal.upside_down is value


@pytest.mark.parametrize("suffix, text, got", [
    (".yaml", "lidar_upside_down: 1\n", "1"), (".yaml", "lidar_upside_down: maybe\n", "'maybe'"),
    (".yaml", "lidar_upside_down: [true]\n", "[True]"), (".json", '{"lidar_upside_down": 0}', "0"),
])
def test_a_file_with_anything_else_is_a_one_line_error_naming_it(tmp_path, suffix, text, got):
    calib = tmp_path / f"calib{suffix}"
    calib.write_text(text)
    with pytest.raises(CalibrationError) as exc:
        _load(FakeReader(), path=calib)
    assert str(exc.value) == f"{calib}: 'lidar_upside_down' must be true or false, got {got}"


def test_true_is_no_number_for_the_other_keys(tmp_path):
    calib = tmp_path / "calib.yaml"
    calib.write_text("lidar_x: true\n")
    with pytest.raises(CalibrationError, match="'lidar_x' must be a number"):
        _load(FakeReader(), path=calib)


def test_a_record_with_a_bad_value_is_an_error_naming_the_log():
    with pytest.raises(LogError, match=r"robot.mcap: calibration 'lidar_upside_down' must be true or false, got 'yes'"):
        _load(FakeReader(record=dict(RECORD, lidar_upside_down="yes")))


# ----------------------------------------------------------------------------- what it does to the sweeps

def test_a_mirrored_sweep_negates_y_only_and_copies():
    xy = np.array([[1.0, 2.0], [3.0, -4.0]], np.float32)
    sweep = SweepInput(7, xy, np.array([0.0, 0.05]), np.array([0.5, -1.0]), np.array([10.0, 20.0]))
    out = mirrored(sweep)
    assert out.xy.tolist() == [[1.0, -2.0], [3.0, 4.0]] and out.xy.dtype == np.float32
    assert xy.tolist() == [[1.0, 2.0], [3.0, -4.0]]  # the input untouched
    assert out.velocity is sweep.velocity and out.t is sweep.t and out.stamp_ns == 7  # radial Doppler, times kept
    assert Calibration(None, (0, 0, 0), None, None).upside_down is False  # upright unless said


@pytest.mark.parametrize("yaw", [0.0, 0.5, -2.5, math.pi])
def test_the_published_mount_carries_the_roll(yaw):
    q = transform_dict(0, "base_link", "lidar", np.array([0.3, 0.1, yaw]), upside_down=True)["transform"]["rotation"]
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    assert r == pytest.approx(_rz(yaw) @ _rx(math.pi), abs=1e-12)
    upright = transform_dict(0, "base_link", "lidar", np.array([0.3, 0.1, yaw]))["transform"]["rotation"]
    assert upright["x"] == upright["y"] == 0.0


# ----------------------------------------------------------------------------- the mount check's words

def test_the_mount_check_names_the_key_each_way():
    assert _fix(MIRRORED, 0.0).endswith("mounted upside down (its scan mirrored): set lidar_upside_down: true in the "
                                        "calibration (--calibration)")
    assert "set lidar_upside_down: false in the calibration" in _fix(MIRRORED, 0.0, upside_down=True)
    both = _fix(MIRRORED_TURNED, 0.0)
    assert "set lidar_upside_down: true and lidar_yaw: 3.141593 (not 0.000000)" in both
    assert "lidar_upside_down" not in _fix(TURNED, 0.0)


def test_the_key_in_a_file_is_no_disagreement_between_the_record_and_tf(tmp_path):
    """The file overrides both: the record's mount against tf is compared without the file's roll."""
    calib = tmp_path / "calib.yaml"
    calib.write_text("lidar_upside_down: true\n")
    upright = [tf_entry("base_link", "laser", (0.35, 0.0, 0.2))]
    loaded, said = _load(FakeReader(upright, record=RECORD), path=calib)
    assert loaded.cal.upside_down and said == []
    loaded, said = _load(FakeReader(UPSIDE_DOWN_TF, record=RECORD), path=calib)
    assert loaded.cal.upside_down and len(said) == 1 and "x 0.35 m, y 0 m, yaw 0 rad, tf" in said[0], said  # x, yaw
