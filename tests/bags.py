"""Bags written by rosbags' own writers from an fmcwlog log's messages: a rosbag2 folder (sqlite3 or
MCAP storage) and a ROS 1 bag, the same messages with the same timestamps (or, with ``delay``,
some topics stamped by the bag later than their header, as a recorder receives them). A bag holds
no MCAP metadata records: the log's ``fmcwlog.calibration`` goes to a calibration file
(:func:`calibration_file`)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

from mcap.reader import make_reader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fmcwlog.io.calibration_file import write_calibration_file
from fmcwlog.io.schemas import message_definition
from fmcwlog.io.topics import CALIBRATION_KEY

OWN = ("fmcwlog_msgs/msg/WheelTicks", "fmcwlog_msgs/msg/PointLabels")


def typestore(ros1: bool = False):
    """ROS 2 Humble's types (ROS 1 Noetic's) with the log format's own."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    own: dict = {}
    for name in OWN:
        own.update(get_types_from_msg(message_definition(name), name))
    store.register({k: v for k, v in own.items() if k not in store.fielddefs})
    return store


def _messages(log: Path, topics: Sequence[str] | None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, log_time, CDR bytes) of ``log``'s messages in file order."""
    with open(log, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            if topics is None or channel.topic in topics:
                yield channel.topic, schema.name, message.log_time, message.data


def write_rosbag2(log: Path, folder: Path, storage: str = "sqlite3", topics: Sequence[str] | None = None,
                  delay: dict[str, int] | None = None) -> Path:
    """``log``'s messages (on ``topics``; all when None) as a rosbag2 folder, its bytes as they are;
    ``delay``: ns added to the bag's timestamp of each message on a topic."""
    store = typestore()
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Ros2Writer(folder, version=9, storage_plugin=plugin) as writer:
        connections: dict = {}
        for topic, datatype, log_time, data in _messages(log, topics):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, datatype, typestore=store)
            writer.write(connections[topic], log_time + (delay or {}).get(topic, 0), data)
    return folder


def _as_ros1(msg, store1):
    """A ROS 2 message as its ROS 1 type in ``store1``: the same fields, a header's seq 0."""
    if not hasattr(msg, "__msgtype__"):
        if isinstance(msg, list):
            return [_as_ros1(m, store1) for m in msg]
        return msg
    name = msg.__msgtype__
    fields = {f: _as_ros1(getattr(msg, f), store1) if hasattr(msg, f) else 0 for f, _ in store1.fielddefs[name][1]}
    return store1.types[name](**fields)


def write_ros1(log: Path, path: Path, topics: Sequence[str] | None = None, delay: dict[str, int] | None = None) -> Path:
    """``log``'s messages as a ROS 1 bag (each decoded, then written as its ROS 1 type)."""
    store2, store1 = typestore(), typestore(ros1=True)
    missing: dict = {}
    for name in ("tf2_msgs/msg/TFMessage",):  # not in Noetic's store; its header as Noetic's (with seq)
        missing.update(get_types_from_msg(store2.generate_msgdef(name, ros_version=1)[0], name))
    store1.register({k: v for k, v in missing.items() if k not in store1.fielddefs})
    with Ros1Writer(path) as writer:
        connections: dict = {}
        for topic, datatype, log_time, data in _messages(log, topics):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, datatype, typestore=store1)
            msg = _as_ros1(store2.deserialize_cdr(data, datatype), store1)
            writer.write(connections[topic], log_time + (delay or {}).get(topic, 0), store1.serialize_ros1(msg, datatype))
    return path


def calibration_file(log: Path, path: Path) -> Path:
    """``log``'s ``fmcwlog.calibration`` record as a calibration file (``--calibration``)."""
    with open(log, "rb") as fh:
        record = next(m.metadata for m in make_reader(fh).iter_metadata() if m.name == CALIBRATION_KEY)
    write_calibration_file(path, dict(record), [f"the {CALIBRATION_KEY} record of {log.name}"])
    return path
