"""Static / moving segmentation of one sweep by position and Doppler (paper §4.1).

Frames and units: ``xy`` (N, 2) in the lidar frame (m); ``epsilon`` (N,) the
ego-motion-compensated radial velocity ``ε = v_r + uᵀ v_s`` (m/s) from
:func:`fmcwlog.frontend.egomotion.compensated_velocity`.

Eq. 17 clusters with DBSCAN under ``dist² = Δx² + Δy² + α Δv²``; embedding each
point as ``(x, y, √α·v)`` makes that the plain Euclidean metric.

Departure from the paper: Wang et al.'s eq. 18-19 threshold the raw Doppler ``v_r``,
which only works while the robot stands still: a moving sensor sees every static point
with ``v_r = -uᵀ v_s ≠ 0``. Here the clustering and the threshold use the compensated
``ε`` instead, and the decision is per cluster, so the clearly moving points of an object
carry its points whose motion is perpendicular to the beam (``ε ≈ 0``; the physics notes,
docs/physics.md).

DBSCAN is :func:`dbscan` here rather than sklearn's: the neighbourhood graph from
one ``cKDTree.query_pairs`` and its components by hooking roots under the lowest node
and following pointers (:func:`_lowest_connected`), which gives
sklearn's labels exactly (``tests/unit/frontend/test_segmentation.py`` compares them) at 0.56
against 2.0 ms per sweep on the corridor log and 2.0 against 5.2 ms on the crowd
log (the same machine, busy; the order of the two held on repeats), and saves the
1.5 s import of sklearn. How the components are found, and what the alternatives cost:
docs/design/speed-experiments.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Checked, param
from ..kernels import compiled


@dataclass(frozen=True)
class SegmentationParams(Checked):
    """Parameters of :func:`segment_moving`.

    alpha: weight of the velocity difference in eq. 17, s² (so ``√α·ε`` is in m).
        With α = 1 s², 1 m/s of velocity difference counts like 1 m of distance.
    eps: DBSCAN neighbourhood radius in the (x, y, √α·ε) space, m.
    min_samples: DBSCAN core-point size (the point itself included).
    v_th: speed threshold on ``|ε|``, m/s (eq. 18-19). With 0.1 m/s Doppler
        quantisation (σ ≈ 0.03 m/s) 0.3 m/s is ~10 σ.
    min_moving_fraction: a cluster is moving when at least this fraction of its
        points has ``|ε| ≥ v_th``. 0.5 is the "median |ε| ≥ v_th" rule; the
        default 0.3 also catches objects moving mostly across the beams, whose
        central points show no Doppler.
    keep_strong_points: if True, a point with ``|ε| ≥ v_th`` is moving even when
        its cluster is judged static (it cannot be static given the fitted
        ego-motion; this only matters when DBSCAN chains a mover to static
        structure). If False the cluster decision is final.
    neighbourhood: DBSCAN only looks at points within this distance (m) of a
        point with ``|ε| ≥ v_th`` (see :func:`segment_moving`); 0 looks at all.
        2 m keeps whole any object up to the tracker's ``max_object_radius`` (0.8 m) around
        one of its points. 1 m saves little and judges more static points moving: on the 120 s
        corridor (``fmcwlog process --method improved --set segmentation.neighbourhood=1``) the
        tracker's clustering takes 0.42 against 0.50 s CPU of a 5.75 s front end, and the
        moving-point F1 is 0.99801 against 0.99846 (26 more static points judged moving;
        docs/design/moving-points.md).
    """

    # 0 clusters by position alone; at 100 s² one Doppler quantum (0.1 m/s) already counts as 1 m
    alpha: float = param(1.0, "s^2", ge=0.0, le=100.0)
    eps: float = param(0.3, "m", gt=0.0, le=10.0)  # a radius beyond a room's size joins everything
    min_samples: int = param(5, "points", ge=1, le=10_000)
    v_th: float = param(0.3, "m/s", gt=0.0, le=50.0)
    min_moving_fraction: float = param(0.3, "", gt=0.0, le=1.0)  # 0 would call every cluster moving
    keep_strong_points: bool = True
    neighbourhood: float = param(2.0, "m", ge=0.0, le=1000.0)


def cluster_points(
    xy: np.ndarray, epsilon: np.ndarray, params: SegmentationParams = SegmentationParams(), labeller=None
) -> np.ndarray:
    """DBSCAN labels (N,) over ``(x, y, √α·ε)`` (eq. 17, with the compensated ``ε`` in place of
    ``v_r``); -1 marks noise. ``xy`` (N, 2) m, ``epsilon`` (N,) m/s. ``labeller``: the DBSCAN,
    :func:`dbscan` where None (:func:`dbscan_numpy` for the numpy reference)."""
    feats = np.column_stack([xy, np.sqrt(params.alpha) * np.asarray(epsilon, float)])
    return (labeller or dbscan)(feats, params.eps, params.min_samples)


def dbscan(feats: np.ndarray, eps: float, min_samples: int) -> np.ndarray:
    """DBSCAN labels (N,) of points (N, D), -1 for noise, numbered as sklearn's ``DBSCAN`` numbers them
    (:func:`dbscan_numpy`): the compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it
    and every coordinate is finite, the same labels exactly."""
    core = compiled.core()
    if core is not None:
        pts = np.ascontiguousarray(feats, dtype=float)
        if pts.ndim == 2 and (pts.shape[1] or not len(pts)):
            labels = np.empty(len(pts), np.int64)
            if core.dbscan(pts, float(eps), int(min_samples), labels):
                return labels
    return dbscan_numpy(feats, eps, min_samples)


def dbscan_numpy(feats: np.ndarray, eps: float, min_samples: int) -> np.ndarray:
    """:func:`dbscan` in numpy: the reference the compiled kernel is tested against.

    Neighbours are the pairs within ``eps`` (inclusive); a core point has at least
    ``min_samples`` neighbours counting itself. Clusters are the connected components
    of core points, numbered in the order of their lowest index (the order of sklearn's
    scan); a border point takes the lowest-numbered cluster among its core neighbours
    (the first scan to reach it).
    """
    n = len(feats)
    labels = np.full(n, -1, np.intp)
    if n == 0:
        return labels
    # the pairs' order depends on the tree, the labels do not (counts, components, minima)
    from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
    pairs = cKDTree(feats, balanced_tree=False, compact_nodes=False).query_pairs(eps, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    core = np.bincount(pairs.ravel(), minlength=n) + 1 >= min_samples
    if not core.any():
        return labels
    core_i, core_j = core[i], core[j]
    both = core_i & core_j
    root = _lowest_connected(n, i[both], j[both])[core]
    is_root = np.zeros(n, bool)
    is_root[root] = True
    labels[core] = (np.cumsum(is_root) - 1)[root]
    to_core, from_core = core_j & ~core_i, core_i & ~core_j
    border = np.concatenate([i[to_core], j[from_core]])
    if border.size:
        first = np.full(n, n)
        np.minimum.at(first, border, np.concatenate([labels[j[to_core]], labels[i[from_core]]]))
        reached = first < n
        labels[reached] = first[reached]
    return labels


def _lowest_connected(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """For each of ``n`` nodes the lowest node of its connected component under the undirected
    edges ``i``-``j``. Every node points at a lower or equal one (a forest whose roots are the lowest
    node of their tree); per round, each edge's higher root is hooked under its lower one, the
    pointers are followed to the roots, and the edges now inside one tree are dropped, until none
    is left (the answer is unique: the same as lowering labels along every edge until stable)."""
    lab = np.arange(n)
    while i.size:
        li, lj = lab[i], lab[j]
        np.minimum.at(lab, np.maximum(li, lj), np.minimum(li, lj))
        while not np.array_equal(hop := lab[lab], lab):
            lab = hop
        apart = lab[i] != lab[j]
        i, j = i[apart], j[apart]
    return lab


def moving_from_labels(
    labels: np.ndarray, epsilon: np.ndarray, params: SegmentationParams = SegmentationParams()
) -> np.ndarray:
    """Moving mask (N,) from cluster labels and compensated velocities.

    Per cluster: moving when the fraction of its points with ``|ε| ≥ v_th``
    reaches ``min_moving_fraction`` (eq. 19 applied to a cluster).
    DBSCAN noise points (label -1): judged individually, ``|ε| ≥ v_th``.
    """
    strong = np.abs(epsilon) >= params.v_th
    moving = strong.copy() if params.keep_strong_points else np.zeros_like(strong)
    clustered = labels >= 0
    if clustered.any():
        lab = labels[clustered]
        n_lab = int(lab.max()) + 1
        size = np.bincount(lab, minlength=n_lab)
        n_strong = np.bincount(lab, weights=strong[clustered], minlength=n_lab)
        cluster_moving = n_strong >= params.min_moving_fraction * size
        moving[clustered] |= cluster_moving[lab]
    noise = ~clustered
    moving[noise] = strong[noise]
    return moving


_EMPTY_SEEDS = np.zeros((0, 2))


@dataclass
class Segmentation:
    """One sweep's clusters and Doppler verdict (:func:`segment_clusters`).

    labels: (N,) DBSCAN cluster of each point; -1 for noise and for points left out of
        the clustering (farther than ``neighbourhood`` from every seed).
    clustered: (N,) the points that went into DBSCAN.
    moving: (N,) the per-cluster Doppler verdict (eq. 19 on ``ε``).
    """

    labels: np.ndarray
    clustered: np.ndarray
    moving: np.ndarray


def segment_clusters(
    xy: np.ndarray,
    epsilon: np.ndarray,
    params: SegmentationParams = SegmentationParams(),
    seeds: np.ndarray | None = None,
    seed_points: np.ndarray | None = None,
) -> Segmentation:
    """DBSCAN clusters and the Doppler verdict of one sweep (see :func:`segment_moving`).

    ``seeds`` (K, 2), lidar frame, m: places besides the points with ``|ε| ≥ v_th``
    around which points are clustered (where a tracked mover is expected, whose
    Doppler may be nil this sweep: :mod:`.tracking`); ``seed_points`` (N,) bool: points
    of ``xy`` that are seeds too (the same as passing ``xy[seed_points]`` in ``seeds``).

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it and every input is
    finite (one call: the cut, DBSCAN and the verdict), the same arrays exactly as
    :func:`segment_clusters_numpy`.
    """
    core = compiled.core()
    if core is not None:
        n = len(xy)
        labels, clustered, moving = np.empty(n, np.int64), np.empty(n, bool), np.empty(n, bool)
        seeds_in = _EMPTY_SEEDS if seeds is None or len(seeds) == 0 else np.ascontiguousarray(seeds, dtype=float)
        marks = None if seed_points is None else np.ascontiguousarray(seed_points, dtype=bool)
        if core.segment_clusters(np.ascontiguousarray(xy, dtype=float), np.ascontiguousarray(epsilon, dtype=float),
                                 seeds_in, marks, params.alpha, params.eps, params.min_samples, params.v_th,
                                 params.min_moving_fraction, params.keep_strong_points, params.neighbourhood,
                                 labels, clustered, moving):
            return Segmentation(labels, clustered, moving)
    return segment_clusters_numpy(xy, epsilon, params, seeds, seed_points)


def segment_clusters_numpy(
    xy: np.ndarray,
    epsilon: np.ndarray,
    params: SegmentationParams = SegmentationParams(),
    seeds: np.ndarray | None = None,
    seed_points: np.ndarray | None = None,
) -> Segmentation:
    """:func:`segment_clusters` in numpy: the reference the compiled kernel is tested against."""
    epsilon = np.asarray(epsilon, dtype=float)
    n = xy.shape[0]
    labels = np.full(n, -1)
    strong = np.abs(epsilon) >= params.v_th
    centre = strong if seed_points is None else strong | seed_points  # points that are centres themselves
    extra = (seeds is not None and len(seeds) > 0) or (seed_points is not None and bool(seed_points.any()))
    if n == 0 or (params.min_moving_fraction > 0 and not strong.any() and not extra):
        return Segmentation(labels, np.zeros(n, bool), np.zeros(n, bool))
    if params.neighbourhood <= 0 or params.min_moving_fraction <= 0:
        near = np.ones(n, bool)
    else:
        centres = xy[centre] if seeds is None or len(seeds) == 0 else np.concatenate([xy[centre], seeds])
        # only points inside the centres' bounding box grown by the neighbourhood can be near one,
        # and a centre is near itself: the KD-tree is asked about the others inside the box alone
        # (segmentation 0.29 ms a sweep on the corridor log against 0.38 ms asking about every
        # point; 0.32 against 0.52 ms on the crowd log, where a third of the points are centres)
        lo, hi = centres.min(axis=0) - params.neighbourhood, centres.max(axis=0) + params.neighbourhood
        near = (xy[:, 0] >= lo[0]) & (xy[:, 0] <= hi[0]) & (xy[:, 1] >= lo[1]) & (xy[:, 1] <= hi[1])
        inside = np.flatnonzero(near & ~centre)
        # the nearest distance is the same in any tree: the quicker build (unbalanced, uncompacted)
        from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
        tree = cKDTree(centres, balanced_tree=False, compact_nodes=False)
        dist, _ = tree.query(xy[inside], k=1, distance_upper_bound=params.neighbourhood)
        near[inside] = np.isfinite(dist)
    moving = np.zeros(n, bool)
    if near.any():
        labels[near] = cluster_points(xy[near], epsilon[near], params, dbscan_numpy)
        moving[near] = moving_from_labels(labels[near], epsilon[near], params)
    return Segmentation(labels, near, moving)


def segment_moving(
    xy: np.ndarray, epsilon: np.ndarray, params: SegmentationParams = SegmentationParams()
) -> np.ndarray:
    """Boolean mask (N,), True where the point hit a moving object.

    Pass the compensated velocity ``ε``, not the raw Doppler ``v_r`` (see the
    module docstring: eq. 18 on ``v_r`` only holds for a standing robot).

    Only clusters holding points with ``|ε| ≥ v_th`` can be moving, so DBSCAN
    runs on the points within ``neighbourhood`` of such points (all of them
    when ``neighbourhood`` is 0). With none, nothing is moving and DBSCAN is
    skipped. The cut can only shorten a cluster that reaches farther than
    ``neighbourhood`` from every moving point: a wall, whose share of moving
    points is nil either way. On the corridor log segmentation takes about 1 ms per
    sweep this way, against 3.9 ms with DBSCAN over every point.

    ``xy`` (N, 2): the sweep in the lidar frame (m); ``epsilon`` (N,): compensated Doppler
    (m/s). Raises nothing of its own.
    """
    return segment_clusters(xy, epsilon, params).moving
