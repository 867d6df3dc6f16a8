"""The only readers of ground truth: ``/ground_truth/odom``, ``/ground_truth/point_labels`` and
``fmcwlog.world`` (LOG_FORMAT.md). Evaluation imports this module; estimation never may
(``tests/test_layers.py`` walks the imports to make sure).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from ..io.mcap_log import LogReader
from ..io.messages import odometry_pose_twist, stamp_ns
from ..io.topics import GT_LABELS_TOPIC, GT_ODOM_TOPIC, WORLD_KEY


def read_ground_truth(reader: LogReader, topic: str = GT_ODOM_TOPIC) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth stamps (ns) and poses (N, 3) of ``base_link`` in ``map``."""
    stamps, poses = [], []
    for m in reader.messages([topic]):
        pose, _ = odometry_pose_twist(m.msg)
        stamps.append(stamp_ns(m.msg.header.stamp))
        poses.append(pose)
    return np.asarray(stamps, dtype=np.int64), np.asarray(poses).reshape(-1, 3)


def read_point_labels(reader: LogReader, topic: str = GT_LABELS_TOPIC) -> dict[int, np.ndarray]:
    """Per-sweep moving labels (uint8) keyed by sweep stamp (ns)."""
    return {stamp_ns(m.msg.header.stamp): np.frombuffer(bytes(m.msg.moving), np.uint8)
            for m in reader.messages([topic])}


@dataclass
class WorldTruth:
    """``fmcwlog.world``: labelled features (``{id, name, a, b}`` in ``map`` m) and walls (M, 4)."""

    features: list[dict] = field(default_factory=list)
    walls: np.ndarray | None = None


def read_world(reader: LogReader) -> WorldTruth:
    world = reader.metadata.get(WORLD_KEY)
    if not world:
        return WorldTruth()
    features = json.loads(world["features"]) if "features" in world else []
    walls = np.asarray(json.loads(world["walls"]), dtype=float).reshape(-1, 4) if "walls" in world else None
    return WorldTruth(features, walls)
