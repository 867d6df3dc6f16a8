"""ROS 2 messages of the log format as Python dicts (for writing) and numpy arrays (when read).

``sensor_msgs/PointCloud2`` fields are located by name and offset, never by an
assumed layout, as the log format requires (docs/log-format.md); ``nav_msgs/Odometry`` carries a planar pose in
its ``header.frame_id`` and a twist in its ``child_frame_id``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..geometry import quaternion_to_yaw, yaw_to_quaternion

# PointField datatype codes (sensor_msgs/PointField) -> numpy dtypes, little-endian.
POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}
POINTFIELD_NUMPY = {code: np.dtype(name) for code, name in POINTFIELD_DTYPES.items()}  # made once, not per field read
FLOAT32 = 7


def stamp(ns: int) -> dict[str, int]:
    """``builtin_interfaces/Time`` from integer nanoseconds since the epoch."""
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def stamp_ns(t: Any) -> int:
    """Integer nanoseconds from a decoded ``builtin_interfaces/Time``."""
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


POINT_FIELDS = ("x", "y", "z", "intensity", "velocity", "t")


def pointcloud_message(stamp_ns_: int, frame_id: str, columns: dict[str, np.ndarray]) -> dict:
    """A ``sensor_msgs/PointCloud2`` dict with one FLOAT32 field per column, packed in order."""
    names = list(columns)
    n = len(next(iter(columns.values()))) if names else 0
    packed = np.empty((n, len(names)), dtype="<f4")
    for i, name in enumerate(names):
        packed[:, i] = columns[name]
    step = 4 * len(names)
    return {
        "header": {"stamp": stamp(stamp_ns_), "frame_id": frame_id},
        "height": 1,
        "width": n,
        "fields": [
            {"name": name, "offset": 4 * i, "datatype": FLOAT32, "count": 1}
            for i, name in enumerate(names)
        ],
        "is_bigendian": False,
        "point_step": step,
        "row_step": step * n,
        "data": packed.tobytes(),
        "is_dense": True,
    }


def pointcloud_columns(msg: Any, names: Iterable[str] = POINT_FIELDS) -> dict[str, np.ndarray]:
    """Columns of a decoded PointCloud2 as float64 arrays, located by field name and offset.

    Extra fields are ignored; a missing requested field raises ``KeyError``; a big-endian cloud,
    data shorter than ``width × height × point_step`` or a field of unknown datatype raises
    ``ValueError``. Units are the message's (the log format: m, m/s, s after ``header.stamp``).
    """
    if msg.is_bigendian:
        raise ValueError("big-endian PointCloud2 is not supported")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = bytes(msg.data)
    if len(data) < n * step:
        raise ValueError(f"PointCloud2 data holds {len(data)} bytes, expected {n * step}")
    by_name = {f.name: f for f in msg.fields}
    out = {}
    for name in names:
        f = by_name[name]
        dt = POINTFIELD_NUMPY.get(f.datatype)
        if dt is None:
            raise ValueError(f"field {name!r} has unknown datatype {f.datatype}")
        if n == 0:
            out[name] = np.zeros(0)
            continue
        col = np.ndarray((n,), dtype=dt, buffer=data, offset=int(f.offset), strides=(step,))
        out[name] = col.astype(np.float64)
    return out


_PLANAR = np.array([0, 1, 5, 6, 7, 11, 30, 31, 35])  # (x, y, yaw) x (x, y, yaw) in a row-major 6x6


def planar_covariance(cov3: np.ndarray | None) -> list[float]:
    """A 6x6 row-major ROS covariance (x, y, z, roll, pitch, yaw) from a planar 3x3 one over
    (x, y, yaw); z, roll and pitch are fixed by the plane (0). All zeros when ``cov3`` is None
    (unknown), as ROS messages leave it."""
    if cov3 is None:
        return [0.0] * 36
    out = np.zeros(36)
    out[_PLANAR] = np.asarray(cov3, dtype=float).reshape(9)
    return out.tolist()


def pose7(pose: np.ndarray) -> tuple[float, float, float, float, float, float, float]:
    """The 7 numbers of a ``geometry_msgs/Pose`` (position, orientation) of a planar pose ``(x, y, yaw)``."""
    q = yaw_to_quaternion(pose[2])
    return float(pose[0]), float(pose[1]), 0.0, float(q[0]), float(q[1]), float(q[2]), float(q[3])


def pose7_array(poses: np.ndarray) -> np.ndarray:
    """:func:`pose7` of each of ``poses`` (N, 3) at once: (N, 7) float64, the same numbers."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    out = np.zeros((len(poses), 7))
    out[:, :2] = poses[:, :2]
    out[:, 3:] = yaw_to_quaternion(poses[:, 2])
    return out


