"""Feature lengths in the map each method built (the paper's Tables 2 and 3).

A feature is measured from the points each method kept for its map: every
static point the method placed in its map (``/<method>/points/static`` in
``processed.mcap``, already placed with that method's poses) is also placed
with the ground-truth pose of its sweep; the points that land within
``end_radius`` of a feature's end in the true world are "the points that saw
that end". A feature's measured length is the distance between the means of its
two ends' points as the method placed them, corrected by the same distance with
the ground-truth placement (which removes the few-centimetre offset of
averaging points near a corner, the same for every method):

    measured = true + |m_b(est) − m_a(est)| − |m_b(gt) − m_a(gt)|

so a method with perfect poses measures every feature at its true length, and
a drifting or sliding one stretches or shrinks the map between the ends.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry import interpolate_poses, inverse, transform_points
from ..io.mcap_log import LogReader
from ..io.messages import odometry_pose_twist, pointcloud_columns, stamp_ns


def feature_lengths(out_dir: Path, methods: list[str], features: list[dict], gt_ns: np.ndarray, gt: np.ndarray,
                    radius: float) -> dict[str, list[dict]]:
    """Per method and feature, the measured length from the points that saw its ends (module docstring).

    ``gt_ns`` (N,) and ``gt`` (N, 3): ground-truth stamps and poses; ``radius`` (m) picks the
    points near each end. Returns, per method, one row per feature with ``measured_m`` None
    where an end was not seen.
    """
    ends = np.array([[f["a"], f["b"]] for f in features], dtype=float).reshape(-1, 2)  # (2F, 2): a0, b0, a1, ...
    proc = out_dir / "processed.mcap"
    if not proc.is_file():
        return {}
    reader = LogReader(proc)
    poses: dict[str, dict[int, np.ndarray]] = {m: {} for m in methods}
    sums = {m: {"est": np.zeros((len(ends), 2)), "gt": np.zeros((len(ends), 2)), "n": np.zeros(len(ends))} for m in methods}
    topics = [f"/{m}/odom" for m in methods] + [f"/{m}/points/static" for m in methods]
    gt_t = gt_ns * 1e-9
    for msg in reader.messages(topics):
        method = msg.topic.split("/")[1]
        ns = stamp_ns(msg.msg.header.stamp)
        if msg.topic.endswith("/odom"):
            poses[method][ns] = odometry_pose_twist(msg.msg)[0]
            continue
        pose = poses[method].get(ns)
        if pose is None:
            continue
        cols = pointcloud_columns(msg.msg, ("x", "y"))
        est = np.column_stack([cols["x"], cols["y"]])
        if len(est) == 0:
            continue
        base = transform_points(inverse(pose), est)
        true_pose = interpolate_poses(np.array(ns * 1e-9), gt_t, gt)
        in_world = transform_points(true_pose, base)
        d = np.linalg.norm(in_world[:, None, :] - ends[None, :, :], axis=2)  # (N, 2F)
        near = d < radius
        s = sums[method]
        s["n"] += near.sum(axis=0)
        s["est"] += near.T.astype(float) @ est
        s["gt"] += near.T.astype(float) @ in_world
        poses[method].pop(ns, None)
    out: dict[str, list[dict]] = {}
    for m in methods:
        s = sums[m]
        rows = []
        for i, f in enumerate(features):
            a, b = 2 * i, 2 * i + 1
            true = float(np.hypot(*(np.subtract(f["b"], f["a"]))))
            if s["n"][a] == 0 or s["n"][b] == 0:
                measured = None
            else:
                mean_est = s["est"][[a, b]] / s["n"][[a, b], None]
                mean_gt = s["gt"][[a, b]] / s["n"][[a, b], None]
                measured = true + float(np.linalg.norm(mean_est[1] - mean_est[0]) - np.linalg.norm(mean_gt[1] - mean_gt[0]))
            rows.append({"id": f.get("id", i + 1), "name": f.get("name", ""), "true_m": true, "measured_m": measured,
                         "points_a": int(s["n"][a]), "points_b": int(s["n"][b])})
        out[m] = rows
    return out
