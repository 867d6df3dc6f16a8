"""The mount from a log's tf (fmcwlog.io.tf_tree) and the order of the calibration's sources
(fmcwlog.io.calibration.load_calibration), on a stand-in reader holding tf messages as a ROS
decoder gives them (attributes, not dicts). Expected mounts are composed here by hand: plane
rotations and translations, not the 3-D matrices the code composes."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from types import SimpleNamespace as NS

import pytest
from helpers import tf_entry

from fmcwlog.errors import LogError
from fmcwlog.io.calibration import MOUNT_EXAMPLE, NO_MOUNT, RECORD_SOURCE, load_calibration
from fmcwlog.io.tf_tree import TfMount, mount_from_tf

DEG = math.pi / 180


def _ns(d):
    """A decoded message as a ROS decoder gives it: nested attributes."""
    if isinstance(d, dict):
        return NS(**{k: _ns(v) for k, v in d.items()})
    if isinstance(d, list):
        return [_ns(v) for v in d]
    return d


class FakeReader:
    """The reader's public interface over messages given per topic (each a dict or a list of transforms)."""

    def __init__(self, static=(), tf=(), frame_id="laser", record=None, path="robot.mcap"):
        self.path = Path(path)
        self._messages = {"/scan": [{"header": {"frame_id": frame_id}}]}
        self.topics = {"/scan": "sensor_msgs/msg/LaserScan"}
        if static:
            self._messages["/tf_static"] = [{"transforms": list(static)}]
            self.topics["/tf_static"] = "tf2_msgs/msg/TFMessage"
        if tf:
            self._messages["/tf"] = [{"transforms": list(entries)} for entries in tf]
            self.topics["/tf"] = "tf2_msgs/msg/TFMessage"
        self.record = record
        self.read: list[str] = []

    def messages(self, topics=None):
        for topic in topics:
            self.read.append(topic)
            for m in self._messages.get(topic, []):
                yield NS(topic=topic, msg=_ns(m))

    def metadata_all(self, name):
        return [self.record] if self.record is not None and name == "fmcwlog.calibration" else []

    def damage_note(self):
        return ""


def _plane(*links):
    """(x, y, yaw) of a chain of planar links, each (x, y, yaw) in its parent: composed by hand."""
    x = y = yaw = 0.0
    for lx, ly, lyaw in links:
        x, y = x + math.cos(yaw) * lx - math.sin(yaw) * ly, y + math.sin(yaw) * lx + math.cos(yaw) * ly
        yaw += lyaw
    return x, y, yaw


def _mount(reader, base="base_link"):
    found, notes = mount_from_tf(reader, "/scan", base)
    return found, notes


def test_a_direct_static_transform_is_the_mount():
    found, notes = _mount(FakeReader([tf_entry("base_link", "laser", (0.35, 0.0, 0.2))]))
    assert isinstance(found, TfMount) and notes == []
    assert found.mount == (0.35, 0.0, 0.0)
    assert found.source == "tf /tf_static base_link->laser"


def test_a_chain_through_a_mount_frame_is_composed():
    links = [(0.2, 0.1, 30 * DEG), (0.1, -0.05, 15 * DEG)]
    reader = FakeReader([tf_entry("sensor_mount", "laser", (0.1, -0.05, -0.4), (0, 0, 15 * DEG)),  # child first
                         tf_entry("base_link", "sensor_mount", (0.2, 0.1, 0.5), (0, 0, 30 * DEG))])
    found, _ = _mount(reader)
    assert found.mount == pytest.approx(_plane(*links), abs=1e-12)
    assert found.source == "tf /tf_static base_link->sensor_mount->laser"


def test_a_chain_of_turned_frames_that_cancel_is_the_straight_mount():
    """base_link -> sensor_mount turned +90° and raised, sensor_mount -> laser turned back: (0.35, 0, 0)."""
    reader = FakeReader([tf_entry("base_link", "sensor_mount", (0.2, 0.1, 0.3), (0, 0, 90 * DEG)),
                         tf_entry("sensor_mount", "laser", (-0.1, -0.15, -0.1), (0, 0, -90 * DEG))])
    found, _ = _mount(reader)
    assert found.mount == pytest.approx((0.35, 0.0, 0.0), abs=1e-12)


