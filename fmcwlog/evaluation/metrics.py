"""Trajectory metrics: association, alignment, ATE, RPE and feature-length errors.

Pure numpy functions, no file I/O. Trajectories are planar: timestamps ``t``
of shape (N,) in seconds and poses of shape (N, 3) = ``(x, y, yaw)`` in metres
and radians (yaw counter-clockwise positive, REP-103). Reference ("ref",
ground truth) and estimate ("est") poses are expressed in their own world
frames; the alignment functions return the SE(2) transform ``T`` (a pose
``(x, y, yaw)``) that maps the estimate's world frame into the reference's
world frame, i.e. ``compose(T, est) ≈ ref``.

The definitions follow evo (github.com/MichaelGrupp/evo, checked against
v1.38.1):

* statistics (:class:`ErrorStats`) are computed exactly like
  ``evo.core.metrics.PE.get_statistic`` (population std, ``ddof=0``);
* :func:`ate` is ``evo_ape`` with ``--pose_relation trans_part``;
  ``alignment='se2'`` is ``-a`` (Umeyama, no scale), ``'first'`` is
  ``--align_origin``;
* :func:`rpe` is ``evo_rpe --delta D --delta_unit m`` with consecutive pairs
  (``--all_pairs`` off); pairs are taken on the reference by default
  (``--pairs_from_reference``), which is *not* evo's default (evo selects
  pairs on the estimate unless that flag is given); ``pairs_from='estimate'``
  reproduces evo's default.

The report pairs a 10 Hz estimate with 50 Hz ground truth by
:func:`interpolate_reference`: the reference is resampled at the estimate's
stamps (linear in x, y, shortest-arc linear in yaw, which for planar poses
equals evo's position lerp + quaternion slerp). Estimate stamps outside the
reference's time span are dropped (no extrapolation). evo's
``SyncMethod.interpolation`` gives the same poses for every estimate stamp
inside the reference's span that also has a reference stamp within
``max_diff``; unlike evo, stamps with no reference sample nearby are kept (use
``max_gap`` to drop them) and stamps just outside the span are dropped instead
of clamped to the end pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..geometry import between, compose, interpolate_poses, inverse, wrap_angle

__all__ = [
    "ErrorStats",
    "ATEResult",
    "RPEResult",
    "FeatureLengthError",
    "error_statistics",
    "interpolate_reference",
    "align_se2",
    "align_first_pose",
    "ate",
    "path_pairs",
    "rpe",
    "feature_length_errors",
    "mean_relative_error_pct",
    "relative_reduction_pct",
]


# --------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ErrorStats:
    """Summary statistics of an error array, in the errors' own unit.

    Computed as ``evo.core.metrics.PE.get_statistic``: ``rmse = sqrt(mean(e²))``,
    ``std`` is the population standard deviation (``ddof=0``), ``sse = sum(e²)``.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int


def error_statistics(errors: np.ndarray) -> ErrorStats:
    """Statistics of a non-empty 1-D error array, exactly as evo computes them."""
    e = np.asarray(errors, dtype=float)
    if e.ndim != 1 or e.size == 0:
        raise ValueError(f"need a non-empty 1-D error array, got shape {e.shape}")
    sq = np.power(e, 2)
    return ErrorStats(
        rmse=math.sqrt(np.mean(sq)),
        mean=float(np.mean(e)),
        median=float(np.median(e)),
        std=float(np.std(e)),
        min=float(np.min(e)),
        max=float(np.max(e)),
        sse=float(np.sum(sq)),
        n=int(e.size),
    )


# --------------------------------------------------------------------------
# time association
# --------------------------------------------------------------------------


def _check_stamps(t: np.ndarray, name: str) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array of seconds, got shape {t.shape}")
    return t


