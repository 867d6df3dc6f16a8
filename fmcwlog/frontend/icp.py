"""What both ICP variants share: parameters, result, nearest-neighbour pairs, one Gauss-Newton step.

Frames and units: ``source_xy`` (N, 2) in the source frame (e.g. the de-skewed
frame of a sweep, m); ``target_xy`` (M, 2) in the target frame (e.g. ``map``);
poses ``(x, y, θ)`` map source into target (``q ≈ R(θ) p + t``,
:func:`fmcwlog.geometry.transform_points`). The caller builds the target's
``cKDTree`` once and passes it in.

The variants: :mod:`fmcwlog.frontend.robust_icp` (the paper's, eq. 22-26) and
:mod:`fmcwlog.frontend.point_to_point_icp` (the classic baseline).

Correspondences (:class:`NearestPairs`): the pairs are exactly those of a KD-tree query per
iteration, but the tree is asked once per registration for each point's ``CANDIDATES`` nearest
map points (within the gate plus ``QUERY_MARGIN``, distance ``reach`` to the last), and later
iterations take the closest candidate by direct arithmetic. By the triangle inequality a point
that has moved ``s`` since it was asked has no other map point nearer than ``reach - s``, so
the candidate is exact while closer than that, and no pair exists while that exceeds the gate;
only the points failing both are asked again (0-2 % of them an iteration). Measured on the
60 s corridor log's 600 registrations replayed in one process, old and new alternating per
sweep (CPU time): the baseline's ICP 3.08 -> 2.25 and 3.49 -> 2.55 ms a sweep (-27 %), the
improved ICP with its inlier check (:func:`.recovery.inlier_fraction`, answered from the
candidates) 1.90 -> 1.65 and 2.54 -> 2.20 ms (-13 %), the same poses bit for bit.
A nearest-point grid (a distance transform with indices over the local map, one vectorised
lookup per iteration) was measured and not taken: the map spans the whole 27 m × 26 m
floor the sensor sees, so ``scipy.ndimage.distance_transform_edt`` with indices costs
11.5 ms at the map's 5 cm (2.3 ms at 10 cm, whose cell-centre answers are up to 7 cm off),
and it would be rebuilt at every keyframe (40 % of the sweeps): 0.9-4.6 ms a sweep against
the 0.2 ms a query costs and the ~4 queries a sweep makes.
Per iteration the search costs numpy calls, not arithmetic (~300-1000 points, ~1 µs a call):
the candidates are kept as x and y planes so that their distances are three broadcast-friendly
calls (an (N, 6, 2) minus (N, 1, 2) broadcast alone cost 20 µs), the source is moved in three
calls, a freshly asked point's answer is the tree's own first neighbour, and the pairs are
gathered with ``take``. The same poses bit for bit; on the 20 s long-corridor and crowd logs'
captured registrations, old and new alternating in one process (CPU time), the baseline's ICP
-19 % and -15 % a registration (with a call-lean Kabsch in :mod:`.point_to_point_icp`), the
improved ICP -8 % and -7 %. A re-ask costs a tree query's fixed ~25-50 µs whatever its size.
A compiled search (numba 0.68.1) was measured and not taken: an exact k-nearest query over
0.6 m grid buckets (the tree's own arithmetic, so the same distances; no index differed) fused
with the candidate check into one call an iteration gave every output of ``process`` bit for
bit on the 20 s crowd and 120 s corridor logs, and cut the search on the corridor's 4,045
captured registrations from 5.0 to 2.0 s CPU (crowd: 1.0 -> 0.42 s), but numba costs a fresh
process 0.8-1.0 s CPU with its on-disk cache warm (0.3 s import, 0.45-0.5 s to load the first
kernel) and ~5 s where it compiles (any new cache directory: a new container, user or
worker): about -8 % on the 120 s log's whole run, nothing or a loss on 20 s logs, and a
third of the 2.4 s issue 14 allows a 2-minute log; ``cache=True`` also fails at import where
neither the package directory nor the home directory can be written.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..config import Checked, param
from ..geometry import transform_points, wrap_angle
from .gmmsc import DistanceMixture, GMMSCParams


@dataclass(frozen=True)
class ICPParams(Checked):
    """Parameters shared by :func:`register` and :func:`register_point_to_point`.

    max_iterations: iteration cap.
    max_correspondence_distance: pairs farther apart are dropped (m).
    translation_tol, rotation_tol: stop when a step is below both (m, rad).
    min_correspondences: fewer usable pairs aborts (converged=False).
    huber_delta: Huber threshold δ on the residual norm (m); robust only.
    use_huber: weight residuals by the Huber kernel (robust only; False = plain least squares).
    use_gmmsc: apply GMMSC weights/rejection (robust only; False = Huber only).
    gmmsc: parameters of the distance mixture.
    gmm_start_translation, gmm_start_rotation: GMMSC starts once a (Huber-only)
        step is below both (m, rad); see :func:`register`.
    gmm_refit_ratio: after the first fit the mixture is refit only when the
        median pair distance leaves ``[r, 1/r] ×`` the median the mixture was
        fit to (``DistanceMixture.fit_median``; this also applies to a mixture
        reused from a previous sweep); otherwise eq. 21 is just evaluated with
        the last mixture (~0.05 ms instead of an EM run).
        ≥ 1 refits every iteration.
    extrapolate, max_extrapolation, extrapolation_min_cos, extrapolation_lever:
        step extrapolation of the robust variant (``_extrapolation_factor``);
        halves the iterations in our tests at unchanged accuracy.
    workers: threads for the KD-tree query (1: the per-sweep budget is tiny).
    """

    max_iterations: int = param(30, "", ge=1, le=1000)
    max_correspondence_distance: float = param(0.5, "m", gt=0.0, le=100.0)
    # tolerances: a zero tolerance never stops before max_iterations; 1 m / 1 rad steps are not convergence
    translation_tol: float = param(1e-4, "m", gt=0.0, le=1.0)
    rotation_tol: float = param(5e-5, "rad", gt=0.0, le=1.0)
    # fewer than 2 pairs leave the 3 unknowns of an SE(2) step undetermined
    min_correspondences: int = param(10, "pairs", ge=2, le=1_000_000)
    # δ beyond 1 m makes the kernel plain least squares for any pair the 0.5 m gate lets through
    huber_delta: float = param(0.05, "m", gt=0.0, le=1.0)
    use_huber: bool = True
    use_gmmsc: bool = True
    gmmsc: GMMSCParams = field(default_factory=GMMSCParams)
    gmm_start_translation: float = param(2e-3, "m", gt=0.0, le=1.0)
    gmm_start_rotation: float = param(2e-3, "rad", gt=0.0, le=1.0)
    gmm_refit_ratio: float = param(0.25, "", gt=0.0, le=1.0)  # 1 refits every iteration; above 1 means the same
    extrapolate: bool = True
    max_extrapolation: float = param(10.0, "", ge=0.0, le=100.0)  # extra steps; 0 never extrapolates
    extrapolation_min_cos: float = param(0.9, "", ge=-1.0, le=1.0)
    extrapolation_lever: float = param(3.0, "m", ge=0.0, le=100.0)  # turns rad into m to compare steps
    workers: int = param(1, "threads", ge=1, le=1024)  # scipy's -1 (all cores) is not offered: sweeps are tiny


@dataclass
class ICPResult:
    """Registration result.

    pose: (3,) source-to-target pose (m, m, rad).
    iterations: iterations run.
    n_correspondences_kept: pairs used in the last step (within the gate and,
        for the robust variant, kept by GMMSC).
    converged: the last step was below tolerance.
    rmse: RMS distance of the kept pairs at the last iteration (m).
    hessian: (3, 3) ``JᵀWJ`` of the last step (information up to the noise scale).
    n_gmm_fits: EM fits run (robust variant; 0 for the baseline).
    mixture: the distance mixture last used (robust variant), reusable as the
        next sweep's ``mixture`` to skip the EM fit.
    search: the registration's correspondence search: the nearest map distances at the final
        pose from it (:meth:`NearestPairs.nearest`) cost few or no new queries.
    """

    pose: np.ndarray
    iterations: int
    n_correspondences_kept: int
    converged: bool
    rmse: float
    hessian: np.ndarray
    n_gmm_fits: int = 0
    mixture: DistanceMixture | None = None
    search: NearestPairs | None = None


@dataclass
class Correspondences:
    """Nearest-neighbour pairs within the distance gate.

    source_idx (K,): indices into ``source_xy``; moved (K, 2): those points in
    the target frame under the current pose; target (K, 2): their nearest target
    points; distances (K,): ``‖moved - target‖`` (m).
    """

    source_idx: np.ndarray
    moved: np.ndarray
    target: np.ndarray
    distances: np.ndarray


def find_correspondences(
    source_xy: np.ndarray,
    pose: np.ndarray,
    target_tree: cKDTree,
    target_xy: np.ndarray,
    max_distance: float,
    workers: int = 1,
) -> Correspondences:
    """Transform the source by ``pose`` and pair each point with its nearest target point.

    Pairs farther than ``max_distance`` (m) are dropped (the tree's
    ``distance_upper_bound`` prunes the search itself).
    """
    moved = transform_points(pose, source_xy)
    dist, idx = target_tree.query(
        moved, k=1, distance_upper_bound=max_distance, workers=workers
    )
    ok = np.isfinite(dist)
    src = np.flatnonzero(ok)
    return Correspondences(src, moved[ok], target_xy[idx[ok]], dist[ok])


QUERY_MARGIN = 0.1  # m beyond the gate the tree is asked about: a point moves this far before its "none" expires
CANDIDATES = 6  # nearest map points kept per source point (module docstring: 4 gave the baseline -18 %, 6 -27 %)


class NearestPairs:
    """The nearest target point of every source point under successive poses (module docstring).

    ``source_xy`` (N, 2) in the source frame, ``target_tree`` over ``target_xy`` (M, 2);
    :meth:`pairs` answers as :func:`find_correspondences` would for the same pose, querying
    the tree only for the points whose answer may lie outside their stored candidates.

    Layout, for few numpy calls an iteration (each costs ~1 µs; the arrays are ~300-1000 points):
    the candidates' coordinates as one (N, CANDIDATES, 2) array, so that the distances of all
    of them are three calls; the answer kept as a flat index into it (row × CANDIDATES + column),
    which gives a pair's target point by one ``take`` and its map index by another.
    """

    def __init__(self, source_xy: np.ndarray, target_tree: cKDTree, target_xy: np.ndarray,
                 max_distance: float, workers: int = 1):
        self.source = source_xy
        self.tree = target_tree
        self.target = target_xy
        self.gate = max_distance
        self.bound = max_distance + QUERY_MARGIN
        self.workers = workers
        self._padded = np.vstack([target_xy, [np.inf, np.inf]])  # the tree's "none" index is M: infinitely far
        n = len(source_xy)
        self._at = np.empty((n, 2))  # where each point was when the tree was last asked (target frame)
        self._candidates = np.empty((n, CANDIDATES), np.int64)  # its nearest target indices then
        self._xy = np.empty((n, CANDIDATES, 2))  # and their coordinates, one candidate a row
        self._flat_xy = self._xy.reshape(n * CANDIDATES, 2)  # a view
        self._by_axis = np.empty((2, CANDIDATES, n))  # the same coordinates as x and y planes (fast broadcasts)
        self._d2 = np.empty((n, CANDIDATES))  # squared distances to them, filled each iteration
        self._first = np.arange(n) * CANDIDATES  # flat index of each point's first (nearest when asked)
        self._swapped = source_xy[:, ::-1].copy()  # (y, x) of each source point: the rotation in 3 calls
        self._reach = np.zeros(n)  # every other target point was at least this far from it then, m
        self._asked = False

    def _ask(self, moved: np.ndarray, which: np.ndarray | slice) -> np.ndarray:
        """Query the tree for ``moved[which]``, store the answers and return the nearest's distance
        (the tree's own ``√((Δx)² + (Δy)²)``, the arithmetic of :meth:`_closest`)."""
        pts = moved[which]
        d, idx = self.tree.query(pts, k=CANDIDATES, distance_upper_bound=self.bound, workers=self.workers)
        self._at[which], self._candidates[which] = pts, idx
        self._xy[which] = q = self._padded[idx]
        self._by_axis[:, :, which] = q.T
        self._reach[which] = np.minimum(d[:, -1], self.bound) - 1e-9  # less the distances' rounding
        return d[:, 0]

    def _closest(self, moved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For every moved point: the flat index of its closest stored candidate and its distance."""
        diff = self._by_axis - moved.T[:, None, :]
        diff *= diff
        d2 = self._d2
        np.add(diff[0], diff[1], out=d2.T)  # the tree's own arithmetic: (Δx)² + (Δy)², then the root
        flat = d2.argmin(axis=1)
        flat += self._first
        return flat, np.sqrt(d2.take(flat))

    def _moved(self, pose: np.ndarray) -> np.ndarray:
        """The source (N, 2) under ``pose``: :func:`~fmcwlog.geometry.transform_points`, the same
        operations in the same order (``c x - s y + t_x``, ``s x + c y + t_y``), in three calls."""
        pose = np.asarray(pose, dtype=float)
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        moved = self.source * c
        moved += self._swapped * np.array((-s, s))  # -(s y) = (-s) y exactly; the sums commute exactly
        moved += pose[:2]
        return moved

    def _search(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Under ``pose``: the moved source (N, 2), each point's answer as a flat candidate index
        (N,) and its distance (N,), above the gate (possibly inf) where no target point is within it."""
        moved = self._moved(pose)
        if not self._asked:
            self._asked = True
            return moved, self._first.copy(), self._ask(moved, slice(None))
        flat, dist = self._closest(moved)
        # a target point outside the candidates was at least ``reach`` from the point's anchor, so
        # at least ``limit = reach - s`` from it now (moved by s): the candidate wins while closer
        # than that, and nothing is within the gate while that exceeds the gate; both fail where
        # limit <= min(distance, gate)
        shift = moved - self._at
        shift *= shift
        limit = self._reach - np.sqrt(shift[:, 0] + shift[:, 1])
        unsure = np.flatnonzero(limit <= np.minimum(dist, self.gate))
        if unsure.size:
            dist[unsure] = self._ask(moved, unsure)
            flat[unsure] = self._first[unsure]
        return moved, flat, dist

    def nearest(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Under ``pose``: the moved source (N, 2), each point's nearest target index (N,) and its
        distance (N,); where no target point is within the gate, the distance is above the gate
        (possibly inf) and the index is not to be used."""
        moved, flat, dist = self._search(pose)
        return moved, self._candidates.take(flat), dist

    def pairs(self, pose: np.ndarray) -> Correspondences:
        """The pairs within the gate under ``pose``, as :func:`find_correspondences` gives them."""
        moved, flat, dist = self._search(pose)
        src = np.flatnonzero(dist < self.gate)
        return Correspondences(src, moved.take(src, axis=0), self._flat_xy.take(flat.take(src), axis=0),
                               dist.take(src))


def gauss_newton_step(
    moved: np.ndarray,
    target: np.ndarray,
    pose: np.ndarray,
    weights: np.ndarray,
    prior_pose: np.ndarray | None = None,
    prior_information: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One weighted Gauss-Newton step on ``(x, y, θ)`` for point-to-point residuals.

    ``moved`` = ``R p + t`` (K, 2) under ``pose``; residual ``e = moved - target``
    (eq. 24 with the opposite sign); ``∂e/∂(x, y, θ) = [I | (-(Rp)_y, (Rp)_x)]``
    (eq. 25). Returns ``Δ = -(JᵀWJ)⁻¹ JᵀWe`` (eq. 26 as corrected in NOTES.md)
    and ``H = JᵀWJ``. Sums are formed in closed form, no (K, 3) Jacobian.

    Optional Gaussian prior (not in the paper): adds ``(x - x_p)ᵀ Λ (x - x_p)``
    to the cost, i.e. ``H += Λ``, ``g += Λ (x - x_p)`` (yaw difference wrapped).
    ``Λ`` must be in the units of the weighted squared residuals (an inverse
    prior covariance times the residual variance).
    """
    rp = moved - pose[:2]  # R p
    ax, ay = -rp[:, 1], rp[:, 0]  # ∂(Rp)/∂θ
    e = moved - target
    w = weights
    sw = w.sum()
    swax, sway = w @ ax, w @ ay
    h = np.array(
        [
            [sw, 0.0, swax],
            [0.0, sw, sway],
            [swax, sway, w @ (ax * ax + ay * ay)],
        ]
    )
    g = np.array([w @ e[:, 0], w @ e[:, 1], w @ (ax * e[:, 0] + ay * e[:, 1])])
    if prior_pose is not None and prior_information is not None:
        dp = np.asarray(pose, float) - np.asarray(prior_pose, float)
        dp[2] = wrap_angle(dp[2])
        lam = np.asarray(prior_information, float)
        h = h + lam
        g = g + lam @ dp
    try:
        delta = -np.linalg.solve(h, g)
    except np.linalg.LinAlgError:
        delta = -np.linalg.lstsq(h, g, rcond=None)[0]
    return delta, h


def step_is_small(step: np.ndarray, p: ICPParams) -> bool:
    return bool(np.hypot(step[0], step[1]) < p.translation_tol and abs(step[2]) < p.rotation_tol)
