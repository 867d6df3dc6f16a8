"""Can a viewer place every message of an MCAP file? Each frame a message names must resolve to ``map``
through the file's own tf at the message's stamp, as Foxglove's 3D panel and RViz resolve it.

    python bench/replay_frames.py FILE... [--tf-topic /tf --tf-topic /tf_static] [--root map]

Read with plain ``mcap`` + ``mcap_ros2`` (not fmcwlog's reader). The tf tree follows tf2's rules:
a transform on ``/tf_static`` holds at every time; one on another tf topic holds between its child's
first and last stamp (interpolated between samples, never extrapolated). The frames checked are
every ``header.frame_id`` a message holds (nested headers included: a path's poses, a TFMessage's
parents; a static transform's parent need only exist) and an Odometry's ``child_frame_id``. By default every ``tf2_msgs/msg/TFMessage`` topic
counts, as Foxglove reads them; ``--tf-topic /tf --tf-topic /tf_static`` is what RViz (tf2) listens to.
Exit status 0 when every message resolves; otherwise each frame that does not, one line a frame
(topic, how many messages, the first stamp, why).
"""

from __future__ import annotations

import argparse
import math
import struct
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

TF_TYPE = "tf2_msgs/msg/TFMessage"
STATIC_TOPIC = "/tf_static"
# Types whose one frame is their header, their first field, and whose payload mcap_ros2 decodes value by
# value (an OccupancyGrid's int8 cells: ten minutes for the maps of one processed Intel log): their
# header is read from the CDR bytes instead (encapsulation, then sec, nanosec, frame_id).
HEADER_ONLY = {"nav_msgs/msg/OccupancyGrid"}


def _ns(t) -> int:
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def _planar(tr) -> tuple[float, float, float]:
    """x, y and yaw of a geometry_msgs/Transform (a planar one: z, roll and pitch are not used)."""
    q = tr.rotation
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    return tr.translation.x, tr.translation.y, yaw


def _compose(a, b):
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.atan2(math.sin(a[2] + b[2]),
                                                                                math.cos(a[2] + b[2]))


@dataclass
class _Link:
    parent: str
    stamps: np.ndarray  # ns, increasing; empty for a static link
    poses: np.ndarray  # (N, 3) x, y, yaw (unwrapped); (1, 3) for a static link


@dataclass
class TfTree:
    """The file's tf: per child frame, its parent and its pose in the parent over time."""

    links: dict[str, _Link] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)  # a child given two parents

    def _link_at(self, frame: str, t: int) -> tuple[str, tuple[float, float, float]] | str:
        """``frame``'s parent and its pose in it at ``t`` (ns), or why there is none."""
        link = self.links.get(frame)
        if link is None:
            return f"no transform names {frame!r} as its child"
        if not len(link.stamps):
            return link.parent, tuple(link.poses[0])
        if t < link.stamps[0] or t > link.stamps[-1]:
            return (f"{link.parent!r} -> {frame!r} is known from {link.stamps[0]} to {link.stamps[-1]} ns, "
                    f"not at {t} ns")
        if len(link.stamps) == 1:
            return link.parent, tuple(link.poses[0])
        pose = [float(np.interp(t, link.stamps, link.poses[:, k])) for k in range(3)]
        return link.parent, (pose[0], pose[1], math.atan2(math.sin(pose[2]), math.cos(pose[2])))

    def resolve(self, frame: str, t: int, root: str = "map") -> tuple[float, float, float] | str:
        """``frame``'s pose (x, y, yaw) in ``root`` at ``t`` (ns), or why it does not resolve."""
        pose = (0.0, 0.0, 0.0)
        seen = [frame]
        while frame != root:
            step = self._link_at(frame, t)
            if isinstance(step, str):
                return f"{' -> '.join(seen)}: {step}"
            frame, local = step
            pose = _compose(local, pose)
            if frame in seen:
                return f"a loop: {' -> '.join([*seen, frame])}"
            seen.append(frame)
        return pose


def _frames(msg, stamp: int | None = None):
    """(frame, stamp in ns) of every header in ``msg`` (nested ones too) and an Odometry's child frame."""
    header = getattr(msg, "header", None)
    if header is not None and hasattr(header, "frame_id"):
        stamp = _ns(header.stamp)
        yield header.frame_id, stamp
        if isinstance(getattr(msg, "child_frame_id", None), str) and not hasattr(msg, "transform"):
            yield msg.child_frame_id, stamp  # an Odometry's; a TransformStamped's child is what its own transform gives
    for name in getattr(msg, "__slots__", ()):
        if name == "header":
            continue
        value = getattr(msg, name)
        if isinstance(value, list) and value and hasattr(value[0], "__slots__"):
            for item in value:
                yield from _frames(item, stamp)
        elif hasattr(value, "__slots__"):
            yield from _frames(value, stamp)


