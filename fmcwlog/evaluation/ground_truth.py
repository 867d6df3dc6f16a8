"""The only readers of ground truth: ``/ground_truth/odom``, ``/ground_truth/point_labels`` and
``fmcwlog.world`` (the log format, docs/log-format.md). Evaluation imports this module; estimation never may
(``tests/test_layers.py`` walks the imports to make sure).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReportError
from ..io.logs import Log
from ..io.messages import odometry_pose_twist, stamp_ns
from ..io.topics import GT_LABELS_TOPIC, GT_ODOM_TOPIC, WORLD_KEY


def read_ground_truth(reader: Log, topic: str = GT_ODOM_TOPIC) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth stamps (ns) and poses (N, 3) of ``base_link`` in ``map``.

    A pose that is not finite, an orientation that is no rotation (a zero quaternion) or a stamp
    that does not increase raises :class:`ReportError` naming the log and the message: scores
    against a damaged truth would be wrong.
    """
    stamps: list[int] = []
    poses: list[np.ndarray] = []
    for m in reader.messages([topic]):
        pose, _ = odometry_pose_twist(m.msg)
        ns = stamp_ns(m.msg.header.stamp)
        q = m.msg.pose.pose.orientation
        problem = ("its pose is not finite" if not np.isfinite(pose).all()
                   else "its orientation is a zero quaternion" if not math.hypot(q.x, q.y, q.z, q.w) > 1e-6
                   else f"its stamp does not increase (after {_seconds(stamps[-1])} s)" if stamps and ns <= stamps[-1]
                   else None)
        if problem:
            raise ReportError(f"{reader.path}: {topic} message {len(stamps) + 1} at {_seconds(ns)} s: {problem}; "
                              "the ground truth is damaged")
        stamps.append(ns)
        poses.append(pose)
    return np.asarray(stamps, dtype=np.int64), np.asarray(poses).reshape(-1, 3)


def _seconds(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def read_point_labels(reader: Log, topic: str = GT_LABELS_TOPIC) -> dict[int, np.ndarray]:
    """Per-sweep moving labels (uint8, 1 where the point of the same index hit a mover) keyed by
    sweep stamp (ns); an empty dict where the log has no ``topic``."""
    return {stamp_ns(m.msg.header.stamp): np.frombuffer(bytes(m.msg.moving), np.uint8)
            for m in reader.messages([topic])}


@dataclass
class WorldTruth:
    """``fmcwlog.world``: labelled features (``{id, name, a, b}`` in ``map`` m) and walls (M, 4)."""

    features: list[dict] = field(default_factory=list)
    walls: np.ndarray | None = None


def read_world(reader: Log) -> WorldTruth:
    """The log's ``fmcwlog.world`` record (an empty truth if it has none).

    A record that breaks the log format (a key missing, JSON that does not parse, a feature
    without its id, name or two finite ends, walls that are not ``[x1, y1, x2, y2]``) raises
    :class:`ReportError` naming the log and the entry: scoring maps against a half-read
    truth would be worse than no score.
    """
    world = reader.metadata.get(WORLD_KEY)
    if not world:
        return WorldTruth()
    where = f"{reader.path}: {WORLD_KEY}"
    missing = [k for k in ("features", "walls") if k not in world]
    if missing:
        raise ReportError(f"{where} has no {' or '.join(repr(k) for k in missing)} (docs/log-format.md: features and walls)")
    features = [_feature(f, f"{where} features[{i}]") for i, f in enumerate(_json_list(world["features"], where, "features"))]
    if len({f["id"] for f in features}) != len(features):
        raise ReportError(f"{where}: feature ids repeat")
    walls = _finite(_json_list(world["walls"], where, "walls"), (-1, 4), f"{where} walls")
    return WorldTruth(features, walls)


def _json_list(text: str, where: str, key: str) -> list:
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        raise ReportError(f"{where}: {key!r} is not JSON") from None
    if not isinstance(value, list):
        raise ReportError(f"{where}: {key!r} is not a JSON list")
    return value


def _finite(value: object, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ReportError(f"{where}: not numbers") from None
    if arr.size == 0 and shape[0] == -1:
        arr = arr.reshape(0, *shape[1:])
    if arr.ndim != len(shape) or any(s not in (-1, n) for s, n in zip(shape, arr.shape)):
        raise ReportError(f"{where}: shape {arr.shape}, expected {' x '.join('N' if s == -1 else str(s) for s in shape)}")
    if not np.isfinite(arr).all():
        raise ReportError(f"{where}: a value is not finite")
    return arr


def _feature(f: object, where: str) -> dict:
    if not isinstance(f, dict) or not {"id", "name", "a", "b"} <= set(f):
        raise ReportError(f"{where}: needs id, name, a and b")
    if not isinstance(f["id"], int) or isinstance(f["id"], bool) or not isinstance(f["name"], str):
        raise ReportError(f"{where}: id must be a whole number and name a string")
    a, b = (_finite(f[k], (2,), f"{where}.{k}") for k in ("a", "b"))
    if not np.hypot(*(b - a)) > 0:  # the true length is |b - a|: errors relative to it need one
        raise ReportError(f"{where}: a and b are the same point (a feature's length must be positive)")
    return {**f, "a": a.tolist(), "b": b.tolist()}
