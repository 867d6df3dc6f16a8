"""Feature lengths measured in the map each method built (the paper's Tables 2 and 3).

The paper labels nine features in its simulated floor and measures their lengths "in the
map" each front end built (§5.2; it does not say how, presumably by hand on the map
image). Here a feature's two ends are found in the method's own occupancy map
(``<method>_map.yaml`` + ``.pgm``, map_server, in ``<method>/odom``) and its measured
length is the distance between them in that map; the ends are reported in that frame.

What the ground truth may do, and what it may not
    The truth says *where to look* and *what to look for*, never which cells to use.
    *Where*: the method's trajectory is aligned to the ground truth (SE(2), least
    squares, :func:`fmcwlog.evaluation.metrics.align_se2`, as the ATE is) over the
    poses within ``view_radius`` = 8 m of the end, and the true end is mapped into the
    method's frame with that alignment. *What*: the world's walls say whether the end is
    a *corner* (two walls meet there) or a *wall end* (a wall stops: a door jamb), and
    in which directions and how far its walls leave it.

What the map must show
    Near that place the walls are fitted in the map's occupied cells
    (:mod:`fmcwlog.evaluation.map_geometry`: a Hough search within 10 deg of the expected
    direction, then trimmed total-least-squares refits, in a strip 0.5 m either side of
    where the wall should be). A corner is the intersection of its two walls' lines; a
    wall end is the end of its wall's run of cells (a cell centre). An end is *not
    measurable* — the feature is not scored, its row says why — when the map holds no
    wall there, too little of it (under 40 % of the up to 1.5 m searched), a wall drawn
    twice (a parallel line within 0.5 m holding over half as many cells), walls that stop
    over 25 cm short of their corner, or a wall that runs on where it should stop.

How exact it is
    With perfect poses (``bench/feature_floor.py``: the log's static points placed with
    the ground truth into fmcwlog's own occupancy grid) the nine features of the 2-minute
    ``corridor`` log measure within 8.1 cm, 1.17 % on average: walls 5 cm cells wide, wall
    ends taken at a cell centre (the 1 m openings come out 2–4 cm too wide, 2–3.4 %), and the
    niche's 0.6 m side walls, seen only at grazing angles, drawn a few cm outward (+8 cm,
    3.5 %). That is the floor under any method's figure here. Rasterised maps of the exact
    walls measure every feature within one cell (``tests/unit/evaluation/test_features.py``).

Why the alignment is local, not one fit over the whole run as the ATE's
    The search must land within the strip's 0.5 m of where the map drew the end, and a
    drifting method's map is out of place by different amounts in different parts. On
    the 2-minute corridor log the baseline's trajectory is 1.5 m off at worst after one
    global fit (ATE max); its map's ends are found 0.33 m (median) and up to 0.71 m from
    a globally placed search, 14 of 18 ends found, 5 features measured; fitted over the
    poses within 8 m of each end, 0.30 m and 0.66 m, 16 ends, 7 features (5 m: 15 ends,
    6 features; 12 m: 14 ends, 5 features). The improved method's ends lie 3 cm (median)
    from the search either way. Only the search moves; the end is what the map shows:
    the improved method's nine lengths are the same (within 1 cm) under all four, the
    baseline's measured ones within 2 cm, but its features 1 and 7 (its niche and the
    hall's north-east corner, both drawn out of shape) are found under some and not others.

A row (``report.json``: ``methods.<method>.features``)
    ``id``, ``name``, ``true_m``; ``measured_m`` (None when not measurable), ``measurable``,
    ``reason`` (why not, per end); ``end_a``/``end_b``: ``kind`` (corner, wall end),
    ``expected_xy`` (where the search was placed) and ``xy`` (what the map shows), both in
    ``<method>/odom`` (m), ``reason``, and per fitted wall its ``direction``, ``cells``
    (inliers) and ``rms_m`` (perpendicular RMS residual; None without inliers); :mod:`.evaluate` adds
    ``abs_error_m`` and ``rel_error_pct``.

Why not the points near the true ends
    A measure that picks the points the method kept that the *ground-truth* poses put near
    each end, and compares where the method placed them, is a relative pose error between the
    times each end was seen, weighted by points: it never looks at the map (a wall drawn twice,
    metres apart, scores well; a wall no map shows scores to 1 mm), and RPE already reports that
    kind of error (docs/design/feature-lengths.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ReportError
from ..geometry import compose, inverse, rot2
from ..io.map_files import read_map_server
from ..io.outputs import read_tum
from .map_geometry import WallSearch, fit_corner, fit_wall, wall_end
from .metrics import align_se2, interpolate_reference

CORNER, WALL_END = "corner", "wall end"


@dataclass(frozen=True)
class FeatureSearch:
    """Parameters of the measurement.

    walls: how walls are fitted and when a fit is trusted (:class:`WallSearch`).
    view_radius: the alignment that places the search uses the poses whose ground-truth
        position is within this of the end, m (> 0); with fewer than ``min_poses`` such
        poses, all poses.
    min_poses: fewest poses for a local alignment (>= 2).
    touch: a wall touches an end when its segment passes within this of it, m (> 0).
    """

    walls: WallSearch = field(default_factory=WallSearch)
    view_radius: float = 8.0
    min_poses: int = 20
    touch: float = 1e-3


@dataclass(frozen=True)
class EndShape:
    """What a feature end is in the true world: a corner or a wall end, and its walls.

    arms: the walls leaving the end, as (unit direction (2,), length m) in the world frame;
    reason: why the end has no shape a map can show (then ``kind`` is None).
    """

    kind: str | None
    arms: tuple[tuple[np.ndarray, float], ...]
    reason: str | None = None


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def end_shape(point: np.ndarray, walls: np.ndarray, touch: float = 1e-3) -> EndShape:
    """The walls leaving ``point`` (world, m) among ``walls`` (M, 4: x0, y0, x1, y1)."""
    p = np.asarray(point, dtype=float)
    arms: list[tuple[np.ndarray, float]] = []
    for seg in np.asarray(walls, dtype=float).reshape(-1, 4):
        a, b = seg[:2], seg[2:]
        ab = b - a
        length = float(np.hypot(*ab))
        if length == 0:
            continue
        s = float(np.clip((p - a) @ ab / length**2, 0.0, 1.0))
        if np.hypot(*(a + s * ab - p)) > touch:
            continue
        for tip in (a, b):  # the parts of the wall on either side of the point
            rest = float(np.hypot(*(tip - p)))
            if rest > touch and not any(np.dot(d, (tip - p) / rest) > 1 - 1e-6 for d, _ in arms):
                arms.append(((tip - p) / rest, rest))
    if not arms:
        return EndShape(None, (), "no wall of the world touches this end")
    if len(arms) == 1:
        return EndShape(WALL_END, tuple(arms))
    i, j = max(((i, j) for i in range(len(arms)) for j in range(i + 1, len(arms))),
               key=lambda ij: abs(_cross(arms[ij[0]][0], arms[ij[1]][0])))
    if abs(_cross(arms[i][0], arms[j][0])) < 0.5:  # under 30 deg: one straight wall through the point
        return EndShape(None, tuple(arms), "the end lies along a straight wall: no corner or wall end to find")
    return EndShape(CORNER, (arms[i], arms[j]))


def search_frames(t: np.ndarray, est: np.ndarray, gt_t: np.ndarray, gt: np.ndarray, ends: np.ndarray,
                  search: FeatureSearch = FeatureSearch()) -> np.ndarray:
    """Per end (K, 2; world, m), the world -> method-frame transform (K, 3) that places its search.

    ``t`` (s) and ``est`` (N, 3): the method's trajectory in its frame; ``gt_t`` (s), ``gt``: the
    truth. Each is the inverse of the SE(2) alignment (:func:`align_se2`, the ATE's) of the
    method's positions to the true ones over the poses within ``view_radius`` of the end, or over
    all poses when fewer than ``min_poses`` are that close. Raises ValueError when the
    trajectory and the truth do not overlap in time.
    """
    idx, ref = interpolate_reference(t, gt_t, gt)
    e = est[idx]
    overall = inverse(align_se2(e[:, :2], ref[:, :2]))
    out = np.tile(overall, (len(ends), 1))
    for k, end in enumerate(np.asarray(ends, dtype=float).reshape(-1, 2)):  # a few ends, each over all poses
        near = np.hypot(*(ref[:, :2] - end).T) <= search.view_radius
        if near.sum() >= search.min_poses:
            out[k] = inverse(align_se2(e[near, :2], ref[near, :2]))
    return out


def measure_end(cells: np.ndarray, point: np.ndarray, shape: EndShape, world_to_est: np.ndarray,
                search: WallSearch = WallSearch()) -> dict[str, Any]:
    """One end found in a map's occupied cells (N, 2), looked for where ``world_to_est``
    (x, y, yaw) puts the true ``point``; a dict with ``xy`` None and the ``reason`` when not found."""
    expected = compose(world_to_est, np.array([*point, 0.0]))[:2]
    out: dict[str, Any] = {"kind": shape.kind, "expected_xy": expected.tolist(), "xy": None, "reason": shape.reason,
                           "walls": []}
    if shape.kind is None:
        return out
    r = rot2(world_to_est[2])
    arms = [(r @ d, length) for d, length in shape.arms]
    if shape.kind == CORNER:
        fits, xy, reason = fit_corner(cells, expected, arms, search)
    else:
        fits = [fit_wall(cells, expected, *arms[0], search)]
        xy, reason = wall_end(fits[0], expected, search)
    # no cells, no residual: null (JSON has no NaN; a strict reader refuses the whole report)
    out["walls"] = [{"direction": f.direction.tolist(), "cells": f.n, "rms_m": f.rms if np.isfinite(f.rms) else None,
                     "reason": f.reason} for f in fits]
    out["xy"], out["reason"] = (None if xy is None else xy.tolist()), reason
    return out


def _rows(cells: np.ndarray | None, map_reason: str | None, features: list[dict], shapes: list[tuple],
          transforms: np.ndarray, search: WallSearch) -> list[dict]:
    rows = []
    for i, f in enumerate(features):
        true = float(np.hypot(*np.subtract(f["b"], f["a"])))
        row: dict[str, Any] = {"id": f.get("id", i + 1), "name": f.get("name", ""), "true_m": true,
                               "measured_m": None, "measurable": False, "reason": map_reason,
                               "end_a": None, "end_b": None}
        if cells is not None:
            ends = [measure_end(cells, np.asarray(f[k], float), shape, frame, search)
                    for k, shape, frame in zip("ab", shapes[i], transforms[i])]
            row["end_a"], row["end_b"] = ends
            if all(e["xy"] is not None for e in ends):
                row["measured_m"] = float(np.hypot(*np.subtract(ends[1]["xy"], ends[0]["xy"])))
                row["measurable"], row["reason"] = True, None
            else:
                row["reason"] = "; ".join(f"end {k}: {e['reason']}" for k, e in zip("ab", ends) if e["xy"] is None)
        rows.append(row)
    return rows


def feature_lengths(out_dir: Path, methods: list[str], features: list[dict], walls: np.ndarray | None,
                    gt_ns: np.ndarray, gt: np.ndarray, search: FeatureSearch = FeatureSearch()) -> dict[str, list[dict]]:
    """Per method, one row per feature measured in its occupancy map (module docstring).

    ``features``: ``{id, name, a, b}`` with ends in the world frame (m); ``walls`` (M, 4): the
    world's walls; ``gt_ns`` (N,), ``gt`` (N, 3): ground-truth stamps (ns) and poses of base_link
    in ``map`` (m, m, rad); ``out_dir``: a ``process`` output folder holding ``<method>_map.yaml``
    and ``<method>.tum`` per method. A row's ``measured_m`` is None, with its ``reason``, where the
    map does not show the feature; a missing or unreadable map or trajectory is such a reason,
    not an exception.
    """
    ends = np.array([[f["a"], f["b"]] for f in features], dtype=float).reshape(-1, 2)  # a0, b0, a1, ...
    if walls is None:
        shapes = [(EndShape(None, (), "the log's world has no walls"),) * 2 for _ in features]
    else:
        shapes = [(end_shape(a, walls, search.touch), end_shape(b, walls, search.touch)) for a, b in ends.reshape(-1, 2, 2)]
    out: dict[str, list[dict]] = {}
    for m in methods:
        cells, frames, reason = _placed_map(out_dir, m, np.asarray(gt_ns, dtype=np.int64) * 1e-9, gt, ends, search)
        out[m] = _rows(cells, reason, features, shapes, frames.reshape(-1, 2, 3), search.walls)
    return out


def _placed_map(out_dir: Path, method: str, gt_t: np.ndarray, gt: np.ndarray, ends: np.ndarray,
                search: FeatureSearch) -> tuple[np.ndarray | None, np.ndarray, str | None]:
    """The occupied cells of a method's map and each end's search frame, or why there are none."""
    none = np.zeros((len(ends), 3))
    path, tum = out_dir / f"{method}_map.yaml", out_dir / f"{method}.tum"
    if not path.is_file():
        return None, none, f"no occupancy map {path.name} in the folder"
    try:
        cells = read_map_server(path).occupied_centres()
    except ReportError as exc:
        return None, none, str(exc)
    t, est = read_tum(tum) if tum.is_file() else (np.zeros(0), np.zeros((0, 3)))
    if len(t) < 2:
        return None, none, f"{tum.name} holds under two poses: its map cannot be placed against the truth"
    try:
        return cells, search_frames(t, est, gt_t, gt, ends, search), None
    except ValueError as exc:
        return None, none, f"{tum.name} cannot be placed against the truth: {exc}"