def test_a_sibling_of_the_base_frame_goes_through_their_common_parent():
    """base_footprint -> base_link and base_footprint -> laser (as a URDF rooted at base_footprint has it)."""
    reader = FakeReader([tf_entry("base_footprint", "base_link", (0.05, 0.0, 0.1), (0, 0, 10 * DEG)),
                         tf_entry("base_footprint", "laser", (0.4, 0.1, 0.3), (0, 0, 40 * DEG))])
    found, _ = _mount(reader)
    # laser in base_link = inverse(base_link in footprint) composed with laser in footprint
    c, s = math.cos(10 * DEG), math.sin(10 * DEG)
    dx, dy = 0.4 - 0.05, 0.1 - 0.0
    assert found.mount == pytest.approx((c * dx + s * dy, -s * dx + c * dy, 30 * DEG), abs=1e-12)
    assert found.source == "tf /tf_static base_link<-base_footprint->laser"
    found, _ = _mount(reader, base="base_footprint")
    assert found.mount == pytest.approx((0.4, 0.1, 40 * DEG), abs=1e-12)


def test_the_projection_keeps_the_heading_of_a_slightly_rolled_and_pitched_sensor():
    found, notes = _mount(FakeReader([tf_entry("base_link", "laser", (0.3, -0.1, 0.5), (0.01, 0.02, 0.5))]))
    assert found.mount == pytest.approx((0.3, -0.1, 0.5), abs=1e-12)  # yaw of Rz Ry Rx is the x axis's heading
    assert notes == []  # 1.3° is not worth a warning


def test_a_tilted_sensor_is_said_with_its_angle():
    found, notes = _mount(FakeReader([tf_entry("base_link", "laser", (0.3, 0.0, 0.5), (0, 10 * DEG, 0))]))
    assert isinstance(found, TfMount) and len(notes) == 1
    assert "tilts laser by 10.0 degrees from base_link's plane" in notes[0] and "not horizontal" in notes[0]
    found, notes = _mount(FakeReader([tf_entry("base_link", "laser", (0.3, 0.0, 0.5), (math.pi, 0, 0))]))
    assert found.upside_down and notes == []  # upside down and level: a mount, nothing to warn of


def test_a_transform_that_never_changes_on_tf_counts_and_one_that_moves_does_not():
    still = [[tf_entry("base_link", "laser", (0.35, 0.0, 0.2)), tf_entry("odom", "base_link", (0.1 * i, 0, 0))]
             for i in range(20)]
    found, _ = _mount(FakeReader(tf=still))
    assert found.mount == pytest.approx((0.35, 0.0, 0.0)) and found.source == "tf /tf base_link->laser"
    turning = [[tf_entry("base_link", "laser", (0.35, 0.0, 0.2), (0, 0, 0.01 * i))] for i in range(20)]
    found, _ = _mount(FakeReader(tf=turning))
    assert found == "laser moves relative to base_link on /tf (a joint or the robot's motion, not a mount)"


def test_tf_static_is_read_alone_where_it_reaches_the_base():
    reader = FakeReader([tf_entry("base_link", "laser", (0.35, 0, 0))],
                        tf=[[tf_entry("base_link", "laser", (9.0, 0, 0))]])
    found, _ = _mount(reader)
    assert found.mount == (0.35, 0.0, 0.0) and "/tf" not in reader.read


def test_ros1_frame_names_with_a_leading_slash_and_its_tf_message_type():
    reader = FakeReader([tf_entry("/base_link", "/laser", (0.35, 0, 0))], frame_id="/laser")
    reader.topics["/tf_static"] = "tf/msg/tfMessage"
    found, _ = _mount(reader)
    assert found.mount == (0.35, 0.0, 0.0)


@pytest.mark.parametrize("reader, words", [
    (FakeReader(), "it has no /tf_static or /tf"),
    (FakeReader([tf_entry("chassis", "laser", (0.35, 0, 0))]),
     "its tf links laser to no frame base_link (its frames: chassis, laser; --base-frame names the robot's base frame)"),
    (FakeReader([tf_entry("base_link", "laser", (0.35, 0, 0))], frame_id=""),
     "the messages on /scan name no frame (header.frame_id)"),
])
def test_why_tf_gives_no_mount(reader, words):
    found, _ = _mount(reader)
    assert found == words


# ----------------------------------------------------------------------------- the order of the sources

