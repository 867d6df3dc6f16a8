"""The LiDAR's mount as a ROS log's transform tree holds it: ``/tf_static``, and ``/tf`` where a
transform never changes over the log.

A robot's URDF places the sensor through its fixed joints, which ``robot_state_publisher``
publishes on ``/tf_static`` (a driver or a launch file may publish the same on ``/tf``, over and
over). The scan's ``header.frame_id`` names the sensor's frame; the path from the robot's base
frame (``base_link`` unless told otherwise) to it, through whatever frames lie between
(``base_link -> sensor_mount -> laser``), composed in 3-D, is the mount. It is projected to the
plane processing works in: x and y of the sensor's origin in the base frame, and the heading of its
x axis. A sensor whose z axis points down (tilted by more than 90°) is upside down: rolled by π
about its x axis, ``R = Rz(yaw) Rx(π)``, its scan mirrored (``Calibration.upside_down``); a pitch
of π is the same sensor facing back, ``Rz(yaw + π) Rx(π)``, and the heading of the x axis,
``atan2(r10, r00)``, is the yaw of both. A sensor tilted by more than :data:`TILT_WARN_RAD` from
either (upright or upside down) sweeps a cone, not the plane: said.

Only the reader's public interface is used (``topics``, ``messages``, ``path``), so any log reader
with that interface serves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..errors import LogError
from .topics import TF_STATIC_TOPIC, TF_TOPIC

TF_TOPICS = (TF_STATIC_TOPIC, TF_TOPIC)  # /tf_static first: its transform wins over /tf's for a frame
STATIC_TOLERANCE = 1e-6  # m, and unit quaternion components: a /tf transform that moves less is static
TILT_WARN_RAD = math.radians(2.0)  # a sensor tilted more sees the floor or over obstacles within a few m
MAX_FRAMES_NAMED = 8  # frames listed when none of them links the sensor to the base


class MessageSource(Protocol):
    """What this module reads of a log: a reader's public interface."""

    path: Any

    @property
    def topics(self) -> dict[str, str]: ...

    def messages(self, topics: Any = None) -> Any: ...


@dataclass(frozen=True)
class Link:
    """One transform of the tree: ``child``'s pose in ``parent`` (translation m, rotation 3x3), from ``topic``."""

    parent: str
    child: str
    translation: np.ndarray
    rotation: np.ndarray
    topic: str


@dataclass(frozen=True)
class TfMount:
    """The sensor's pose in the base frame as tf gives it.

    mount: (x m, y m, yaw rad) in the plane; tilt: the angle (rad) between the sensor's z axis and
    the base frame's (over π/2: :attr:`upside_down`); path: the frames from the base to the sensor, each hop marked ``->`` where
    tf holds it parent to child and ``<-`` where it is taken inverted; topics: the tf topics whose
    transforms it used.
    """

    mount: tuple[float, float, float]
    tilt: float
    path: str
    topics: tuple[str, ...]

    @property
    def source(self) -> str:
        """Where the mount came from, as run.json says it: ``tf /tf_static base_link->laser``."""
        return f"tf {', '.join(self.topics)} {self.path}"

    @property
    def upside_down(self) -> bool:
        """The sensor's z axis points down: rolled by π about its x axis (its scan mirrored, y -> -y)."""
        return self.tilt > math.pi / 2

    def upside_down_note(self, log: Any, base: str) -> str:
        """The note that the mount was taken as upside down from tf."""
        return (f"{log}: tf turns the lidar upside down ({self.path}: its z axis {math.degrees(self.tilt):.1f} "
                f"degrees from {base}'s): taken as lidar_upside_down: true, its scan mirrored back (y -> -y) "
                "before processing")


def _frame(name: str) -> str:
    """A frame's name as tf2 compares it (ROS 1's leading slash dropped)."""
    return str(name).strip().lstrip("/")