def interpolate_reference(
    t_est: np.ndarray,
    t_ref: np.ndarray,
    ref_poses: np.ndarray,
    max_gap: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Resample the reference at the estimate's stamps (the report's association).

    x and y are interpolated linearly; yaw linearly along the shorter arc
    between neighbouring reference samples (``geometry.interpolate_poses``).
    Estimate stamps outside ``[t_ref[0], t_ref[-1]]`` are dropped rather than
    extrapolated or clamped.

    Args:
        t_est: estimate stamps (N_est,), seconds.
        t_ref: reference stamps (N_ref,), seconds, strictly increasing.
        ref_poses: reference poses (N_ref, 3), (m, m, rad), reference world frame.
        max_gap: if given, also drop estimate stamps whose two bracketing
            reference samples are more than ``max_gap`` seconds apart
            (ground-truth dropouts), unless the stamp hits a reference stamp.

    Returns:
        ``(idx_est, ref_at_est)``: indices (K,) of the kept estimate stamps and
        the reference poses (K, 3) at those stamps, so ``est[idx_est]`` pairs
        with ``ref_at_est``.

    Raises:
        ValueError: if no estimate stamp falls inside the reference's span.
    """
    t_est = _check_stamps(t_est, "t_est")
    t_ref = _check_stamps(t_ref, "t_ref")
    ref_poses = _check_poses(ref_poses, "ref_poses")
    if ref_poses.shape[0] != t_ref.size:
        raise ValueError("t_ref and ref_poses must have the same length")
    if t_ref.size < 2 or np.any(np.diff(t_ref) <= 0):
        raise ValueError("t_ref must hold at least two strictly increasing stamps")
    keep = (t_est >= t_ref[0]) & (t_est <= t_ref[-1])
    if max_gap is not None:
        j = np.clip(np.searchsorted(t_ref, t_est, side="left"), 1, t_ref.size - 1)
        exact = (t_ref[j] == t_est) | (t_ref[j - 1] == t_est)
        keep &= exact | (t_ref[j] - t_ref[j - 1] <= max_gap)
    idx_est = np.flatnonzero(keep)
    if idx_est.size == 0:
        raise ValueError("no estimate stamp inside the reference's time span")
    return idx_est, interpolate_poses(t_est[idx_est], t_ref, ref_poses)


# --------------------------------------------------------------------------
# alignment
# --------------------------------------------------------------------------


def _check_poses(p: np.ndarray, name: str) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ValueError(f"{name} must have shape (N, 3) = (x, y, yaw), got {p.shape}")
    return p


def _check_pair(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    est = _check_poses(est, "est_poses")
    ref = _check_poses(ref, "ref_poses")
    if est.shape != ref.shape:
        raise ValueError(
            f"est and ref must be associated (same length), got {est.shape} and {ref.shape}"
        )
    return est, ref


def align_se2(est_xy: np.ndarray, ref_xy: np.ndarray) -> np.ndarray:
    """Least-squares rigid alignment of estimated positions onto reference positions.

    Umeyama's method without scale (Kabsch) in 2-D: finds the rotation ``R``
    (a proper rotation, det +1) and translation ``t`` minimising
    ``sum_i |R est_i + t - ref_i|²``.

    On planar data this equals evo's 3-D ``align(correct_scale=False)``
    whenever the best orthogonal fit is a proper rotation, which is the case
    for any sensible estimate. Two differences: evo's 3-D fit may pick a
    180° roll (an in-plane mirror) when the estimate is mirrored, and evo
    refuses collinear (straight-line) data, which is well posed here.

    Args:
        est_xy: estimated positions (N, 2) in m (extra columns, e.g. yaw, are
            ignored), estimate world frame.
        ref_xy: reference positions (N, 2) in m, reference world frame.

    Returns:
        ``T = (x, y, yaw)`` (3,): estimate world frame expressed in the
        reference world frame, so ``compose(T, est)`` is the aligned estimate.

    Raises:
        ValueError: on mismatched shapes or if all points coincide (rotation
            undetermined).
    """
    x = np.asarray(est_xy, dtype=float)[:, :2]
    y = np.asarray(ref_xy, dtype=float)[:, :2]
    if x.shape != y.shape or x.shape[0] == 0:
        raise ValueError(f"need two non-empty (N, 2) position arrays, got {x.shape}, {y.shape}")
    mean_x = x.mean(axis=0)
    mean_y = y.mean(axis=0)
    cov = (y - mean_y).T @ (x - mean_x) / x.shape[0]  # Umeyama eq. 38
    u, d, vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(float).eps) < 1:
        raise ValueError("degenerate positions (all identical): rotation is undetermined")
    s = np.eye(2)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s[1, 1] = -1.0  # keep a proper rotation (Kabsch)
    r = u @ s @ vt
    t = mean_y - r @ mean_x
    return np.array([t[0], t[1], math.atan2(r[1, 0], r[0, 0])])


def align_first_pose(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Transform mapping the first estimated pose onto the first reference pose.

    ``T = ref[0] ⊕ ⊖est[0]``, so ``compose(T, est[0]) == ref[0]``
    (evo's ``align_origin``). Only the first rows are used.

    Args:
        est: estimated poses (N, 3) or a single pose (3,), estimate world frame.
        ref: reference poses (M, 3) or (3,), reference world frame.

    Returns:
        ``T = (x, y, yaw)`` (3,) in the reference world frame.
    """
    e0 = np.atleast_2d(np.asarray(est, dtype=float))[0]
    r0 = np.atleast_2d(np.asarray(ref, dtype=float))[0]
    return compose(r0, inverse(e0))


