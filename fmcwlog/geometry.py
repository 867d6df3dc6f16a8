"""SE(2) helpers shared by the simulator, the estimator and the metrics.

Poses are ``(x, y, yaw)`` in metres and radians; yaw is counter-clockwise
positive (REP-103). Arrays of poses have shape ``(N, 3)``.

One pose (a float64 array of shape (3,)) takes a scalar path: the same float operations in the
same order on Python floats, with :mod:`math`'s sin and cos, which are the C library's, as numpy's
float64 ``sin``/``cos`` are on a machine without AVX-512 (numpy uses SVML there; this one, like
most, has AVX2 only: no difference over 3.2 million angles, ``tests/unit/core/test_geometry.py``). Python's
float ``%`` and numpy's ``remainder`` are the same ``fmod``-and-adjust, so the scalar ``wrap_angle``
is numpy's too. The results are bit-for-bit the array path's; a pose spends ~1 µs instead of
~5 µs, and the front end composes, inverts and wraps single poses tens of times a sweep (on the
120 s corridor log, 23 000 compositions and 68 000 wraps: 1.4 s of a 28 s run's profile).
"""

from __future__ import annotations

import math

import numpy as np

_F64 = np.dtype(np.float64)
_PI = math.pi
_TWO_PI = 2.0 * math.pi


def _is_pose(a: object) -> bool:
    """Whether ``a`` is one pose, a float64 array of shape (3,): the scalar path's input."""
    return type(a) is np.ndarray and a.shape == (3,) and a.dtype is _F64


def _wrap(a: float) -> float:
    """:func:`wrap_angle` of a Python float: the same operations (float ``%`` is numpy's remainder)."""
    return (a + _PI) % _TWO_PI - _PI


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to [-pi, pi)."""
    if type(a) is float or type(a) is np.float64:
        return np.float64(_wrap(float(a)))  # what numpy gives for a scalar: an np.float64
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def rot2(yaw: np.ndarray | float) -> np.ndarray:
    """2x2 rotation matrix (eq. 14); for an array of N yaws, shape (N, 2, 2)."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.empty((*np.shape(c), 2, 2))  # filled in place: four nested np.stack calls cost more than the trig
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    return out


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
    if (type(a) is np.ndarray and a.shape == (3,) and a.dtype is _F64  # _is_pose, inline: a hot path
            and type(b) is np.ndarray and b.shape == (3,) and b.dtype is _F64):
        ax, ay, ath = a.tolist()
        if math.isfinite(ath):  # math.cos raises on ±inf where numpy gives NaN
            bx, by, bth = b.tolist()
            c, s = math.cos(ath), math.sin(ath)
            return np.array([ax + c * bx - s * by, ay + s * bx + c * by, (ath + bth + _PI) % _TWO_PI - _PI])
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
    if _is_pose(a):
        ax, ay, ath = a.tolist()
        if math.isfinite(ath):
            c, s = math.cos(ath), math.sin(ath)
            return np.array([-c * ax - s * ay, s * ax - c * ay, _wrap(-ath)])
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(a.shape)
    out[..., 0] = -c * a[..., 0] - s * a[..., 1]
    out[..., 1] = s * a[..., 0] - c * a[..., 1]
    out[..., 2] = wrap_angle(-a[..., 2])
    return out


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative pose ``⊖a ⊕ b``: b expressed in a's frame."""
    found = between_floats(a, b)
    if found is not None:
        return np.array(found)
    return compose(inverse(a), b)


def between_floats(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float] | None:
    """:func:`between` of two poses (float64 arrays of shape (3,), ``a``'s yaw finite) as three
    Python floats, bit for bit the array's; None for any other input (then call :func:`between`)."""
    if (type(a) is np.ndarray and a.shape == (3,) and a.dtype is _F64  # _is_pose, inline: a hot path
            and type(b) is np.ndarray and b.shape == (3,) and b.dtype is _F64):
        ax, ay, ath = a.tolist()
        if math.isfinite(ath):  # inverse(a) as floats, then composed with b: the same operations (_wrap inline)
            c, s = math.cos(ath), math.sin(ath)
            ix, iy, ith = -c * ax - s * ay, s * ax - c * ay, (-ath + _PI) % _TWO_PI - _PI
            bx, by, bth = b.tolist()
            c, s = math.cos(ith), math.sin(ith)
            return ix + c * bx - s * by, iy + s * bx + c * by, (ith + bth + _PI) % _TWO_PI - _PI
    return None


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (N, 2) from a frame at ``pose`` (3,) into its parent frame.

    ``pose`` may also be (N, 3), one pose per point.
    """
    if _is_pose(pose) and type(points) is np.ndarray and points.dtype is _F64:  # (a Python float is weak: float32
        # points would be multiplied in float32, where numpy's float64 scalar cos makes it float64)
        x, y, yaw = pose.tolist()
        if math.isfinite(yaw):
            return rotate_translate(math.cos(yaw), math.sin(yaw), x, y, points)
    pose = np.asarray(pose, dtype=float)
    return rotate_translate(np.cos(pose[..., 2]), np.sin(pose[..., 2]), pose[..., 0], pose[..., 1], points)


def rotate_translate(c, s, tx, ty, points: np.ndarray) -> np.ndarray:
    """``R p + t`` of points (N, 2) given ``cos``/``sin`` of the yaw and the translation, each a
    float or one per point (N,): :func:`transform_points`' arithmetic, for callers that have the
    pose as columns (the deskew)."""
    out = np.empty((len(points), 2))
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + tx
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + ty
    return out


def interpolate_poses(t_query: np.ndarray, t: np.ndarray, poses: np.ndarray,
                      unwrapped_yaw: np.ndarray | None = None) -> np.ndarray:
    """Linear interpolation of poses (N, 3) stamped ``t`` (sorted) at ``t_query``.

    Yaw is unwrapped before interpolating so a pass through ±pi is handled;
    queries outside ``[t[0], t[-1]]`` are clamped to the ends. ``unwrapped_yaw``: ``np.unwrap`` of
    ``poses[:, 2]`` (:func:`unwrapped_yaw`), where the caller keeps it across queries of one track.
    """
    yaw = _unwrap(poses[:, 2]) if unwrapped_yaw is None else unwrapped_yaw
    out = np.empty((*np.shape(t_query), 3))
    out[..., 0] = np.interp(t_query, t, poses[:, 0])
    out[..., 1] = np.interp(t_query, t, poses[:, 1])
    out[..., 2] = wrap_angle(np.interp(t_query, t, yaw))
    return out


def unwrapped_yaw(poses: np.ndarray) -> np.ndarray:
    """The yaw of poses (N, 3) as :func:`interpolate_poses` interpolates it: ``np.unwrap`` of it."""
    return _unwrap(poses[:, 2])


def _unwrap(yaw: np.ndarray) -> np.ndarray:
    """``np.unwrap(yaw)`` of a 1-D float64 array. Where no step reaches π (the motion prior's few
    seconds of 50 Hz poses, nearly always) every correction is 0 and np.unwrap returns
    ``yaw[1:] + cumsum(zeros)``: that, without its dozen other array operations (the runner reads
    the prior three times a sweep)."""
    step = yaw[1:] - yaw[:-1]  # np.diff
    if yaw.dtype is not _F64 or yaw.ndim != 1 or not bool((np.abs(step) < np.pi).all()):
        return np.unwrap(yaw)
    out = yaw.copy()
    out[1:] += 0.0  # the zero corrections' sum, as np.unwrap adds it (-0.0 becomes 0.0)
    return out