def _rotation(q: Any) -> np.ndarray | None:
    """The rotation matrix of a geometry_msgs/Quaternion; None for a zero or non-finite one."""
    v = np.array([q.x, q.y, q.z, q.w], float)
    n = float(np.linalg.norm(v))
    if not np.isfinite(v).all() or n < 1e-9:
        return None
    x, y, z, w = v / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _links(message: Any, topic: str) -> list[Link]:
    """The usable transforms of one TFMessage (a non-finite or zero-rotation one is left out)."""
    out = []
    for tf in getattr(message, "transforms", None) or []:
        t, r = tf.transform.translation, _rotation(tf.transform.rotation)
        xyz = np.array([t.x, t.y, t.z], float)
        parent, child = _frame(tf.header.frame_id), _frame(tf.child_frame_id)
        if r is not None and np.isfinite(xyz).all() and parent and child and parent != child:
            out.append(Link(parent, child, xyz, r, topic))
    return out


def _same(a: Link, b: Link) -> bool:
    return (a.parent == b.parent and bool(np.abs(a.translation - b.translation).max() <= STATIC_TOLERANCE)
            and bool(np.abs(a.rotation - b.rotation).max() <= STATIC_TOLERANCE))


def _is_tf(reader: MessageSource, topic: str) -> bool:
    """Whether the log has ``topic`` as transforms: tf2_msgs/TFMessage, or ROS 1's tf/tfMessage."""
    return reader.topics.get(topic, "").lower().endswith("tfmessage")


@dataclass
class TfTree:
    """The static transforms of a log, by child frame; ``moving``: the frames whose /tf transform changed."""

    links: dict[str, Link]
    moving: dict[str, str]  # child -> its parent on /tf
    notes: list[str]


def read_tree(reader: MessageSource, topics: tuple[str, ...]) -> TfTree:
    """The transforms on ``topics`` that hold still over the log.

    ``/tf_static``: every transform, the last one of a frame where it is published again (as tf2
    keeps it; one that changed is noted). ``/tf``: a frame whose transform never moves by more
    than :data:`STATIC_TOLERANCE` (a fixed joint republished); the others are joints or the
    robot's motion, kept in ``moving``. A frame on ``/tf_static`` is not looked for on ``/tf``.
    Raises :class:`LogError` where the tf topics cannot be read.
    """
    links: dict[str, Link] = {}
    moving: dict[str, str] = {}
    notes: list[str] = []
    for topic in topics:
        if not _is_tf(reader, topic):
            continue
        here: dict[str, Link] = {}
        changed: set[str] = set()
        for lm in reader.messages([topic]):
            for link in _links(lm.msg, topic):
                if link.child in links:  # /tf_static's, read first
                    continue
                before = here.get(link.child)
                if before is not None and not _same(before, link):
                    changed.add(link.child)
                if topic == TF_STATIC_TOPIC or before is None:
                    here[link.child] = link
        for child in sorted(changed):
            if topic == TF_STATIC_TOPIC:
                notes.append(f"{reader.path}: {topic} changes {here[child].parent} -> {child} during the log: "
                             "used its last transform")
            else:
                moving[child] = here.pop(child).parent
        links.update(here)
    return TfTree(links, moving, notes)


def _ancestors(tree: TfTree, frame: str) -> list[str]:
    """``frame`` and its parents up to the root of its tree (a loop ends it)."""
    out = [frame]
    while out[-1] in tree.links and tree.links[out[-1]].parent not in out:
        out.append(tree.links[out[-1]].parent)
    return out


