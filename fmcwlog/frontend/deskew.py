"""Motion compensation (de-skewing) of one sweep under a constant body twist.

Frames and units: points ``xy`` (N, 2) in the lidar frame *at their own
capture time* ``t`` (N,) (s after the sweep stamp); the result is expressed in
the lidar frame at ``t_ref``. The base_link twist ``(v, ω)`` (m/s, rad/s;
``v_y`` defaults to 0, the non-holonomic rear axle) is held constant over the
sweep; ``mount = (lidar_x, lidar_y, lidar_yaw)`` places the lidar in base_link.
Nothing is checked: a NaN gives NaN, and ``xy`` and ``t`` of different lengths raise
numpy's ``ValueError``.

Departure from the paper: Wang et al. match each sweep as it was seen. A 270° sweep at
10 Hz lasts 75 ms, and at 1.5 m/s the robot moves 11 cm during it, so here every point is
moved to the reference time before matching or mapping (the physics notes, docs/physics.md).
Without it the improved method's ATE on the 30 s crowd sample log is 2.7 cm against 0.5 cm
(``fmcwlog process sample_logs/crowd_30s.mcap -o OUT --method improved --set frontend.deskew=false``;
``tests/integration/test_ablation.py``).

Speed, with results bit-for-bit those of the plain path (``tests/unit/frontend/test_deskew.py``
checks :func:`se2_exp` against scipy's matrix exponential, and the fast paths against the plain
one): :func:`se2_exp` of one ``dt`` (the front end's predictions, three a sweep) runs on Python
floats; over many it evaluates ``np.sinc``'s own operations in place and fills its output rather
than stacking it; :func:`deskew` chains the exponential, the two compositions with the mount and the
transform column by column instead of through three (N, 3) pose arrays: 174 µs a sweep of 1,079
points against 231 µs through the arrays, and one ``dt`` 2.1 against 28.7 µs (the 120 s corridor
log, CPU time, best of 7 alternating runs). """

from __future__ import annotations

import math
from typing import cast

import numpy as np

from ..geometry import _is_pose, _wrap, compose, inverse, rotate_translate, transform_points, wrap_angle
from ..kernels import compiled
from ..kernels.voxel import voxel_centroids_numpy, voxel_downsample_numpy

_EPS = float(np.finfo(np.float64).eps)  # np.sinc's stand-in for an argument of 0


def _floats(*values: object) -> bool:
    """Whether every value is a Python or numpy float (twists given as numbers, not arrays)."""
    for q in values:  # a loop, not all() over a generator: called a few times a sweep
        if type(q) is not float and type(q) is not np.float64:
            return False
    return True


def _by_columns(dt: np.ndarray, mount: np.ndarray, *twist: object) -> bool:
    """Whether the lidar's motion can take the column path: times (N,), one finite mount (3,), a
    twist of floats; anything else takes the plain formulas."""
    return dt.ndim == 1 and _is_pose(mount) and math.isfinite(mount[2]) and _floats(*twist)


def _sinc(x: np.ndarray) -> np.ndarray:
    """``np.sinc(x)`` of a float64 array that may be overwritten: its operations
    (``y = π x``, ``y = eps`` where ``y == 0``, ``sin(y) / y``), two temporaries fewer."""
    y = np.multiply(x, np.pi, out=x)
    y[y == 0.0] = _EPS
    out = np.sin(y)
    out /= y
    return out


def sinc_of_float(x: float) -> float:
    """``np.sinc`` of one float: the same operations on Python floats (``math.sin`` is numpy's
    float64 ``sin`` here: :mod:`fmcwlog.geometry`)."""
    y = math.pi * x
    if y == 0.0:
        y = _EPS
    return math.sin(y) / y