RECORD = {"wheel_radius_left": "0.1", "wheel_radius_right": "0.1", "track_width": "0.45",
          "ticks_per_revolution": "4096", "lidar_x": "0.35", "lidar_y": "0.0", "lidar_yaw": "0.0", "scan_rate": "10.0"}
WHEELS = {k: v for k, v in RECORD.items() if not k.startswith("lidar")}
TF_030 = [tf_entry("base_link", "laser", (0.30, 0.0, 0.2))]


def _load(reader, need_wheels=False, path=None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = load_calibration(reader, reader.path, "/scan", need_wheels, path)
    return loaded, [str(w.message) for w in caught]


def test_the_record_goes_before_tf_and_a_disagreement_names_both():
    loaded, said = _load(FakeReader(TF_030, record=RECORD), need_wheels=True)
    assert loaded.cal.mount == (0.35, 0.0, 0.0)
    assert loaded.sources.describe() == RECORD_SOURCE
    assert said == ["robot.mcap: fmcwlog.calibration and tf disagree on the lidar's mount: the record has x 0.35 m, "
                    "y 0 m, yaw 0 rad, tf /tf_static base_link->laser has x 0.3 m, y 0 m, yaw 0 rad; used the "
                    "record's (--calibration FILE overrides both)"]


def test_a_record_and_tf_that_agree_say_nothing():
    loaded, said = _load(FakeReader([tf_entry("base_link", "laser", (0.3502, 0.0, 0.2))], record=RECORD))
    assert said == [] and loaded.cal.mount == (0.35, 0.0, 0.0)


def test_tf_gives_the_mount_a_record_without_it_lacks():
    loaded, said = _load(FakeReader(TF_030, record=WHEELS), need_wheels=True)
    assert said == [] and loaded.cal.mount == pytest.approx((0.30, 0.0, 0.0))
    assert loaded.cal.wheels is not None and loaded.cal.scan_rate == 10.0
    assert loaded.sources.to_json() == {"mount": "tf /tf_static base_link->laser", "wheels": RECORD_SOURCE}
    assert loaded.sources.describe() == f"mount from tf /tf_static base_link->laser; wheels from {RECORD_SOURCE}"
    assert float(loaded.values["lidar_x"]) == pytest.approx(0.30) and loaded.values["track_width"] == "0.45"


def test_a_file_goes_before_the_record_and_tf_group_by_group(tmp_path):
    mount_only = tmp_path / "mount.yaml"
    mount_only.write_text("lidar_x: 0.4\nlidar_y: 0.01\nlidar_yaw: 0.02\n")
    loaded, said = _load(FakeReader(TF_030, record=RECORD), need_wheels=True, path=mount_only)
    assert said == [] and loaded.cal.mount == (0.4, 0.01, 0.02)
    assert loaded.cal.wheels.track_width == 0.45  # the record's: the file has no wheels
    assert loaded.sources.to_json() == {"mount": str(mount_only), "wheels": RECORD_SOURCE}


def test_nothing_gives_the_mount_a_warning_names_the_option_and_the_file_it_takes(tmp_path):
    loaded, said = _load(FakeReader())
    assert loaded.cal.mount == (0.0, 0.0, 0.0) and loaded.sources.describe() == NO_MOUNT
    assert len(said) == 1 and "nothing gives the lidar's mount" in said[0] and "--calibration calib.yaml" in said[0]
    assert "fmcwlog calibrate robot.mcap -o calib.yaml" in said[0]
    example = said[0].split("a file such as '")[1].split("'")[0]
    assert example == MOUNT_EXAMPLE
    calib = tmp_path / "calib.yaml"
    calib.write_text(example + "\n")  # the one-line example is a file the option takes
    loaded, said = _load(FakeReader(), path=calib)
    assert said == [] and loaded.cal.mount == (0.35, 0.0, 0.0) and loaded.sources.describe() == str(calib)


def test_ticks_without_wheels_leave_the_wheels_to_the_caller():
    loaded, _ = _load(FakeReader(TF_030), need_wheels=True)
    assert loaded.cal.wheels is None and loaded.sources.wheels == "none"


def test_a_bad_record_value_is_an_error_naming_the_log():
    with pytest.raises(LogError, match=r"robot.mcap: calibration 'lidar_x' = 99 m is outside"):
        _load(FakeReader(TF_030, record=dict(RECORD, lidar_x="99")))