def _pose_in(tree: TfTree, frames: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The pose of ``frames[0]`` in ``frames[-1]``, its ancestor, by the links between them."""
    t, r = np.zeros(3), np.eye(3)
    for child in frames[:-1]:
        link = tree.links[child]
        t, r = link.rotation @ t + link.translation, link.rotation @ r
    return t, r


def mount_in(tree: TfTree, sensor: str, base: str) -> TfMount | str:
    """``sensor``'s pose in ``base`` through the tree (their common ancestor, as tf2 looks it up), or
    why the tree cannot give it."""
    if sensor == base:
        return TfMount((0.0, 0.0, 0.0), 0.0, base, ())
    up_sensor, up_base = _ancestors(tree, sensor), _ancestors(tree, base)
    common = next((f for f in up_sensor if f in up_base), None)
    if common is None:
        for frame in up_sensor + up_base:
            if frame in tree.moving:
                return (f"{frame} moves relative to {tree.moving[frame]} on {TF_TOPIC} (a joint or the robot's "
                        f"motion, not a mount)")
        known = sorted({f for link in tree.links.values() for f in (link.parent, link.child)})
        if not known:
            return "its tf holds no static transform"
        shown = ", ".join(known[:MAX_FRAMES_NAMED]) + (f" and {len(known) - MAX_FRAMES_NAMED} more"
                                                          if len(known) > MAX_FRAMES_NAMED else "")
        return (f"its tf links {sensor} to no frame {base} (its frames: {shown}; --base-frame names the "
                "robot's base frame)")
    sensor_part = up_sensor[:up_sensor.index(common) + 1]
    base_part = up_base[:up_base.index(common) + 1]
    t_s, r_s = _pose_in(tree, sensor_part)  # the sensor in the common frame
    t_b, r_b = _pose_in(tree, base_part)  # the base in the common frame
    t, r = r_b.T @ (t_s - t_b), r_b.T @ r_s
    path = "<-".join(base_part)
    path += "->" + "->".join(reversed(sensor_part[:-1])) if len(sensor_part) > 1 else ""
    used = {tree.links[f].topic for f in sensor_part[:-1] + base_part[:-1]}
    tilt = math.acos(min(1.0, max(-1.0, float(r[2, 2]))))
    return TfMount((float(t[0]), float(t[1]), math.atan2(float(r[1, 0]), float(r[0, 0]))), tilt, path,
                   tuple(topic for topic in TF_TOPICS if topic in used))


def sensor_frame(reader: MessageSource, scan_topic: str) -> str | None:
    """The ``header.frame_id`` of the first message on ``scan_topic`` (None where it has none)."""
    messages = reader.messages([scan_topic])
    try:
        first = next(iter(messages), None)
    finally:
        close = getattr(messages, "close", None)
        if close is not None:
            close()
    if first is None:
        return None
    return _frame(getattr(getattr(first.msg, "header", None), "frame_id", "") or "") or None


def mount_from_tf(reader: MessageSource, scan_topic: str, base: str) -> tuple[TfMount | str, list[str]]:
    """The mount of the sensor that writes ``scan_topic`` in ``base``, from the log's tf (or why not),
    and the notes reading it made: ``/tf_static`` first, ``/tf`` only where that does not reach."""
    present = [t for t in TF_TOPICS if _is_tf(reader, t)]
    if not present:
        return f"it has no {TF_STATIC_TOPIC} or {TF_TOPIC}", []
    try:
        sensor = sensor_frame(reader, scan_topic)
        if sensor is None:
            return f"the messages on {scan_topic} name no frame (header.frame_id)", []
        tree = read_tree(reader, (TF_STATIC_TOPIC,))
        found = mount_in(tree, sensor, base)
        if isinstance(found, str) and TF_TOPIC in present:
            tree = read_tree(reader, TF_TOPICS)
            found = mount_in(tree, sensor, base)
    except LogError as exc:
        return f"its tf cannot be read ({exc})", []
    notes = list(tree.notes)
    if isinstance(found, TfMount) and min(found.tilt, math.pi - found.tilt) > TILT_WARN_RAD:
        what = f"{sensor}, upside down," if found.upside_down else sensor
        notes.append(f"{reader.path}: tf tilts {what} by {math.degrees(min(found.tilt, math.pi - found.tilt)):.1f} "
                     f"degrees from {base}'s plane ({found.path}): its scan is not horizontal; processed as a planar "
                     "scan at x, y, yaw")
    return found, notes