def se2_exp(
    vx: float | np.ndarray, vy: float | np.ndarray, omega: float | np.ndarray, dt: np.ndarray
) -> np.ndarray:
    """Pose (..., 3) (m, m, rad) reached after ``dt`` (s) under a constant body twist
    ``(vx, vy)`` (m/s, the body's own axes) and ``omega`` (rad/s), from the identity.

    Exact SE(2) exponential: with ``θ = ω dt``,
    ``[x, y] = V(θ) [vx, vy] dt``, ``V = [[sinθ/θ, -(1-cosθ)/θ], [(1-cosθ)/θ, sinθ/θ]]``.
    Written with ``np.sinc`` so ``ω → 0`` is exact: ``(1-cosθ)/θ = θ/2 · sinc²(θ/2)``.
    """
    dt = np.asarray(dt, dtype=float)
    if not _floats(vx, vy, omega):  # arrays of twists: the formula as it stands
        th = omega * dt
        a = np.sinc(th / np.pi)
        b = 0.5 * th * np.sinc(th / (2.0 * np.pi)) ** 2
        return np.stack(np.broadcast_arrays((a * vx - b * vy) * dt, (b * vx + a * vy) * dt, th), -1)
    if dt.ndim == 0:
        return np.array(_se2_exp_scalar(float(vx), float(vy), float(omega), float(dt)))
    x, y, th = _se2_exp_columns(float(vx), float(vy), float(omega), dt)  # (the same values)
    out = np.empty((*np.broadcast_shapes(np.shape(x), np.shape(y), np.shape(th)), 3))
    out[..., 0], out[..., 1], out[..., 2] = x, y, th
    return out


def _se2_exp_scalar(vx: float, vy: float, omega: float, dt: float) -> tuple[float, float, float]:
    """:func:`se2_exp` of one ``dt``: the array formula's operations on floats. Numpy squares a
    float64 *scalar* with ``pow`` (an array with ``x * x``, which differs in the last bit for
    ~0.1 % of values), so this squares with ``**`` as numpy does for the 0-d ``dt`` it replaces."""
    th = omega * dt
    a = sinc_of_float(th / np.pi)
    b = 0.5 * th * sinc_of_float(th / (2.0 * np.pi)) ** 2
    return (a * vx - b * vy) * dt, (b * vx + a * vy) * dt, th


def advance(pose: np.ndarray, v: float, omega: float, dt: float) -> np.ndarray:
    """``compose(pose, se2_exp(v, 0.0, omega, np.array(dt)))``: the pose (3,; m, m, rad) reached from
    ``pose`` after ``dt`` (s) under the base_link twist ``(v, ω)`` (m/s, rad/s), a constant-velocity
    prediction. For one float64 pose with a finite yaw and a float twist and ``dt``, those calls'
    operations on Python floats in one call (the same bits); else those calls themselves."""
    if (type(pose) is np.ndarray and pose.shape == (3,) and pose.dtype == np.float64
            and type(v) in _FLOAT and type(omega) in _FLOAT and type(dt) in _FLOAT):
        x, y, yaw = pose.tolist()
        if math.isfinite(yaw):  # compose's float path: math.cos raises on ±inf where numpy gives NaN
            bx, by, bth = _se2_exp_scalar(float(v), 0.0, float(omega), float(dt))
            c, s = math.cos(yaw), math.sin(yaw)
            return np.array([x + c * bx - s * by, y + s * bx + c * by, _wrap(yaw + bth)])
    return compose(pose, se2_exp(v, 0.0, omega, np.array(dt)))


_FLOAT = (float, np.float64)


