"""Errors and disagreements along the path, for the report's plots: pure numpy, no file I/O.

Poses are planar ``(x, y, yaw)`` in metres and radians, stamps in seconds (as in
:mod:`fmcwlog.evaluation.metrics`, whose association, alignment and RPE these reuse).

- :func:`path_distance`: distance travelled along a trajectory, m.
- :func:`heading_errors`: signed yaw error of an (aligned) estimate, degrees.
- :func:`rpe_series`: the RPE of every pair of :func:`metrics.rpe`, placed at the
  distance travelled (on the reference) where the pair starts: ``evo_rpe``'s per-pair
  values against distance rather than only their mean.
- :func:`disagreement`: how far two estimates of the same run are apart once one is
  SE(2)-aligned onto the other (Umeyama, no scale, as :func:`metrics.align_se2`). With
  no ground truth this is what can be said: it is a *disagreement*, not an error — the
  reference trajectory is itself an estimate, and least-squares alignment spreads a
  drift over the whole path (a copy scaled by ``s`` about any point is ``|s - 1|`` times
  its distance from the centroid away, not from the start).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import compose, wrap_angle
from .metrics import ErrorStats, align_se2, error_statistics, interpolate_reference, rpe


def path_distance(poses: np.ndarray) -> np.ndarray:
    """Distance travelled (N,) in m from the first pose to each pose, summing the straight steps."""
    xy = np.asarray(poses, dtype=float)[:, :2]
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def heading_errors(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Signed heading error ``yaw_est - yaw_ref`` (N,) in degrees, wrapped to [-180, 180).

    ``est`` must be expressed in the reference's frame (aligned) and associated row by row.
    """
    return np.rad2deg(wrap_angle(np.asarray(est, dtype=float)[:, 2] - np.asarray(ref, dtype=float)[:, 2]))


@dataclass(frozen=True)
class RPESeries:
    """Per-pair relative pose error over ``delta`` metres (evo's consecutive pairs on the reference).

    ``start_m[k]``: distance travelled on the reference where pair k starts (m);
    ``trans_pct[k]``: translation error, % of ``delta`` (the mean is the report's ``rpe_*_pct``);
    ``rot_deg_per_m[k]``: yaw error per metre of ``delta`` (deg/m).
    """

    delta: float
    start_m: np.ndarray
    trans_pct: np.ndarray
    rot_deg_per_m: np.ndarray


def rpe_series(est: np.ndarray, ref: np.ndarray, delta: float) -> RPESeries:
    """Every pair of :func:`metrics.rpe` (``est`` and ``ref`` associated row by row).

    Raises ``ValueError`` as :func:`metrics.rpe` does when no pair spans ``delta``."""
    r = rpe(est, ref, delta)
    start = path_distance(ref)[r.pairs[:, 0]]
    return RPESeries(float(delta), start, 100.0 * r.trans_errors / delta, r.rot_errors_deg / delta)


@dataclass(frozen=True)
class Disagreement:
    """How far an estimate is from a reference estimate after SE(2) alignment onto it.

    ``t`` (K,) s: the stamps compared (the other's stamps inside the reference's span);
    ``along_m`` (K,): distance travelled along the reference there; ``gap_m`` (K,): the
    distance between the two positions; ``aligned`` (K, 3): the other, in the reference's frame.
    """

    t: np.ndarray
    along_m: np.ndarray
    gap_m: np.ndarray
    aligned: np.ndarray
    stats: ErrorStats

    def summary(self) -> dict[str, float | int]:
        """The numbers report.json keeps (m; ``path_m`` is the reference's length over the compared span)."""
        s = self.stats
        return {"rmse_m": s.rmse, "mean_m": s.mean, "median_m": s.median, "max_m": s.max,
                "final_m": float(self.gap_m[-1]), "path_m": float(self.along_m[-1] - self.along_m[0]),
                "poses": s.n}


def disagreement(t_ref: np.ndarray, ref: np.ndarray, t_other: np.ndarray, other: np.ndarray) -> Disagreement:
    """Align ``other`` (stamps ``t_other`` s, poses (M, 3)) onto ``ref`` and measure the gap.

    The reference is resampled at the other's stamps (:func:`metrics.interpolate_reference`;
    stamps outside its span are dropped), ``other`` is aligned with :func:`metrics.align_se2`,
    and the gap is the distance between positions, m.

    Raises:
        ValueError: if fewer than two of the other's stamps fall within the reference's span.
    """
    idx, ref_at = interpolate_reference(t_other, t_ref, ref)
    if idx.size < 2:
        raise ValueError("fewer than two common stamps")
    o = np.asarray(other, dtype=float)[idx]
    aligned = compose(align_se2(o[:, :2], ref_at[:, :2]), o)
    gap = np.linalg.norm(aligned[:, :2] - ref_at[:, :2], axis=1)
    along = path_distance(ref_at)
    return Disagreement(np.asarray(t_other, dtype=float)[idx], along, gap, aligned, error_statistics(gap))