def pose_dict(pose: np.ndarray) -> dict:
    """``geometry_msgs/Pose`` of a planar pose ``(x, y, yaw)``."""
    x, y, z, qx, qy, qz, qw = pose7(pose)
    return {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def odometry_message(
    stamp_ns_: int, frame_id: str, child_frame_id: str, pose: np.ndarray, twist: np.ndarray,
    pose_covariance: np.ndarray | None = None, twist_covariance: np.ndarray | None = None,
) -> dict:
    """``nav_msgs/Odometry``: ``pose`` (x, y, yaw) in ``frame_id``, ``twist`` (vx, vy, wz) in ``child_frame_id``;
    covariances (3, 3) over (x, y, yaw) and (vx, vy, wz), zeros where not given."""
    return {
        "header": {"stamp": stamp(stamp_ns_), "frame_id": frame_id},
        "child_frame_id": child_frame_id,
        "pose": {"pose": pose_dict(pose), "covariance": planar_covariance(pose_covariance)},
        "twist": {
            "twist": {
                "linear": {"x": float(twist[0]), "y": float(twist[1]), "z": 0.0},
                "angular": {"x": 0.0, "y": 0.0, "z": float(twist[2])},
            },
            "covariance": planar_covariance(twist_covariance),
        },
    }


def transform_dict(stamp_ns_: int, parent: str, child: str, pose: np.ndarray, upside_down: bool = False) -> dict:
    """``geometry_msgs/TransformStamped``: frame ``child`` at ``pose`` (x, y, yaw) in ``parent``;
    ``upside_down``: rolled by π about its x axis as well, ``Rz(yaw) Rx(π)`` (the quaternion
    ``(cos(yaw/2), sin(yaw/2), 0, 0)`` as x, y, z, w)."""
    p = pose_dict(pose)
    if upside_down:
        half = 0.5 * float(pose[2])
        p["orientation"] = {"x": math.cos(half), "y": math.sin(half), "z": 0.0, "w": 0.0}
    return {"header": {"stamp": stamp(stamp_ns_), "frame_id": parent}, "child_frame_id": child,
            "transform": {"translation": p["position"], "rotation": p["orientation"]}}


def tf_message(transforms: list[dict]) -> dict:
    """``tf2_msgs/TFMessage`` of :func:`transform_dict` entries."""
    return {"transforms": transforms}


def path_message(stamp_ns_: int, frame_id: str, stamps_ns: list[int], poses: list[np.ndarray]) -> dict:
    """``nav_msgs/Path``: the poses (x, y, yaw) at their stamps, in ``frame_id``."""
    return {"header": {"stamp": stamp(stamp_ns_), "frame_id": frame_id},
            "poses": [{"header": {"stamp": stamp(ns), "frame_id": frame_id}, "pose": pose_dict(p)}
                      for ns, p in zip(stamps_ns, poses)]}


def occupancy_grid_message(stamp_ns_: int, frame_id: str, resolution: float, width: int, height: int,
                           origin_xy: np.ndarray, data: np.ndarray) -> dict:
    """``nav_msgs/OccupancyGrid``: ``data`` (H·W,) int8 row-major from the cell at ``origin_xy`` (m)."""
    return {
        "header": {"stamp": stamp(stamp_ns_), "frame_id": frame_id},
        "info": {
            "map_load_time": stamp(stamp_ns_),
            "resolution": float(resolution),
            "width": int(width),
            "height": int(height),
            "origin": {"position": {"x": float(origin_xy[0]), "y": float(origin_xy[1]), "z": 0.0},
                       "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        },
        "data": np.asarray(data, dtype=np.int8),  # written as raw bytes (LogWriter)
    }


def odometry_pose_twist(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y, yaw)`` and ``(vx, vy, wz)`` of a decoded ``nav_msgs/Odometry``."""
    p = msg.pose.pose.position
    q = msg.pose.pose.orientation
    tw = msg.twist.twist
    pose = np.array([p.x, p.y, float(quaternion_to_yaw(q.x, q.y, q.z, q.w))])
    return pose, np.array([tw.linear.x, tw.linear.y, tw.angular.z])