def _se2_exp_columns(vx: float, vy: float, omega: float, dt: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x``, ``y``, ``θ`` of :func:`se2_exp` over an array ``dt`` (ndim ≥ 1) and a float twist:
    its formula, ``np.sinc``'s operations done in place (``a ** 2`` of an array is ``a * a``)."""
    th = omega * dt
    a = _sinc(th / np.pi)  # sinθ/θ
    s = _sinc(th / (2.0 * np.pi))
    b = 0.5 * th
    b *= s * s  # (1-cosθ)/θ
    x = a * vx
    x -= b * vy
    x *= dt
    y = b * vx
    y += a * vy
    y *= dt
    return x, y, th


def lidar_motion(
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray | tuple,
    t_ref: float = 0.0,
    v_y: float = 0.0,
) -> np.ndarray:
    """Poses (N, 3) (m, m, rad) of the lidar at times ``t`` (N,, s) expressed in the lidar
    frame at ``t_ref`` (s).

    ``L⁻¹ ⊕ exp((t - t_ref) ξ) ⊕ L`` with ``L`` the mounting (lidar in base_link: m, m, rad)
    and ``ξ = (v, v_y, ω)`` the base_link twist (m/s, m/s, rad/s).
    """
    mount = np.asarray(mount, dtype=float)
    dt = np.asarray(t, dtype=float) - t_ref
    if not _by_columns(dt, mount, v, omega, v_y):
        return compose(compose(inverse(mount), se2_exp(v, v_y, omega, dt)), mount)
    x, y, yaw = _lidar_motion_columns(dt, v, omega, mount, v_y)
    out = np.empty((len(dt), 3))
    out[:, 0], out[:, 1], out[:, 2] = x, y, yaw
    return out


def _lidar_motion_columns(dt: np.ndarray, v, omega, mount: np.ndarray, v_y
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y, yaw (N,) of :func:`lidar_motion` over ``dt`` (N,) for one ``mount`` (3,): the
    operations of ``compose(compose(inverse(mount), se2_exp(...)), mount)``, column by column."""
    bx, by, bth = _se2_exp_columns(float(v), float(v_y), float(omega), dt)
    ix, iy, ith = inverse(mount).tolist()
    mx, my, myaw = mount.tolist()
    c, s = np.cos(ith), np.sin(ith)  # numpy's, as compose's array path: bit for bit even with SVML
    px = ix + c * bx  # compose(inverse(mount), base)
    px -= s * by
    py = iy + s * bx
    py += c * by
    pth = cast(np.ndarray, wrap_angle(ith + bth))
    c2, s2 = np.cos(pth), np.sin(pth)  # compose(that, mount)
    qx = c2 * mx
    qx += px  # (a + b is b + a, bit for bit)
    qx -= s2 * my
    qy = s2 * mx
    qy += py
    qy += c2 * my
    pth += myaw
    return qx, qy, cast(np.ndarray, wrap_angle(pth))


def deskew(
    xy: np.ndarray,
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray | tuple = (0.0, 0.0, 0.0),
    t_ref: float = 0.0,
    v_y: float = 0.0,
) -> np.ndarray:
    """Move every point (N, 2) to the lidar frame at ``t_ref``; returns (N, 2) in m.

    ``xy`` (N, 2), m, in the lidar frame at each point's capture time ``t`` (N,), s after
    the sweep's stamp; ``v``, ``v_y`` (m/s) and ``omega`` (rad/s): base_link's twist,
    constant over the sweep; ``mount``: the lidar in base_link (m, m, rad); ``t_ref`` (s,
    on ``t``'s clock): the time whose lidar frame the result is in.
    A point seen at ``t_i`` from the lidar pose ``P(t_i)`` (relative to the lidar
    at ``t_ref``) is ``P(t_i) · p_i`` in the reference frame; one exact SE(2)
    exponential per point, fully vectorised. ``t`` of another length than ``xy``
    raises ``ValueError``.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it and the column path
    applies (one call; the same points to rounding, ~1e-15 m), else :func:`deskew_numpy`.
    """
    core = compiled.core()
    if core is not None:
        xy = np.asarray(xy, dtype=float)
        mount = np.asarray(mount, dtype=float)
        t = np.asarray(t, dtype=float)
        if (len(xy) and xy.ndim == 2 and xy.shape[1] == 2 and t.shape == xy.shape[:1] and _is_pose(mount)
                and math.isfinite(mount[2]) and _floats(v, omega, v_y, t_ref)):
            out = np.empty(xy.shape)
            mx, my, myaw = mount.tolist()
            core.deskew(np.ascontiguousarray(xy), np.ascontiguousarray(t), t_ref, v, v_y, omega, mx, my, myaw, out)
            return out
    return deskew_numpy(xy, t, v, omega, mount, t_ref, v_y)


def deskew_placed(
    xy: np.ndarray,
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray,
    pose: np.ndarray,
    keep: np.ndarray | None = None,
) -> np.ndarray:
    """The points (K, 2) where ``keep`` (N,, bool; None: all N) is set, de-skewed (:func:`deskew`,
    ``t_ref`` 0, ``v_y`` 0) and placed by ``pose`` (3,; m, m, rad): the lidar frame at the sweep's
    stamp (as :func:`deskew` gives it) into the frame ``pose`` is given in (base_link for the mount,
    ``map`` for the lidar's pose in it). ``xy`` (N, 2) m, ``t`` (N,) s as for :func:`deskew`.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call: the
    compiled :func:`deskew` and the transform's ``R p + t`` in numpy's order, the same bits as the
    two calls), else :func:`deskew_placed_numpy`."""
    core = compiled.core()
    if (core is not None and type(xy) is np.ndarray and xy.dtype == np.float64 and xy.ndim == 2
            and xy.shape[1] == 2 and xy.flags.c_contiguous and type(t) is np.ndarray and t.dtype == np.float64
            and t.shape == xy.shape[:1] and t.flags.c_contiguous and _floats(v, omega) and _is_pose(mount)
            and _is_pose(pose) and (keep is None or (type(keep) is np.ndarray and keep.dtype == np.bool_
                                                     and keep.shape == t.shape and keep.flags.c_contiguous))):
        mx, my, myaw = mount.tolist()
        x, y, yaw = pose.tolist()
        if math.isfinite(myaw) and math.isfinite(yaw):
            return core.deskew_placed(xy, t, keep, 0.0, v, 0.0, omega, mx, my, myaw, math.cos(yaw), math.sin(yaw),
                                      x, y)
    return deskew_placed_numpy(xy, t, v, omega, mount, pose, keep)


def deskew_placed_numpy(
    xy: np.ndarray,
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray,
    pose: np.ndarray,
    keep: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`deskew_placed` as its two steps: the reference the compiled kernel is tested against."""
    if keep is not None:
        xy, t = xy[keep], t[keep]
    return transform_points(pose, deskew(xy, t, v, omega, mount))


def deskewed_source(
    xy: np.ndarray,
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray,
    near: np.ndarray,
    moving: np.ndarray | None,
    velocity: np.ndarray | None,
    voxel_size: float,
    centroid: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """A sweep's points for matching and mapping, in one pass: ``(use, points, source, velocity)``.

    ``use`` (N,, bool): the points neither in the body mask ``near`` (N,, bool) nor ``moving`` (N,,
    bool; None: none moving); ``points`` (K, 2): those de-skewed (``v`` m/s, ``omega`` rad/s) and
    placed in base_link at the sweep's stamp (:func:`deskew_placed` with the ``mount`` (3,) as the
    pose); ``source`` (M, 2): ``points`` thinned to one per ``voxel_size`` (m) voxel, the first in
    beam order (:func:`~fmcwlog.kernels.voxel.voxel_downsample`) or, with ``centroid``, each voxel's
    centroid (:func:`~fmcwlog.kernels.voxel.voxel_centroids`); ``points`` itself where ``voxel_size``
    <= 0 or none is used; ``velocity``: the used points' radial Doppler (K,; None without).
    ``xy`` (N, 2) m and ``t`` (N,) s as for :func:`deskew`.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call: the same
    bits as the compiled :func:`deskew_placed` and thinning one after the other), else
    :func:`deskewed_source_numpy`."""
    core = compiled.core()
    if (core is not None and near is not None and _is_pose(mount) and _floats(v, omega)
            and sweep_columns(xy, t, near, moving)):
        mx, my, myaw = mount.tolist()
        if math.isfinite(myaw):
            fast_velocity = core_velocity(velocity, t)
            use = np.empty(len(xy), bool)
            points, source, kept = core.deskew_source(
                xy, t, near, moving, velocity if fast_velocity else None, v, omega, mx, my, myaw, math.cos(myaw),
                math.sin(myaw), mx, my, float(voxel_size), bool(centroid), use)
            if velocity is not None and not fast_velocity:
                kept = velocity[use]
            return use, points, source, kept
    return deskewed_source_numpy(xy, t, v, omega, mount, near, moving, velocity, voxel_size, centroid)


def deskewed_source_numpy(
    xy: np.ndarray,
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray,
    near: np.ndarray,
    moving: np.ndarray | None,
    velocity: np.ndarray | None,
    voxel_size: float,
    centroid: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`deskewed_source` as its steps: the reference the compiled kernel is tested against."""
    use = used_points(near, moving)
    return thinned_source(use, deskew_placed_numpy(xy, t, v, omega, mount, mount, use), velocity, voxel_size, centroid)


def used_points(near: np.ndarray, moving: np.ndarray | None) -> np.ndarray:
    """The points (N,, bool) neither in the body mask ``near`` nor ``moving`` (None: none moving)."""
    return ~(near | moving) if moving is not None else ~near


def thinned_source(use: np.ndarray, points: np.ndarray, velocity: np.ndarray | None, voxel_size: float,
                   centroid: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """``(use, points, source, velocity)`` of the numpy references: ``points`` (the used ones, placed)
    thinned to ``source`` as :func:`deskewed_source` says, and the used points' Doppler."""
    source = (voxel_centroids_numpy if centroid else voxel_downsample_numpy)(points, voxel_size)
    return use, points, source, None if velocity is None else velocity[use]


def core_velocity(velocity: np.ndarray | None, t: np.ndarray) -> bool:
    """Whether the compiled kernels take ``velocity`` as it is (float64, C-contiguous, one per point
    of ``t``); else the caller indexes it with the kernel's ``use``."""
    return (type(velocity) is np.ndarray and velocity.dtype == np.float64 and velocity.shape == t.shape
            and velocity.flags.c_contiguous)


def sweep_columns(xy: object, t: object, *masks: object) -> bool:
    """Whether ``xy``, ``t`` and the ``masks`` are what the compiled de-skew kernels take as they are:
    contiguous arrays, float64 (N, 2) and (N,), each mask bool (N,) or None (one call for all)."""
    if not (type(xy) is np.ndarray and xy.dtype == np.float64 and xy.ndim == 2 and xy.shape[1] == 2
            and xy.flags.c_contiguous):
        return False
    n = xy.shape[:1]
    if not (type(t) is np.ndarray and t.dtype == np.float64 and t.shape == n and t.flags.c_contiguous):
        return False
    for m in masks:
        if m is not None and not (type(m) is np.ndarray and m.dtype == np.bool_ and m.shape == n
                                  and m.flags.c_contiguous):
            return False
    return True


def deskew_numpy(
    xy: np.ndarray,
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray | tuple = (0.0, 0.0, 0.0),
    t_ref: float = 0.0,
    v_y: float = 0.0,
) -> np.ndarray:
    """:func:`deskew` in numpy: the reference the compiled kernel is tested against."""
    xy = np.asarray(xy, dtype=float)
    if xy.shape[0] == 0:
        return xy.copy()
    mount = np.asarray(mount, dtype=float)
    dt = np.asarray(t, dtype=float) - t_ref
    if not _by_columns(dt, mount, v, omega, v_y) or xy.ndim != 2 or len(dt) != len(xy):
        return transform_points(lidar_motion(t, v, omega, mount, t_ref, v_y), xy)
    px, py, yaw = _lidar_motion_columns(dt, v, omega, mount, v_y)
    return rotate_translate(np.cos(yaw), np.sin(yaw), px, py, xy)  # transform_points(poses, xy)
