"""SE(2) helpers shared by the simulator, the estimator and the metrics.

Poses are ``(x, y, yaw)`` in metres and radians; yaw is counter-clockwise
positive (REP-103). Arrays of poses have shape ``(N, 3)``.
"""

from __future__ import annotations

import numpy as np


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def rot2(yaw: np.ndarray | float) -> np.ndarray:
    """2x2 rotation matrix (eq. 14); for an array of N yaws, shape (N, 2, 2)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def yaw_to_quaternion(yaw: np.ndarray | float) -> np.ndarray:
    """Quaternion ``(qx, qy, qz, qw)`` of a rotation by ``yaw`` about z; shape (..., 4)."""
    yaw = np.asarray(yaw, dtype=float)
    out = np.zeros((*yaw.shape, 4))
    out[..., 2] = np.sin(yaw / 2.0)
    out[..., 3] = np.cos(yaw / 2.0)
    return out


def quaternion_to_yaw(qx, qy, qz, qw) -> np.ndarray:
    """Yaw (rad) of a quaternion, assuming a rotation about z (planar robot)."""
    return np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose composition ``a ⊕ b`` (b expressed in a's frame); broadcasts over (..., 3)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    # filled in place rather than np.stack-ed: these run a few thousand times a second
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    out[..., 1] = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    out[..., 2] = wrap_angle(a[..., 2] + b[..., 2])
    return out


def inverse(a: np.ndarray) -> np.ndarray:
    """Inverse pose ``⊖a``; broadcasts over (..., 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(a.shape)
    out[..., 0] = -c * a[..., 0] - s * a[..., 1]
    out[..., 1] = s * a[..., 0] - c * a[..., 1]
    out[..., 2] = wrap_angle(-a[..., 2])
    return out


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative pose ``⊖a ⊕ b``: b expressed in a's frame."""
    return compose(inverse(a), b)


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (N, 2) from a frame at ``pose`` (3,) into its parent frame.

    ``pose`` may also be (N, 3), one pose per point.
    """
    pose = np.asarray(pose, dtype=float)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    out = np.empty((len(points), 2))
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + pose[..., 0]
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + pose[..., 1]
    return out


def interpolate_poses(t_query: np.ndarray, t: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Linear interpolation of poses (N, 3) stamped ``t`` (sorted) at ``t_query``.

    Yaw is unwrapped before interpolating so a pass through ±pi is handled;
    queries outside ``[t[0], t[-1]]`` are clamped to the ends.
    """
    yaw = np.unwrap(poses[:, 2])
    out = np.empty((*np.shape(t_query), 3))
    out[..., 0] = np.interp(t_query, t, poses[:, 0])
    out[..., 1] = np.interp(t_query, t, poses[:, 1])
    out[..., 2] = wrap_angle(np.interp(t_query, t, yaw))
    return out