# --------------------------------------------------------------------------
# ATE
# --------------------------------------------------------------------------


Alignment = Literal["se2", "first", "none"]


@dataclass(frozen=True)
class ATEResult:
    """Absolute trajectory error (translation part), metres.

    ``errors[i] = |xy(compose(transform, est[i])) - xy(ref[i])|``.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    errors: np.ndarray  # (N,) m
    alignment: str
    transform: np.ndarray  # (3,) estimate world frame in the reference world frame
    est_aligned: np.ndarray  # (N, 3) aligned estimate, reference world frame

    @property
    def stats(self) -> ErrorStats:
        return error_statistics(self.errors)


def ate(est_poses: np.ndarray, ref_poses: np.ndarray, alignment: Alignment = "se2") -> ATEResult:
    """Translation-part absolute trajectory error, as ``evo_ape --pose_relation trans_part``.

    Args:
        est_poses: estimated poses (N, 3), estimate world frame, already
            associated with ``ref_poses`` row by row (see
            :func:`interpolate_reference`).
        ref_poses: reference poses (N, 3), reference world frame.
        alignment: ``'se2'`` least-squares rigid alignment of the positions
            (:func:`align_se2`, evo ``-a`` without ``-s``); ``'first'`` align
            the first pose (:func:`align_first_pose`, evo ``--align_origin``);
            ``'none'`` compare as given.

    Returns:
        :class:`ATEResult` with errors in metres.
    """
    est, ref = _check_pair(est_poses, ref_poses)
    if alignment == "se2":
        transform = align_se2(est[:, :2], ref[:, :2])
    elif alignment == "first":
        transform = align_first_pose(est, ref)
    elif alignment == "none":
        transform = np.zeros(3)
    else:
        raise ValueError(f"alignment must be 'se2', 'first' or 'none', got {alignment!r}")
    aligned = compose(transform, est) if alignment != "none" else est.copy()
    errors = np.linalg.norm(aligned[:, :2] - ref[:, :2], axis=1)
    s = error_statistics(errors)
    return ATEResult(
        rmse=s.rmse,
        mean=s.mean,
        median=s.median,
        std=s.std,
        min=s.min,
        max=s.max,
        sse=s.sse,
        errors=errors,
        alignment=alignment,
        transform=transform,
        est_aligned=aligned,
    )


# --------------------------------------------------------------------------
# RPE
# --------------------------------------------------------------------------


def path_pairs(xy: np.ndarray, delta: float) -> np.ndarray:
    """Consecutive index pairs ~``delta`` metres of travelled path apart.

    Exactly ``evo.core.filters.filter_pairs_by_path(..., all_pairs=False)``:
    starting at index 0, the path length is accumulated step by step
    (``+= |p_k - p_{k-1}|``) and the first index where it reaches
    ``>= delta`` closes the pair and starts the next one, the accumulator
    restarting at 0 (so each pair spans at least ``delta``, the overshoot is
    not carried over). The running sum is formed with the same sequential
    float additions as evo (``np.cumsum`` restarted at each pair start), so
    boundary cases such as ten 0.1 m steps (sum 0.9999999999999999 < 1) come
    out identically; only the step lengths themselves may differ from evo's
    (3-D BLAS dot) in the last bit. Loops once per pair, not per pose.

    Args:
        xy: positions (N, 2+) in m (extra columns ignored).
        delta: path distance in m, ``>= 0``.

    Returns:
        int array (K, 2) of ``(i, j)`` pairs; K may be 0.
    """
    if delta < 0:
        raise ValueError("delta must be >= 0")
    p = np.asarray(xy, dtype=float)[:, :2]
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)  # steps[k]: pose k -> k+1
    n_steps = steps.size
    cum = np.concatenate([[0.0], np.cumsum(steps)])  # only to guess window sizes
    ids = [0]
    j = 0
    while j < n_steps:
        guess = int(np.searchsorted(cum, cum[j] + delta, side="left"))
        width = max(guess - j + 8, 16)
        while True:
            local = np.cumsum(steps[j : j + width])  # evo's accumulator from pose j
            hit = np.flatnonzero(local >= delta)
            if hit.size or j + width >= n_steps:
                break
            width *= 2
        if not hit.size:
            break
        j = j + int(hit[0]) + 1
        ids.append(j)
    ids_arr = np.asarray(ids, dtype=int)
    return np.stack([ids_arr[:-1], ids_arr[1:]], axis=1)


@dataclass(frozen=True)
class RPEResult:
    """Relative pose error over ``delta`` metres of travelled path.

    For each pair (i, j): ``E = ⊖(⊖ref_i ⊕ ref_j) ⊕ (⊖est_i ⊕ est_j)`` (evo's
    ``rpe_base``); ``trans_errors = |xy(E)|`` in m (this equals the distance
    between the reference and estimated displacement, expressed in the frame
    of pose i), ``rot_errors_deg = |yaw(E)|`` in degrees, in [0, 180].

    ``trans_pct`` is ``100 * trans_errors / delta`` (% of the nominal
    distance, the usual "translation error in % of distance travelled") and
    ``rot_deg_per_m`` is ``rot_errors_deg / delta``. Because each pair spans
    at least ``delta`` (see :func:`path_pairs`), ``path_lengths`` gives the
    actual reference path length of each pair for callers who prefer to
    normalise by it.
    """

    delta: float  # m
    pairs: np.ndarray  # (K, 2) int indices into the associated trajectories
    pairs_from: str
    trans_errors: np.ndarray  # (K,) m
    rot_errors_deg: np.ndarray  # (K,) deg
    path_lengths: np.ndarray  # (K,) m, reference path length between i and j
    trans: ErrorStats  # m
    trans_pct: ErrorStats  # % of delta
    rot_deg: ErrorStats  # deg
    rot_deg_per_m: ErrorStats  # deg / m


def rpe(
    est_poses: np.ndarray,
    ref_poses: np.ndarray,
    delta: float,
    delta_unit: Literal["m"] = "m",
    pairs_from: Literal["reference", "estimate"] = "reference",
) -> RPEResult:
    """Relative pose error over ``delta`` metres, as ``evo_rpe`` with consecutive pairs.

    Equivalent to ``evo_rpe --delta delta --delta_unit m --pairs_from_reference``
    (``--all_pairs`` off), for ``PoseRelation.translation_part`` (m) and
    ``rotation_angle_deg`` (deg). ``pairs_from='estimate'`` reproduces evo's
    default (pairs chosen on the estimate's path). The RPE does not depend on
    any rigid alignment of the estimate, so none is applied.

    Args:
        est_poses: estimated poses (N, 3), estimate world frame, associated
            row by row with ``ref_poses``.
        ref_poses: reference poses (N, 3), reference world frame.
        delta: travelled distance per pair, metres (> 0).
        delta_unit: only ``'m'`` is implemented.
        pairs_from: which trajectory's travelled path selects the pairs.

    Returns:
        :class:`RPEResult`.

    Raises:
        ValueError: on bad arguments or if no pair spans ``delta`` (evo raises
            ``FilterException``).
    """
    est, ref = _check_pair(est_poses, ref_poses)
    if delta_unit != "m":
        raise ValueError(f"only delta_unit='m' is implemented, got {delta_unit!r}")
    if not delta > 0:
        raise ValueError("delta must be > 0 metres")
    if pairs_from not in ("reference", "estimate"):
        raise ValueError("pairs_from must be 'reference' or 'estimate'")
    pairs = path_pairs(ref if pairs_from == "reference" else est, delta)
    if pairs.shape[0] == 0:
        raise ValueError(f"delta = {delta} m produced no pairs (trajectory too short)")
    i, j = pairs[:, 0], pairs[:, 1]
    err = between(between(ref[i], ref[j]), between(est[i], est[j]))
    trans = np.linalg.norm(err[:, :2], axis=1)
    rot_deg = np.rad2deg(np.abs(wrap_angle(err[:, 2])))
    steps = np.linalg.norm(np.diff(ref[:, :2], axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(steps)])
    return RPEResult(
        delta=float(delta),
        pairs=pairs,
        pairs_from=pairs_from,
        trans_errors=trans,
        rot_errors_deg=rot_deg,
        path_lengths=cum[j] - cum[i],
        trans=error_statistics(trans),
        trans_pct=error_statistics(100.0 * trans / delta),
        rot_deg=error_statistics(rot_deg),
        rot_deg_per_m=error_statistics(rot_deg / delta),
    )


# --------------------------------------------------------------------------
# feature lengths (paper Tables 2 and 3)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class FeatureLengthError:
    """Error of one measured feature length (e.g. a wall) against its true length."""

    true_m: float
    measured_m: float
    abs_error_m: float  # |measured - true|, m
    rel_error_pct: float  # 100 * abs_error / true, %


def feature_length_errors(
    true_lengths: np.ndarray, measured_lengths: np.ndarray
) -> list[FeatureLengthError]:
    """Per-feature absolute and relative length errors.

    Args:
        true_lengths: true lengths (K,), metres, all > 0.
        measured_lengths: measured lengths (K,), metres.

    Returns:
        One :class:`FeatureLengthError` per feature, in input order. (The
        functions are unit-agnostic except for the ``_m`` field names: pass
        millimetres and the absolute errors are in millimetres.)
    """
    t = np.asarray(true_lengths, dtype=float)
    m = np.asarray(measured_lengths, dtype=float)
    if t.shape != m.shape or t.ndim != 1:
        raise ValueError("true and measured lengths must be 1-D arrays of the same length")
    if np.any(t <= 0):
        raise ValueError("true lengths must be positive")
    abs_err = np.abs(m - t)
    rel = 100.0 * abs_err / t
    return [
        FeatureLengthError(float(a), float(b), float(c), float(d))
        for a, b, c, d in zip(t, m, abs_err, rel)
    ]


def mean_relative_error_pct(records: list[FeatureLengthError]) -> float:
    """Average of the per-feature relative errors, % (the papers' 'average relative error')."""
    if not records:
        raise ValueError("no records")
    return float(np.mean([r.rel_error_pct for r in records]))


def relative_reduction_pct(before: float, after: float) -> float:
    """Relative reduction ``100 * (before - after) / before``, % (e.g. 6.05 → 3.59 is 40.6 %)."""
    if before == 0:
        raise ValueError("before must be non-zero")
    return 100.0 * (before - after) / before
