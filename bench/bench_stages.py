"""Per-sweep cost of the estimator stages on a synthetic 1000-point sweep.

Run: ``PYTHONPATH=. python bench/bench_stages.py``. Prints median (and p90)
milliseconds over repeated runs of: ego-motion fit, compensated velocity +
segmentation, de-skew, one robust ICP registration against a ~10k-point local
map (with and without a reused GMM), and the sum of the stages.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's fmcwlog, not an installed one

from fmcwlog.frontend.deskew import deskew, se2_exp
from fmcwlog.frontend.egomotion import (
    base_twist_from_sensor_velocity,
    compensated_velocity,
    fit_sensor_velocity,
    sensor_velocity_from_base_twist,
)
from fmcwlog.frontend.robust_icp import register
from fmcwlog.frontend.segmentation import segment_moving
from fmcwlog.geometry import compose, transform_points, wrap_angle

SEGMENTS = np.array(
    [
        [0, 0, 10, 0], [10, 0, 10, 6], [10, 6, 0, 6], [0, 6, 0, 0],
        [6, 1.5, 6, 4], [6, 4, 8, 4],
        [1, 4.5, 2, 4.5], [2, 4.5, 2, 5.2], [2, 5.2, 1, 5.2], [1, 5.2, 1, 4.5],
    ],
    float,
)
MOUNT = np.array([0.3, 0.0, 0.0])


def local_map(n=10_000):
    lengths = np.hypot(*(SEGMENTS[:, 2:] - SEGMENTS[:, :2]).T)
    pts = []
    for (x0, y0, x1, y1), k in zip(SEGMENTS, np.round(n * lengths / lengths.sum()).astype(int)):
        s = np.arange(k) / k
        pts.append(np.stack([x0 + s * (x1 - x0), y0 + s * (y1 - y0)], -1))
    return np.concatenate(pts)


def sweep(base0, v, omega, rng, movers=True, n=1000):
    """One skewed 270° sweep: beam i fired at t_i from the lidar pose at t_i.

    Base moves with the constant twist (v, ω) from ``base0``; two walkers (disc
    radius 0.3 m) stand in front of the walls; Doppler quantised to 0.1 m/s.
    Returns lidar-frame xy (each at its own time), v_r, t and the lidar pose at t=0.
    """
    t = np.linspace(0.0, 0.075, n)
    lidar = compose(compose(base0, se2_exp(v, 0.0, omega, t)), MOUNT)  # (n, 3)
    ang = np.linspace(-0.75 * np.pi, 0.75 * np.pi, n)
    th = lidar[:, 2] + ang
    d = np.stack([np.cos(th), np.sin(th)], -1)
    a, e = SEGMENTS[:, :2], SEGMENTS[:, 2:] - SEGMENTS[:, :2]
    ao = a[None] - lidar[:, None, :2]
    den = -d[:, None, 0] * e[None, :, 1] + d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (-ao[..., 0] * e[None, :, 1] + ao[..., 1] * e[None, :, 0]) / den
        s = (d[:, None, 0] * ao[..., 1] - d[:, None, 1] * ao[..., 0]) / den
    r = np.where((r > 0) & (s >= 0) & (s <= 1), r, np.inf).min(axis=1)
    vel_world = np.zeros((n, 2))
    if movers:
        for c, vel in (([3.0, 1.5], [1.2, 0.3]), ([6.5, 5.0], [-0.3, -1.0])):
            oc = np.asarray(c) - lidar[:, :2]
            b = np.sum(d * oc, axis=1)
            disc = b**2 - (np.sum(oc * oc, axis=1) - 0.3**2)
            t_hit = np.where(disc > 0, b - np.sqrt(np.maximum(disc, 0)), np.inf)
            closer = (t_hit > 0) & (t_hit < r)
            r = np.where(closer, t_hit, r)
            vel_world[closer] = vel
    r = r + rng.normal(0, 0.005, n)
    xy = np.stack([r * np.cos(ang), r * np.sin(ang)], -1)
    # range rate: (point velocity - lidar origin velocity) along the beam, world axes
    # the lidar-frame velocity is constant under a constant twist; in world axes it
    # turns with the lidar's yaw at each beam's time
    v_lidar_world = transform_points(
        np.stack([np.zeros(n), np.zeros(n), lidar[:, 2]], -1),
        np.tile(sensor_velocity_from_base_twist(v, omega, *MOUNT), (n, 1)),
    )
    v_r = np.sum(d * (vel_world - v_lidar_world), axis=1)
    v_r = np.round(v_r / 0.1) * 0.1
    return xy, v_r, t, lidar[0]


def timed(f, *a, **k):
    t0 = time.perf_counter()
    out = f(*a, **k)
    return out, (time.perf_counter() - t0) * 1e3


def main(n_sweeps=200, movers=True):
    rng = np.random.default_rng(0)
    target = local_map()
    tree = cKDTree(target)
    v, omega = 1.0, 0.3
    rows = []
    mixture = None
    for i in range(n_sweeps):
        base = np.array([4.0, 3.0, 0.3]) + np.r_[rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.2, 0.2)]
        xy, v_r, t, lidar = sweep(base, v, omega, rng, movers)
        ego, t_ego = timed(fit_sensor_velocity, xy, v_r, random_state=i)
        t0 = time.perf_counter()
        eps = compensated_velocity(xy, v_r, ego.v_sensor)
        moving = segment_moving(xy, eps)
        t_seg = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        tw = base_twist_from_sensor_velocity(ego.v_sensor, *MOUNT, covariance=ego.covariance)
        pts = deskew(xy[~moving], t[~moving], tw.v, tw.omega, MOUNT)
        t_dsk = (time.perf_counter() - t0) * 1e3
        prior = lidar + np.r_[rng.normal(0, 0.003, 2), rng.normal(0, 0.001)]
        res, t_icp = timed(register, pts, tree, target, prior)
        res2, t_icp_reuse = timed(register, pts, tree, target, prior, mixture=mixture)
        mixture = res.mixture
        err = np.hypot(*(res.pose[:2] - lidar[:2])) * 1e3
        err_deg = abs(np.rad2deg(wrap_angle(res.pose[2] - lidar[2])))
        rows.append([t_ego, t_seg, t_dsk, t_icp, t_icp_reuse, res.iterations, res.n_gmm_fits,
                     moving.sum(), err, err_deg, res2.iterations, res2.n_gmm_fits])
    a = np.array(rows)
    names = ["ego-motion fit", "compensate+segment", "twist+deskew", "robust ICP (fresh GMM)",
             "robust ICP (reused GMM)"]
    print(f"{n_sweeps} sweeps of {len(xy)} points vs {len(target)}-point map, movers={movers}")
    for j, name in enumerate(names):
        print(f"  {name:26s} median {np.median(a[:, j]):6.2f} ms   p90 {np.percentile(a[:, j], 90):6.2f} ms")
    total = a[:, 0] + a[:, 1] + a[:, 2] + a[:, 3]
    total_reuse = a[:, 0] + a[:, 1] + a[:, 2] + a[:, 4]
    print(f"  {'TOTAL (fresh GMM)':26s} median {np.median(total):6.2f} ms   p90 {np.percentile(total, 90):6.2f} ms")
    print(f"  {'TOTAL (reused GMM)':26s} median {np.median(total_reuse):6.2f} ms   p90 {np.percentile(total_reuse, 90):6.2f} ms")
    print(f"  ICP iterations median {np.median(a[:, 5]):.0f} (reused GMM {np.median(a[:, 10]):.0f}), "
          f"GMM fits per registration mean {a[:, 6].mean():.2f} (reused {a[:, 11].mean():.2f}), moving points median {np.median(a[:, 7]):.0f}, "
          f"pose error median {np.median(a[:, 8]):.2f} mm / {np.median(a[:, 9]):.4f} deg "
          f"(max {a[:, 8].max():.2f} mm / {a[:, 9].max():.4f} deg)")


if __name__ == "__main__":
    main(movers=True)
    main(movers=False)
