"""Movers followed from sweep to sweep, so that one seen moving keeps its label while Doppler is blind to it.

A mover whose motion is perpendicular to the beam has ``ε ≈ 0``: Doppler cannot see it.
Per-sweep clustering (:mod:`.segmentation`) carries such points
only when the same object shows Doppler elsewhere; a person walking across the
beams shows none at all (at 1.2 m/s, ``|uᵀV| < v_th = 0.3 m/s`` within ±14° of
broadside, for seconds when it crosses far ahead of the robot) and is then
labelled static and mapped. But it was seen moving in the sweeps before, and it
stands where the map has seen free space: this module uses both. Not in the paper, whose
verdict is per sweep (Wang et al. §4.1; ``tracking.enabled = false`` gives that verdict alone).

Frames and units: tracks live in the method's odometry frame (called ``map`` here,
where its occupancy grid is), positions in m, velocities in m/s, times in s on the
log's clock. :meth:`MoverTracker.segment` takes a sweep as it came (lidar frame,
each point at its own time), the predicted pose of base_link at the sweep's stamp
and the twist over the sweep, and places the points in ``map`` itself.

Each track is a constant-velocity Kalman filter over ``(x, y, vx, vy)``, measured by
its cluster's centroid (m) and mean compensated Doppler ``ε̄ = ūᵀV`` (m/s) along the
centroid's bearing ``ū``: the Doppler gives the radial speed at once, the centroid's
motion the tangential one. Per sweep, for a few dozen tracks and clusters, all in
arrays (no loop over points or tracks; where :func:`fmcwlog.kernels.compiled.core` selects the
compiled kernel, steps 1-6 are one call of it, with the same labels and track counts and the
states to rounding, :meth:`MoverTracker._segment_compiled`):

1. DBSCAN (:func:`.segmentation.segment_clusters`) also around where confirmed
   tracks are expected and around points in free space, not only around points
   with ``|ε| ≥ v_th``;
2. predict every track to the sweep's middle time;
3. gate: a cluster is a candidate for a track when its centroid is within
   ``gate_distance`` of the prediction and the Mahalanobis distance of
   ``(centroid, ε̄)`` is within ``gate_chi2``; the Doppler term keeps a track whose
   mover walks along the beam from taking a static pillar (``ε̄ = 0``);
4. one-to-one assignment (Hungarian, :func:`scipy.optimize.linear_sum_assignment`)
   for the filter updates;
5. labels: a cluster no larger than ``max_object_radius`` gated by a confirmed track
   is moving, whatever its Doppler; a point of a larger cluster (a walker chained to
   a wall by DBSCAN) or a DBSCAN noise point is moving when it lies within
   ``claim_radius`` of a confirmed track's updated position and its ``ε`` agrees
   with the track's radial velocity;
6. births from clusters judged moving (by Doppler or free space) that no track
   took; a track dies ``max_coast`` after its last update.

A track is confirmed (may label) once it has been matched to clusters judged moving
in ``min_moving_hits`` sweeps and its speed is at least ``min_speed``. Static
structure never births a track (it shows no Doppler and is not in free space).

The map enters twice, through the largest log-odds of a point's cell and its 8 neighbours
(points far from any static structure seen repeatedly):

- free space, from the scans of the last ``free_window`` m of path only
  (:class:`.recent_grid.RecentOccupancy`, fed by the front end through :meth:`MoverTracker.add_scan`):
  a compact cluster with most of its points where every cell around has been seen free
  (summed log-odds ≤ ``free_log_odds``) is moving, Doppler or not, and may birth a track: a
  mover that crosses the beams without ever having been seen moving (a slow cart ahead of the
  robot, whose ``|ε|`` stays under ``v_th`` within ±50° of broadside);
- free space from the last sweeps' rays (``displacement_sweeps``, :class:`RecentRays`): a point
  well short of where the ray of a sweep 0.2-1 s back at its bearing ended stands where that
  sweep saw through, so something moved there since; it counts as seen free. It catches the
  walkers crossing the beams far ahead early in a log, before the grid has seen their place free
  three times over (on the 60 s ``dense-crowd`` logs, seeds 0-2, recall on the mover points Doppler
  cannot see, ``|ε_true| < 0.25 m/s``, rises from 0.88 to 0.945 at the same precision, and the
  corridor and static logs gain no false positive);
- structure, from the method's whole occupancy grid (read only): a point where some cell
  around has been hit at least once more than it was seen free (log-odds ≥
  ``structure_log_odds``) is never labelled moving by a track or by free space, only by its
  own Doppler: a track that slid onto a wall or a pillar cannot carry it there.

Why free space is read from recent scans only: the front end matches against its recent
keyframes, so its pose drifts against what its grid drew a lap ago (0.015-0.02 rad on the
corridor with the LiDAR sideways), and walls 20-25 m away land in cells seen free at the
clamp. On that log (``fmcwlog record --duration 120 --set sensor.mount_x=0 --set
sensor.mount_y=0.25``, processed with ``--method improved``) free space from the whole grid
judges 705 static points moving, from the last 45 m 31, at the same recall (0.9995).

What each part adds, on the 2-minute logs, seed 0 (recall / precision / static points judged
moving; ``dense-crowd``: 46 % of the returns on movers; ``fmcwlog record --scenario dense-crowd
--duration 120``, then ``fmcwlog process --method improved``, ``--set tracking.enabled=false``
for the first): Doppler clusters alone 0.857 / 1.0000 /
17, with the tracker and free space 0.985 / 0.9998 / 114; without the structure check the
precision falls to 0.988 (6,915 static points judged moving). Every variant measured, and the
choice of ``free_window`` and ``free_log_odds``: docs/design/moving-points.md.

The pose used to place a sweep is the last pose moved by the last sweep's twist, which spans
most of the time since: at the end of corners on dense-crowd its yaw error is up to 0.014 rad,
against 0.05 rad with this sweep's own twist, which puts pillars into free space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Checked, param
from ..geometry import _is_pose, compose, inverse, transform_points
from ..kernels import compiled
from ..kernels.occupancy import OccupancyGrid, Scan
from .deskew import _floats, deskew_placed, deskew_placed_numpy, sweep_columns
from .recent_grid import RecentOccupancy, local_max_log_odds
from .segmentation import SegmentationParams, segment_clusters

_NO_MATCH = 1e9  # cost of a pair outside the gate


@dataclass(frozen=True)
class TrackingParams(Checked):
    """Parameters of :class:`MoverTracker` (units and valid ranges; defaults tuned on ``dense-crowd``).

    enabled: follow movers over time and use the map's free space (False: the per-sweep
        Doppler verdict alone, as in the paper).
    gate_distance: a cluster's centroid farther than this (m, > 0) from a track's
        prediction is never its measurement.
    gate_chi2: Mahalanobis gate on (centroid x, y, ε̄), 3 degrees of freedom (> 0);
        16.3 is the 99.9 % quantile.
    position_sigma: noise of a cluster centroid as a measure of the object's position
        (m, > 0); the visible side of a 0.5 m person is ~0.15 m off its centre. Half the
        cluster's radius is added to it, for carts whose visible faces change.
    doppler_sigma: noise of a cluster's mean ε (m/s, > 0); 0.1 m/s quantisation.
    accel_sigma: white acceleration of the constant-velocity model (m/s², > 0); people
        turn and stop.
    birth_tangential_sigma: a new track's unknown speed across the beam (m/s, > 0).
    max_coast: a track not updated for this long (s, ≥ 0) is dropped.
    min_moving_hits: sweeps matched to a cluster judged moving before a track labels (≥ 1).
    min_speed: a track slower than this (m/s, ≥ 0) labels nothing (a mover that stopped).
    max_object_radius: a gated cluster whose points all lie within this (m, > 0) of its
        centroid is one object and moving as a whole; larger ones only near the track.
    claim_radius: points within this (m, ≥ 0; 0 switches it off) of a confirmed track's
        position may be claimed one by one (noise points, large clusters); +0.002 recall.
    claim_doppler: a point claimed one by one has ``|ε - uᵀV̂| ≤`` this (m/s, > 0).
    structure_log_odds: a point whose occupancy cell or any of its 8 neighbours holds
        at least this log-odds is on static structure and is never labelled by a track
        or by free space (one hit adds 0.85, one traversal -0.4); ≤ 0 disables the check.
    free_log_odds: a point whose cell and 8 neighbours all hold at most this log-odds, summed
        over the recent grids (< 0; ≥ 0 disables free space), lies where the scans of the last
        ``free_window`` have seen free space (-1.2: three traversals more than hits).
    free_window: free space is read from the scans of the last this much path (m, > 0), drawn
        at poses consistent with the current one (45 m, between the 64 m loop of dense-crowd and
        the 90 m one of the corridor: docs/design/moving-points.md).
    free_fraction: a cluster no larger than ``max_object_radius`` with at least this
        fraction (0-1] of its points in free space is moving and may birth a track.
    map_tolerance: free space is used only where the predicted pose's yaw error moves a
        point by at most this much (m, ≥ 0; one grid cell): at the end of a corner the
        sweep's yaw is uncertain by ``|Δω|·Δt`` and far walls would land in free space.
        The yaw error has no floor: a floor costs more recall than it saves false positives
        (docs/design/moving-points.md).
    max_tracks: at most this many tracks (≥ 1; the least recently updated are dropped).
    displacement_sweeps: free space from the rays of the last this many sweeps too (≥ 0; 0 switches
        it off): a point at least ``displacement_margin`` short of where an earlier sweep's ray at
        its bearing ended stands where that sweep saw through, so something moved there since
        (:class:`RecentRays`): a walker crossing the beams far ahead before the map has seen its
        place free. Counted as seen free (``free_fraction``, births).
    displacement_step: every this many sweeps back (≥ 1) is compared (2: 0.2, 0.4, ... 1.0 s back
        at 10 Hz; another sweep back sees past what hid the place in one).
    displacement_margin: how far short (m, ≥ 0) of the earlier ray's end a point must lie (range noise,
        the lidar's motion and the bearing bin's spread along a wall seen at grazing incidence).
    displacement_window: the earlier ray's end is the nearest over this many 0.25° bins either side
        (≥ 0): a point's bearing is uncertain by the placement's error.
    displacement_tolerance: a point is compared only where the largest yaw error of the sweeps
        between (the ``yaw_error`` of :meth:`MoverTracker.segment`) moves it by at most this (m, ≥ 0):
        at the end of a corner, walls far ahead at grazing incidence would look seen through.
    """

    enabled: bool = True
    gate_distance: float = param(1.0, "m", gt=0.0, le=100.0)
    gate_chi2: float = param(16.3, "", gt=0.0, le=1000.0)
    position_sigma: float = param(0.15, "m", gt=0.0, le=10.0)
    doppler_sigma: float = param(0.1, "m/s", gt=0.0, le=10.0)
    accel_sigma: float = param(2.0, "m/s^2", gt=0.0, le=100.0)
    birth_tangential_sigma: float = param(1.5, "m/s", gt=0.0, le=50.0)
    max_coast: float = param(0.6, "s", ge=0.0, le=60.0)
    min_moving_hits: int = param(2, "sweeps", ge=1, le=1000)
    min_speed: float = param(0.3, "m/s", ge=0.0, le=50.0)
    max_object_radius: float = param(0.8, "m", gt=0.0, le=100.0)
    claim_radius: float = param(0.5, "m", ge=0.0, le=100.0)
    claim_doppler: float = param(0.3, "m/s", gt=0.0, le=50.0)
    structure_log_odds: float = param(0.8, "log-odds", ge=-100.0, le=100.0)  # <= 0 disables the check
    free_log_odds: float = param(-1.2, "log-odds", ge=-100.0, le=100.0)  # >= 0 disables free space
    free_fraction: float = param(0.5, "", gt=0.0, le=1.0)
    map_tolerance: float = param(0.05, "m", ge=0.0, le=10.0)
    free_window: float = param(45.0, "m", gt=0.0, le=10_000.0)
    max_tracks: int = param(64, "tracks", ge=1, le=100_000)
    displacement_sweeps: int = param(10, "sweeps", ge=0, le=100)  # 0 switches displacement off
    displacement_step: int = param(2, "sweeps", ge=1, le=100)
    displacement_margin: float = param(0.5, "m", ge=0.0, le=100.0)
    displacement_window: int = param(1, "bins", ge=0, le=100)
    displacement_tolerance: float = param(0.15, "m", ge=0.0, le=10.0)


@dataclass
class Detections:
    """One sweep's clusters as measurements (C of them), in ``map``.

    centroid (C, 2) m; bearing (C, 2) unit vector from the lidar to the centroid;
    doppler (C,) mean ε, m/s; radius (C,) largest distance of a point from the
    centroid, m; time (C,) mean capture time, s; moving (C,) the Doppler verdict;
    free_space (C,) no Doppler verdict, but compact and where the map has seen free space.
    """

    centroid: np.ndarray
    bearing: np.ndarray
    doppler: np.ndarray
    radius: np.ndarray
    time: np.ndarray
    moving: np.ndarray
    free_space: np.ndarray

    def __len__(self) -> int:
        return len(self.centroid)


def detections(map_xy: np.ndarray, origin: np.ndarray, times: np.ndarray, epsilon: np.ndarray,
               labels: np.ndarray, moving: np.ndarray, seen_free: np.ndarray, max_radius: float,
               free_fraction: float) -> Detections:
    """Cluster statistics from points (N, 2) in ``map`` with their DBSCAN ``labels`` (-1: none),
    capture ``times`` (s), compensated Doppler ``epsilon`` (m/s), Doppler verdict ``moving`` and
    whether the map has seen their place free (``seen_free``); ``origin`` (2,) is the lidar's
    position. Cluster ``c`` is row ``c`` (labels 0..C-1). A cluster within ``max_radius`` (m) of
    its centroid with at least ``free_fraction`` of its points seen free is a free-space detection."""
    keep = labels >= 0
    lab = labels[keep]
    c = int(lab.max()) + 1 if lab.size else 0
    count = np.maximum(np.bincount(lab, minlength=c), 1)
    xy = map_xy[keep]
    centroid = np.column_stack([np.bincount(lab, xy[:, 0], c), np.bincount(lab, xy[:, 1], c)]) / count[:, None]
    radius = np.zeros(c)
    np.maximum.at(radius, lab, np.hypot(*(xy - centroid[lab]).T))
    d = centroid - origin
    bearing = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
    doppler = np.bincount(lab, epsilon[keep], c) / count
    time = np.bincount(lab, times[keep], c) / count
    is_moving = np.bincount(lab, moving[keep], c) > 0.5 * count
    free_space = (np.bincount(lab, seen_free[keep], c) >= free_fraction * count) & (radius <= max_radius) & ~is_moving
    return Detections(centroid, bearing, doppler, radius, time, is_moving, free_space)


def middle_time(t: np.ndarray) -> float:
    """``np.median(t)`` (s) of a sweep's capture times: where they are sorted, as a sweep's beams
    come, its middle value (or the mean of its two middle values) read directly: the same value
    without the partition (7 µs a sweep of 1,080 points, against 23 µs); else ``np.median`` itself."""
    n = len(t)
    if n and t.dtype == np.float64 and np.logical_and.reduce(t[1:] >= t[:-1]):  # .all()'s reduction; False with a NaN
        # np.mean's sum starts from +0.0 (so a -0.0 comes back as 0.0), then its division
        if n % 2:
            return float(0.0 + t[n // 2])
        return float((0.0 + t[n // 2 - 1] + t[n // 2]) / 2.0)
    return float(np.median(t))


class MoverTracker:
    """Tracks of moving objects in ``map``; :meth:`segment` once per sweep, in time order."""

    def __init__(self, params: TrackingParams = TrackingParams(), resolution: float = 0.05):
        """``resolution``: the free-space grids' cell size (m), the method's map resolution."""
        self.params = params
        self.recent = RecentOccupancy(params.free_window, resolution)
        self.reset()

    def add_scan(self, scan: Scan, path_m: float) -> None:
        """A scan's static points (``map``, m, at its registered pose) taken after ``path_m`` m of
        path: the free space the tracker reads. The method's grid may get the same :class:`.Scan`:
        it is cast once for both."""
        self.recent.integrate(scan, path_m)

    def reset(self) -> None:
        """Drop every track (the free-space grids are kept)."""
        self.x = np.zeros((0, 4))  # (T, 4) x, y, vx, vy
        self.cov = np.zeros((0, 4, 4))
        self.time = np.zeros(0)  # s, the time the state refers to
        self.last_update = np.zeros(0)  # s
        self.moving_hits = np.zeros(0, np.int64)
        self.rays = RecentRays(self.params.displacement_sweeps, self.params.displacement_window)
        self._compiled_config: tuple | None = None  # (SegmentationParams, its and self.params' values as arrays)

    def __len__(self) -> int:
        return len(self.x)

    @property
    def confirmed(self) -> np.ndarray:
        """(T,) tracks that may label points."""
        p = self.params
        speed = np.hypot(self.x[:, 2], self.x[:, 3])
        return (self.moving_hits >= p.min_moving_hits) & (speed >= p.min_speed)

    def predicted(self, when: float) -> np.ndarray:
        """Positions (T, 2) of the confirmed tracks at ``when`` (s), in ``map``."""
        ok = self.confirmed
        return self.x[ok, :2] + self.x[ok, 2:] * (when - self.time[ok])[:, None]

    def predict(self, when: float) -> None:
        """Every track's state and covariance moved to ``when`` (s)."""
        dt = when - self.time
        f = np.tile(np.eye(4), (len(dt), 1, 1))
        f[:, 0, 2] = f[:, 1, 3] = dt
        q = self.params.accel_sigma**2
        g = np.zeros((len(dt), 4, 4))
        g[:, [0, 1], [0, 1]] = dt[:, None] ** 4 / 4
        g[:, [0, 1, 2, 3], [2, 3, 0, 1]] = dt[:, None] ** 3 / 2
        g[:, [2, 3], [2, 3]] = dt[:, None] ** 2
        self.x = np.einsum("tij,tj->ti", f, self.x)
        self.cov = f @ self.cov @ f.transpose(0, 2, 1) + q * g
        self.time = np.full(len(dt), when)

    def _innovations(self, det: Detections, when: float, ti: np.ndarray, ci: np.ndarray):
        """Innovation (M, 3), its covariance (M, 3, 3) and the measurement Jacobian (M, 3, 4)
        of the pairs (track ``ti``, cluster ``ci``)."""
        p = self.params
        delay = det.time[ci] - when  # the cluster's points were seen at their own time
        h = np.zeros((len(ti), 3, 4))
        h[:, 0, 0] = h[:, 1, 1] = 1.0
        h[:, 0, 2] = h[:, 1, 3] = delay
        h[:, 2, 2:] = det.bearing[ci]
        z = np.column_stack([det.centroid[ci], det.doppler[ci]])
        y = z - np.einsum("mij,mj->mi", h, self.x[ti])
        r = np.zeros((len(ti), 3, 3))
        r[:, [0, 1], [0, 1]] = (p.position_sigma**2 + (0.5 * det.radius[ci]) ** 2)[:, None]
        r[:, 2, 2] = p.doppler_sigma**2
        s = h @ self.cov[ti] @ h.transpose(0, 2, 1) + r
        return y, s, h

    def _gate(self, det: Detections, when: float):
        """Pairs (track, cluster) inside both gates, with their innovations."""
        p = self.params
        dist = np.hypot(*(self.x[:, None, :2] - det.centroid[None, :, :]).transpose(2, 0, 1))
        ti, ci = np.nonzero(dist <= p.gate_distance)
        y, s, h = self._innovations(det, when, ti, ci)
        d2 = np.einsum("mi,mi->m", y, np.linalg.solve(s, y[..., None])[..., 0])
        ok = d2 <= p.gate_chi2
        return ti[ok], ci[ok], d2[ok], y[ok], s[ok], h[ok]

    def _update(self, ti: np.ndarray, y: np.ndarray, s: np.ndarray, h: np.ndarray) -> None:
        """Kalman update of tracks ``ti`` with their innovations."""
        cov = self.cov[ti]
        gain = np.linalg.solve(s, h @ cov).transpose(0, 2, 1)  # P Hᵀ S⁻¹ (S symmetric)
        self.x[ti] += np.einsum("mij,mj->mi", gain, y)
        cov = (np.eye(4) - gain @ h) @ cov
        self.cov[ti] = 0.5 * (cov + cov.transpose(0, 2, 1))

    def _birth(self, det: Detections, ci: np.ndarray, when: float) -> None:
        """New tracks on clusters ``ci``: the radial velocity from their Doppler, the tangential unknown."""
        p = self.params
        u = det.bearing[ci]
        n = np.column_stack([-u[:, 1], u[:, 0]])
        x = np.column_stack([det.centroid[ci], det.doppler[ci, None] * u])
        x[:, :2] += x[:, 2:] * (when - det.time[ci])[:, None]
        cov = np.zeros((len(ci), 4, 4))
        cov[:, [0, 1], [0, 1]] = (p.position_sigma**2 + (0.5 * det.radius[ci]) ** 2)[:, None]
        cov[:, 2:, 2:] = (p.doppler_sigma**2 * u[:, :, None] * u[:, None, :]
                          + p.birth_tangential_sigma**2 * n[:, :, None] * n[:, None, :])
        self.x = np.concatenate([self.x, x])
        self.cov = np.concatenate([self.cov, cov])
        self.time = np.concatenate([self.time, np.full(len(ci), when)])
        self.last_update = np.concatenate([self.last_update, np.full(len(ci), when)])
        self.moving_hits = np.concatenate([self.moving_hits, np.ones(len(ci), int)])

    def _prune(self, when: float) -> None:
        keep = when - self.last_update <= self.params.max_coast
        if keep.sum() > self.params.max_tracks:
            keep &= self.last_update >= np.sort(self.last_update[keep])[-self.params.max_tracks]
        self.x, self.cov, self.time = self.x[keep], self.cov[keep], self.time[keep]
        self.last_update, self.moving_hits = self.last_update[keep], self.moving_hits[keep]

    def associate(self, det: Detections, when: float) -> np.ndarray:
        """Steps 2-4 and 6 of the module docstring; returns (C,) the clusters a confirmed track
        claims (step 5, cluster level). ``when`` (s) is the sweep's middle time."""
        p = self.params
        if len(self) == 0 and not (det.moving | det.free_space).any():
            return np.zeros(len(det), bool)
        self.predict(when)
        confirmed = self.confirmed
        claimed = np.zeros(len(det), bool)
        assigned = np.zeros(len(det), bool)
        if len(self) and len(det):
            ti, ci, d2, y, s, h = self._gate(det, when)
            claimed[ci[confirmed[ti] & (det.radius[ci] <= p.max_object_radius)]] = True
            cost = np.full((len(self), len(det)), _NO_MATCH)
            cost[ti, ci] = d2
            from scipy.optimize import linear_sum_assignment  # here: scipy.optimize is 0.16 s of imports

            rows, cols = linear_sum_assignment(cost)
            match = cost[rows, cols] < _NO_MATCH
            rows, cols = rows[match], cols[match]
            pair = np.full(cost.shape, -1)
            pair[ti, ci] = np.arange(len(ti))
            k = pair[rows, cols]
            self._update(rows, y[k], s[k], h[k])
            self.last_update[rows] = when
            self.moving_hits[rows] += det.moving[cols] | det.free_space[cols]
            assigned[cols] = True
        births = np.flatnonzero((det.moving | det.free_space) & ~assigned)
        if births.size:
            self._birth(det, births, when)
        self._prune(when)
        return claimed

    def claim_points(self, map_xy: np.ndarray, bearing: np.ndarray, epsilon: np.ndarray) -> np.ndarray:
        """(N,) points within ``claim_radius`` of a confirmed track (its state after
        :meth:`associate`) whose ``ε`` agrees with the track's radial velocity ``uᵀV̂``."""
        p = self.params
        ok = self.confirmed
        if not ok.any() or len(map_xy) == 0:
            return np.zeros(len(map_xy), bool)
        pos, vel = self.x[ok, :2], self.x[ok, 2:]
        near = np.hypot(*(map_xy[:, None, :] - pos[None]).transpose(2, 0, 1)) <= p.claim_radius  # (N, T)
        agree = np.abs(epsilon[:, None] - bearing @ vel.T) <= p.claim_doppler
        return np.any(near & agree, axis=1)

    def segment(self, xy: np.ndarray, t: np.ndarray, epsilon: np.ndarray, stamp: float, base_pose: np.ndarray,
                twist: tuple[float, float], mount: np.ndarray, grid: OccupancyGrid | None,
                seg_params: SegmentationParams, yaw_error: float = 0.0, ranges: np.ndarray | None = None,
                middle: float | None = None) -> np.ndarray:
        """The moving mask (N,) of one sweep: DBSCAN's Doppler verdict (eq. 17-19), the clusters in
        space the map has seen free, and what the tracks claim; the tracks are updated.

        ``xy`` (N, 2): points in the lidar frame at their own capture times ``t`` (N,, s after
        ``stamp``, s); ``epsilon`` (N,): compensated Doppler (m/s); ``base_pose`` (3,): base_link
        in ``map`` at ``stamp``, as predicted; ``twist``: ``(v, ω)`` over the sweep (m/s, rad/s);
        ``mount`` (3,): the lidar in base_link; ``grid``: the method's occupancy grid (read only,
        for the structure check; free space comes from the scans given to :meth:`add_scan`);
        ``yaw_error``: how far (rad) ``base_pose``'s yaw may be off: free space is only looked up
        where it moves a point by at most ``map_tolerance``; ``ranges`` (N,): ``np.hypot`` of ``xy``'s
        rows (m) and ``middle``: :func:`middle_time` of ``t`` (s), if already computed.
        """
        p = self.params
        lidar = compose(base_pose, mount)
        when = stamp + (middle_time(t) if middle is None else middle)
        if p.free_log_odds < 0:  # the sweep in the map, and which of its points lie in space seen free
            map_xy, seen_free = placed_free_space(self.recent, xy, t, twist, mount, lidar, ranges, yaw_error,
                                                  p.map_tolerance, p.free_log_odds)
        else:
            map_xy = deskew_placed(xy, t, twist[0], twist[1], mount, lidar)
            seen_free = np.zeros(len(xy), bool)
        if p.displacement_sweeps > 0:  # where earlier sweeps saw through: something moved in since
            ends = deskew_placed(np.zeros((2, 2)), t[[0, -1]], twist[0], twist[1], mount, lidar) if len(t) else None
            seen_free = seen_free | self.rays.sweep(map_xy, t, ends, p.displacement_step, p.displacement_margin,
                                                    yaw_error, p.displacement_tolerance)
        core = compiled.core()
        if core is not None:
            found = self._segment_compiled(core, xy, map_xy, t, epsilon, seen_free, lidar, stamp, when, seg_params)
            if found is not None:
                return self._off_structure(found, grid, map_xy)
        seg = segment_clusters(xy, epsilon, seg_params, seeds=self.seeds(lidar, when), seed_points=seen_free)
        idx = np.flatnonzero(seg.clustered)
        labels = seg.labels[idx]
        det = detections(map_xy[idx], lidar[:2], stamp + t[idx], epsilon[idx], labels, seg.moving[idx],
                         seen_free[idx], p.max_object_radius, p.free_fraction)
        claimed = self.associate(det, when)
        moving = seg.moving.copy()
        if idx.size == 0:
            return moving
        unlabelled = ~seg.moving[idx]
        in_cluster = labels >= 0
        by_cluster = np.zeros(len(idx), bool)
        by_cluster[in_cluster] = (claimed | det.free_space)[labels[in_cluster]]
        large = ~in_cluster
        large[in_cluster] = det.radius[labels[in_cluster]] > p.max_object_radius
        loose = np.flatnonzero(unlabelled & ~by_cluster & large)
        if loose.size and p.claim_radius > 0:
            d = map_xy[idx[loose]] - lidar[:2]
            bearing = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
            by_cluster[loose] = self.claim_points(map_xy[idx[loose]], bearing, epsilon[idx[loose]])
        new = idx[unlabelled & by_cluster]
        if new.size and grid is not None and p.structure_log_odds > 0:  # never on structure seen repeatedly
            new = new[local_max_log_odds(grid, map_xy[new]) < p.structure_log_odds]
        moving[new] = True
        return moving

    def _segment_compiled(self, core, xy: np.ndarray, map_xy: np.ndarray, t: np.ndarray, epsilon: np.ndarray,
                          seen_free: np.ndarray, lidar: np.ndarray, stamp: float, when: float,
                          seg_params: SegmentationParams) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`segment` from the seeds on, in one call of the compiled kernel (the same labels and
        tracks, these to rounding): the moving mask (N,) and the points the tracks and free space label
        (for the structure check), or None where an input is not finite (then the numpy code answers).
        The tracks are updated."""
        cached = self._compiled_config
        if cached is None or cached[0] is not seg_params:
            p, sp = self.params, seg_params
            seg = np.array([sp.alpha, sp.eps, sp.min_samples, sp.v_th, sp.min_moving_fraction,
                            float(sp.keep_strong_points), sp.neighbourhood])
            track = np.array([p.gate_distance, p.gate_chi2, p.position_sigma, p.doppler_sigma, p.accel_sigma,
                              p.birth_tangential_sigma, p.max_coast, p.min_moving_hits, p.min_speed,
                              p.max_object_radius, p.claim_radius, p.claim_doppler, p.free_fraction, p.max_tracks])
            cached = self._compiled_config = (seg_params, seg, track)
        moving = np.empty(len(xy), bool)
        out = core.track_sweep(np.ascontiguousarray(xy, dtype=float), map_xy, np.ascontiguousarray(t, dtype=float),
                               np.ascontiguousarray(epsilon, dtype=float), seen_free, lidar, float(stamp), when,
                               cached[1], cached[2], self.x, self.cov, self.time, self.last_update, self.moving_hits,
                               moving)
        if out is None:
            return None
        new, self.x, self.cov, self.time, self.last_update, self.moving_hits = out
        return moving, new

    def _off_structure(self, found: tuple[np.ndarray, np.ndarray], grid: OccupancyGrid | None,
                       map_xy: np.ndarray) -> np.ndarray:
        """The moving mask (N,) with the points the tracks and free space label (``found``: the mask
        and those points' indices) where they are not on structure the map has seen repeatedly."""
        moving, new = found
        p = self.params
        if new.size and grid is not None and p.structure_log_odds > 0:
            new = new[local_max_log_odds(grid, map_xy[new]) < p.structure_log_odds]
        moving[new] = True
        return moving

    def seeds(self, lidar_pose: np.ndarray, when: float) -> np.ndarray:
        """Where confirmed tracks are expected at ``when`` (s), in the lidar frame ``lidar_pose``
        (K, 2): DBSCAN clusters around them too."""
        return transform_points(inverse(lidar_pose), self.predicted(when))


def placed_free_space(recent: RecentOccupancy, xy: np.ndarray, t: np.ndarray, twist: tuple[float, float],
                      mount: np.ndarray, lidar: np.ndarray, ranges: np.ndarray | None, yaw_error: float,
                      tolerance: float, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """A sweep placed in the map and its points in space seen free: ``(map_xy, seen_free)``.

    ``map_xy`` (N, 2): ``xy`` (N, 2, lidar frame at each capture time ``t`` (N,) s) de-skewed by
    ``twist`` ``(v, ω)`` (m/s, rad/s; ``mount`` (3,) the lidar in base_link) and placed by the lidar's
    pose ``lidar`` (3,) in ``map`` (:func:`~.deskew.deskew_placed`); ``seen_free`` (N,):
    :meth:`~.recent_grid.RecentOccupancy.seen_free` (``threshold``) of the points whose placement a
    yaw error of ``yaw_error`` (rad) moves by at most ``tolerance`` (m), at ``ranges`` (N,, m: the
    points' ``np.hypot``; computed where None).

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call: the same
    points as the compiled :func:`~.deskew.deskew_placed`, the same answers as the compiled lookup),
    else :func:`placed_free_space_numpy`."""
    core = compiled.core()
    v, omega = twist
    if (core is not None and sweep_columns(xy, t) and _is_pose(mount) and _is_pose(lidar) and _floats(v, omega)
            and (ranges is None or (type(ranges) is np.ndarray and ranges.dtype == np.float64
                                    and ranges.shape == t.shape and ranges.flags.c_contiguous))):
        mx, my, myaw = mount.tolist()
        x, y, yaw = lidar.tolist()
        if math.isfinite(myaw) and math.isfinite(yaw):
            log_odds, ix0, iy0 = zip(*[grid.lattice_view() for grid in recent.grids]) if recent.grids else ((), (), ())
            map_xy, out = np.empty(xy.shape), np.empty(len(xy), bool)
            core.occupancy_placed_free(list(log_odds), list(ix0), list(iy0), xy, t, ranges, v, omega, mx, my, myaw,
                                       math.cos(yaw), math.sin(yaw), x, y, float(yaw_error), float(tolerance),
                                       float(threshold), float(recent.resolution), map_xy, out)
            return map_xy, out
    return placed_free_space_numpy(recent, xy, t, twist, mount, lidar, ranges, yaw_error, tolerance, threshold)


def placed_free_space_numpy(recent: RecentOccupancy, xy: np.ndarray, t: np.ndarray, twist: tuple[float, float],
                            mount: np.ndarray, lidar: np.ndarray, ranges: np.ndarray | None, yaw_error: float,
                            tolerance: float, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`placed_free_space` as its steps: the reference the compiled kernel is tested against."""
    map_xy = deskew_placed_numpy(xy, t, twist[0], twist[1], mount, lidar)
    if ranges is None:
        ranges = np.hypot(xy[:, 0], xy[:, 1])
    placed = ranges * yaw_error <= tolerance
    return map_xy, recent.seen_free_numpy(map_xy, placed, threshold)


# arctan on [0, 1], Abramowitz & Stegun 4.4.47 (|error| < 1.2e-5 rad): the bearing bins' angle, in
# float32, the same IEEE operations in numpy and the compiled kernel (no libm arctan2: their bins are
# the same; float32 takes twice the points a vector instruction)
_ATAN = (0.9998660, -0.3302995, 0.1801410, -0.0851330, 0.0208351)


def bearing_bins(dx: np.ndarray, dy: np.ndarray, bins: int) -> np.ndarray:
    """The bin (N,, int64 in [0, ``bins``)) of the directions (``dx``, ``dy``) (N,) among ``bins``
    equal bins of the full circle from -π, by a polynomial arctangent in float32, within 1.3e-5 rad
    of the true angle. Every step is one IEEE float32 operation (the Python constants rounded to
    float32) the compiled kernel does in the same order."""
    x, y = dx.astype(np.float32), dy.astype(np.float32)
    ax, ay = np.abs(x), np.abs(y)
    z = np.minimum(ax, ay) / np.maximum(np.maximum(ax, ay), np.float32(1e-30))
    s = z * z
    a1, a3, a5, a7, a9 = (np.float32(c) for c in _ATAN)
    a = ((((a9 * s + a7) * s + a5) * s + a3) * s + a1) * z
    a = np.where(ay > ax, np.float32(math.pi / 2) - a, a)
    a = np.where(x < 0, np.float32(math.pi) - a, a)
    a = np.where(y < 0, -a, a)
    return np.floor((a + np.float32(math.pi)) * np.float32(bins / (2 * math.pi))).astype(np.int64) % bins


def lidar_origins(t: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """The lidar's position (N, 2) at the times ``t`` (N,, s) of a sweep, on the chord between
    ``ends`` (2, 2): where it was at ``t[0]`` and ``t[-1]`` (``ends[0]`` for all where those are the
    same time). Within a sweep (0.1 s) the arc departs from its chord by ``v T² ω / 8``: 5 mm at
    2 m/s and 2 rad/s, against the 0.5 m a displaced point must lie short."""
    w = (t - t[0]) / (t[-1] - t[0]) if len(t) and t[-1] != t[0] else np.zeros(len(t))
    return np.column_stack([ends[0, 0] + (ends[1, 0] - ends[0, 0]) * w, ends[0, 1] + (ends[1, 1] - ends[0, 1]) * w])


class RecentRays:
    """The rays of the last sweeps: where a point of this sweep lies well short of where an earlier
    sweep's ray at its bearing ended, that place was free then and something has moved into it
    (:meth:`sweep`). Frames and units: ``map``, m, rad.

    A sweep is kept as ``bins`` bearing bins of the full circle (:func:`bearing_bins`): per bin, the
    nearest range of the sweep's points whose bearing from the lidar *at their own capture time*
    falls in it, taken over ``window`` bins either side (inf: no return there, never free), and the
    lidar's position then (at 2 m/s the lidar moves 0.15 m within a sweep: from one origin for all,
    walls 1.5 m to the side would look seen through), with the sweep's placement yaw uncertainty
    (rad). The last ``sweeps`` are kept in a ring: ``near`` (S, B), ``origin`` (S, B, 2),
    ``yaw_errors`` (S,); the next sweep goes to slot ``head``; ``count`` are held."""

    def __init__(self, sweeps: int, window: int, bin_rad: float = math.radians(0.25)):
        """``sweeps`` (≥ 0) kept; ``window`` (≥ 0) bins either side; ``bin_rad`` (rad, > 0) a bin's width."""
        self.sweeps, self.window = sweeps, window
        self.bins = int(math.ceil(2 * math.pi / bin_rad))
        self.near = np.full((sweeps, self.bins), np.inf)
        self.origin = np.zeros((sweeps, self.bins, 2))
        self.yaw_errors = np.zeros(sweeps)
        self.head = self.count = 0

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
        """A copy of the ring: ``(near, origin, yaw_errors, head, count)``."""
        return self.near.copy(), self.origin.copy(), self.yaw_errors.copy(), self.head, self.count

    def sweep(self, map_xy: np.ndarray, t: np.ndarray, ends: np.ndarray | None, step: int, margin: float,
              yaw_error: float, tolerance: float) -> np.ndarray:
        """:meth:`displaced` of the sweep's points ``map_xy`` (N, 2) against the sweeps ``step``,
        2 ``step``, ... back, then the sweep kept (:meth:`add`): the displaced mask (N,). The lidar's
        position when each point was taken (s, ``t`` (N,)) is :func:`lidar_origins` between ``ends``
        (2, 2): where it was at ``t[0]`` and ``t[-1]`` (None: no points); ``yaw_error`` (rad), the
        sweep's placement yaw uncertainty.

        The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it and the points, times
        and ends are under 1e30 in size (one call, the same mask and ring), else :meth:`sweep_numpy`."""
        core = compiled.core()
        if (core is not None and self.sweeps > 0 and ends is not None and sweep_columns(map_xy, t)
                and type(ends) is np.ndarray and ends.dtype == np.float64 and ends.shape == (2, 2)
                and _floats(margin, yaw_error, tolerance)):
            out = np.empty(len(t), bool)
            (ax, ay), (bx, by) = ends.tolist()
            if core.rays_sweep(map_xy, t, ax, ay, bx, by, self.near, self.origin, self.yaw_errors, self.head,
                               self.count, int(step), margin, yaw_error, tolerance, self.window, out):
                self.head, self.count = (self.head + 1) % self.sweeps, min(self.count + 1, self.sweeps)
                return out
        return self.sweep_numpy(map_xy, t, ends, step, margin, yaw_error, tolerance)

    def sweep_numpy(self, map_xy: np.ndarray, t: np.ndarray, ends: np.ndarray | None, step: int, margin: float,
                    yaw_error: float, tolerance: float) -> np.ndarray:
        """:meth:`sweep` as its steps: the reference the compiled kernel is tested against."""
        out = self.displaced(map_xy, range(step, self.sweeps + 1, step), margin, yaw_error, tolerance)
        self.add(map_xy, lidar_origins(t, ends) if ends is not None else np.zeros((0, 2)), yaw_error)
        return out

    def add(self, map_xy: np.ndarray, origins: np.ndarray, yaw_error: float) -> None:
        """One sweep's points (N, 2, ``map``), the lidar's position (N, 2) when each was taken, and how
        far (rad) the sweep's placement yaw may be off."""
        if self.sweeps == 0:
            return
        d = map_xy - origins
        b = bearing_bins(d[:, 0], d[:, 1], self.bins)
        nearest = np.full(self.bins, np.inf)
        np.minimum.at(nearest, b, np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]))
        near = nearest.copy()
        for k in range(1, self.window + 1):
            near = np.minimum(near, np.minimum(np.roll(nearest, k), np.roll(nearest, -k)))
        last = np.full(self.bins, -1)
        np.maximum.at(last, b, np.arange(len(b)))  # the last point's of each bin: the lidar moves < 1 mm within a bin
        origin = np.empty((self.bins, 2))
        origin[:] = origins[len(origins) // 2] if len(origins) else 0.0
        origin[last >= 0] = origins[last[last >= 0]]
        self.near[self.head], self.origin[self.head], self.yaw_errors[self.head] = near, origin, yaw_error
        self.head, self.count = (self.head + 1) % self.sweeps, min(self.count + 1, self.sweeps)

    def displaced(self, map_xy: np.ndarray, lags: range, margin: float, yaw_error: float,
                  tolerance: float) -> np.ndarray:
        """(N,) the points of this sweep (``map``) at least ``margin`` (m) short of where the ray of
        the sweep ``lag`` sweeps back (any of ``lags``) at their bearing ended, where the largest yaw
        error (rad) of the sweeps since (``yaw_error``: this one's) moves them by at most
        ``tolerance`` (m)."""
        out = np.zeros(len(map_xy), bool)
        for lag in lags:
            if lag > self.count:
                break
            slots = (self.head - np.arange(1, lag + 1)) % self.sweeps
            slot = slots[-1]
            origin, near = self.origin[slot], self.near[slot]
            err = max(yaw_error, float(self.yaw_errors[slots].max()))
            d = map_xy - origin[0]  # a first bearing, then from the ray's own origin
            d = map_xy - origin[bearing_bins(d[:, 0], d[:, 1], self.bins)]
            r = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
            seen = near[bearing_bins(d[:, 0], d[:, 1], self.bins)]
            out |= np.isfinite(seen) & (seen > r + margin) & (r * err <= tolerance)
        return out
