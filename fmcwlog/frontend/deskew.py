"""Motion compensation (de-skewing) of one sweep under a constant body twist.

Frames and units: points ``xy`` (N, 2) in the lidar frame *at their own
capture time* ``t`` (N,) (s after the sweep stamp); the result is expressed in
the lidar frame at ``t_ref``. The base_link twist ``(v, ω)`` (m/s, rad/s;
``v_y`` defaults to 0, the non-holonomic rear axle) is held constant over the
sweep; ``mount = (lidar_x, lidar_y, lidar_yaw)`` places the lidar in base_link.

NOTES.md "Motion distortion": a 75 ms sweep at 1.5 m/s spans 11 cm, so every
point is moved to the reference time before matching or mapping.
"""

from __future__ import annotations

import numpy as np

from ..geometry import compose, inverse, transform_points


def se2_exp(
    vx: float | np.ndarray, vy: float | np.ndarray, omega: float | np.ndarray, dt: np.ndarray
) -> np.ndarray:
    """Pose (..., 3) reached after ``dt`` (s) under a constant body twist, from the identity.

    Exact SE(2) exponential: with ``θ = ω dt``,
    ``[x, y] = V(θ) [vx, vy] dt``, ``V = [[sinθ/θ, -(1-cosθ)/θ], [(1-cosθ)/θ, sinθ/θ]]``.
    Written with ``np.sinc`` so ``ω → 0`` is exact: ``(1-cosθ)/θ = θ/2 · sinc²(θ/2)``.
    """
    dt = np.asarray(dt, dtype=float)
    th = omega * dt
    a = np.sinc(th / np.pi)  # sinθ/θ
    b = 0.5 * th * np.sinc(th / (2.0 * np.pi)) ** 2  # (1-cosθ)/θ
    x = (a * vx - b * vy) * dt
    y = (b * vx + a * vy) * dt
    return np.stack(np.broadcast_arrays(x, y, th), -1)


def lidar_motion(
    t: np.ndarray,
    v: float,
    omega: float,
    mount: np.ndarray | tuple,
    t_ref: float = 0.0,
    v_y: float = 0.0,
) -> np.ndarray:
    """Poses (N, 3) of the lidar at times ``t`` expressed in the lidar frame at ``t_ref``.

    ``L⁻¹ ⊕ exp((t - t_ref) ξ) ⊕ L`` with ``L`` the mounting and ``ξ = (v, v_y, ω)``
    the base_link twist.
    """
    mount = np.asarray(mount, dtype=float)
    base = se2_exp(v, v_y, omega, np.asarray(t, dtype=float) - t_ref)
    return compose(compose(inverse(mount), base), mount)


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

    A point seen at ``t_i`` from the lidar pose ``P(t_i)`` (relative to the lidar
    at ``t_ref``) is ``P(t_i) · p_i`` in the reference frame; one exact SE(2)
    exponential per point, fully vectorised.
    """
    xy = np.asarray(xy, dtype=float)
    if xy.shape[0] == 0:
        return xy.copy()
    return transform_points(lidar_motion(t, v, omega, mount, t_ref, v_y), xy)