def _raw_header(data: bytes) -> tuple[str, int]:
    """``header.frame_id`` and its stamp (ns) of a CDR message whose first field is a std_msgs/Header."""
    endian = "<" if data[1] & 1 else ">"
    sec, nanosec, length = struct.unpack_from(endian + "iII", data, 4)
    return data[16:16 + length - 1].decode(), sec * 1_000_000_000 + nanosec


def _messages(path: Path, decode=lambda schema, topic: True):
    """(schema name, topic, MCAP message, the decoded message or None where ``decode`` says not to)
    in log-time order."""
    factory, decoders = DecoderFactory(), {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if not decode(schema.name, channel.topic):
                yield schema.name, channel.topic, message, None
                continue
            if schema.id not in decoders:
                decoders[schema.id] = factory.decoder_for(channel.message_encoding, schema)
            yield schema.name, channel.topic, message, decoders[schema.id](message.data)


def read_tf(path: Path, tf_topics: tuple[str, ...] | None = None) -> TfTree:
    """The tf tree of ``path`` from ``tf_topics`` (None: every TFMessage topic; ``/tf_static`` is static)."""
    static: dict[str, tuple[str, tuple[float, float, float]]] = {}
    samples: dict[str, list[tuple[int, str, tuple[float, float, float]]]] = defaultdict(list)
    tree = TfTree()
    def wanted(schema: str, topic: str) -> bool:
        return schema == TF_TYPE and (tf_topics is None or topic in tf_topics)

    for _, topic, _, msg in _messages(path, wanted):
        if msg is None:
            continue
        for tr in msg.transforms:
            parent, child, pose = tr.header.frame_id, tr.child_frame_id, _planar(tr.transform)
            if topic == STATIC_TOPIC:
                static[child] = (parent, pose)  # a later static transform replaces an earlier one
            else:
                samples[child].append((_ns(tr.header.stamp), parent, pose))
    for child, (parent, pose) in static.items():
        tree.links[child] = _Link(parent, np.zeros(0, np.int64), np.array([pose]))
    for child, rows in samples.items():
        parents = {p for _, p, _ in rows}
        if child in tree.links or len(parents) > 1:
            given = sorted(parents | ({tree.links[child].parent} if child in tree.links else set()))
            tree.problems.append(f"{child!r} has more than one parent: {', '.join(map(repr, given))}")
            continue
        rows.sort(key=lambda r: r[0])
        poses = np.array([p for _, _, p in rows])
        poses[:, 2] = np.unwrap(poses[:, 2])
        tree.links[child] = _Link(rows[0][1], np.array([t for t, _, _ in rows], np.int64), poses)
    return tree


def unresolved(path: Path, tf_topics: tuple[str, ...] | None = None, root: str = "map",
               tree: TfTree | None = None) -> dict[tuple[str, str], list]:
    """Every (topic, frame) of ``path`` whose frame does not resolve to ``root`` at a message's
    stamp: [the first such stamp, why, how many messages]. Empty when a viewer places everything.
    ``tree``: the file's tf if already read (:func:`read_tf` with the same ``tf_topics``)."""
    tree = tree if tree is not None else read_tf(path, tf_topics)
    bad: dict[tuple[str, str], list] = {}
    for problem in tree.problems:
        bad[("tf", problem)] = [None, problem]
    for schema, topic, message, msg in _messages(path, lambda schema, _: schema not in HEADER_ONLY):
        timeless = schema == TF_TYPE and topic == STATIC_TOPIC  # its parents need only exist
        for frame, stamp in _frames(msg) if msg is not None else [_raw_header(message.data)]:
            if timeless:
                where = None if frame == root or frame in tree.links else f"no transform names {frame!r} as its child"
            else:
                where = tree.resolve(frame, stamp, root)
            if isinstance(where, str):
                entry = bad.setdefault((topic, frame), [stamp, where, 0])
                entry[2] += 1
    return bad


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--tf-topic", action="append", default=None,
                    help="a tf topic to read, repeated for several (default: every TFMessage topic; "
                         "RViz: --tf-topic /tf --tf-topic /tf_static)")
    ap.add_argument("--root", default="map", help="the frame everything must resolve to (default: map)")
    args = ap.parse_args(argv)
    status = 0
    for path in args.files:
        topics = tuple(args.tf_topic) if args.tf_topic else None
        tree = read_tf(path, topics)
        bad = unresolved(path, topics, args.root, tree)
        verdict = f"every message resolves to {args.root}" if not bad else f"{len(bad)} frames do not resolve"
        print(f"{path}: {len(tree.links)} frames with a parent; {verdict}")
        for (topic, frame), entry in sorted(bad.items()):
            if topic == "tf":
                print(f"  tf: {entry[1]}")
            else:
                print(f"  {topic}: {frame!r} in {entry[2]} messages, first at {entry[0]} ns: {entry[1]}")
        status |= bool(bad)
    return status


if __name__ == "__main__":
    sys.exit(main())
