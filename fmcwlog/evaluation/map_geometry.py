"""Walls found in a map: robust line fits near an expected place, their ends and their corners.

Everything here works on evidence points (N, 2) in one frame, metres: the centres of a
map's occupied cells (or any static points). It is told *where to look* (an anchor point,
the direction in which a wall should leave it, and how long that wall is at most) and
finds *what the map shows there*; nothing here knows the truth.

A wall (an "arm" leaving the anchor) is found in three steps:

1. the evidence in a strip along the arm: ``-behind <= s <= reach`` along it and
   ``|t| <= halfwidth`` across it (``s``, ``t`` measured from the anchor);
2. a Hough search restricted to directions within ``angle_tol_deg`` of the arm's: for
   each direction, the offset across it that holds the most points within ``±band``
   (a sliding window over the sorted offsets, so no binning artefact) — the dominant
   line, robust to clutter (RANSAC's job, done exhaustively over a narrow range of
   directions, so it is deterministic);
3. total-least-squares refits on the points within ``±band`` of the current line,
   repeated until the inlier set stops changing (a trimmed, iteratively refitted line),
   never turning further than ``angle_tol_deg`` from the arm.

Along the fitted line the inliers are split into runs wherever two neighbours are more
than ``max_gap`` apart; the arm's wall is the run with the most inliers. Its end nearest
the anchor is a *wall end* (a door jamb, a wall that stops); two arms' lines intersect in
a *corner*, each refitted without the cells on the other's line (near the corner both
strips hold them). A fit is trusted only when

- the run covers at least ``min_cover`` of the searched length (else "too little wall",
  or "no wall evidence" when the strip is all but empty);
- no second line parallel to it, over ``2 band`` away in the strip, holds more than
  ``max_second`` of its cells with a run as long (else "drawn twice": a wall a drifting
  method drew at two places, or smeared, has no one length);
- for a wall end, the run stops at least ``max_gap`` inside the strip (else the wall
  "runs on": the map shows no end there); for a corner, the walls meet at over
  ``min_corner_angle_deg`` and both runs reach within ``max_corner_gap`` of the
  intersection.

The perpendicular RMS residual of each fit is reported, not used: on a 5 cm map a clean
wall two or three cells thick and a wall drawn twice 5 cm apart both give 2–4 cm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WallSearch:
    """How walls are looked for and when a fit is trusted.

    halfwidth: how far across its expected line a wall may lie, m (> 0). It must exceed
        the map's local displacement after alignment and stay under the spacing of
        parallel walls near a feature (0.6 m at the corridor's niche).
    behind: how far past the expected end, against the arm, evidence is gathered, m (> 0).
    reach: how far along the arm evidence is gathered, m (> 0; capped by the wall's length).
    angle_tol_deg: largest angle between the found wall and its expected direction, deg (0, 45).
    angle_step_deg: step of the direction search, deg (> 0).
    band: inlier half-width around a line, m (> 0): 1.5 cells of a 5 cm map.
    max_gap: a longer stretch without evidence along a wall ends it, m (> 0).
    min_cover: the wall's run must cover this fraction of the searched length, (0, 1].
    min_points: and hold at least this many points (>= 2).
    max_second: a second line parallel to the wall, over ``2 band`` from it in the strip,
        holding more than this fraction of the wall's cells makes the wall ambiguous
        (drawn twice, or smeared), (0, 1].
    max_corner_gap: a corner's two walls must reach this close to their intersection, m (> 0).
    min_corner_angle_deg: two walls meeting at a smaller angle make no corner, deg (0, 90).
    """

    halfwidth: float = 0.5
    behind: float = 0.75
    reach: float = 1.5
    angle_tol_deg: float = 10.0
    angle_step_deg: float = 0.25
    band: float = 0.075
    max_gap: float = 0.25
    min_cover: float = 0.4
    min_points: int = 5
    max_second: float = 0.5
    max_corner_gap: float = 0.25
    min_corner_angle_deg: float = 30.0


@dataclass(frozen=True)
class WallFit:
    """A wall found along an arm, or why none was.

    point: a point of the fitted line (m); direction: its unit direction, oriented like the
    arm; near_end: the end of the wall's run nearest the anchor (m, on the line); far_end:
    the other end within the searched strip; n: inliers in the run; rms: their
    perpendicular RMS residual (m); reason: None when trusted, else why not.
    """

    point: np.ndarray
    direction: np.ndarray
    near_end: np.ndarray
    far_end: np.ndarray
    n: int
    rms: float
    reason: str | None = None

    @property
    def trusted(self) -> bool:
        return self.reason is None


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _normal(d: np.ndarray) -> np.ndarray:
    return np.array([-d[1], d[0]])


def _strip(points: np.ndarray, anchor: np.ndarray, d: np.ndarray, reach: float, search: WallSearch) -> np.ndarray:
    """The evidence in the arm's search strip (step 1)."""
    rel = points - anchor
    s, t = rel @ d, rel @ _normal(d)
    return points[(s >= -search.behind) & (s <= reach) & (np.abs(t) <= search.halfwidth)]


def _hough(points: np.ndarray, d: np.ndarray, search: WallSearch) -> tuple[np.ndarray, float]:
    """Direction near ``d`` and offset of the line holding the most points within ±band (step 2)."""
    tol = np.radians(search.angle_tol_deg)
    angles = np.arange(-tol, tol + 1e-12, np.radians(search.angle_step_deg))
    base = np.arctan2(d[1], d[0])
    best = (-1, d, 0.0)
    for a in angles:  # a few dozen directions; each is vectorised over the points
        u = np.array([np.cos(base + a), np.sin(base + a)])
        off = np.sort(points @ _normal(u))
        counts = np.searchsorted(off, off + 2 * search.band, side="right") - np.arange(len(off))
        i = int(np.argmax(counts))
        if counts[i] > best[0]:
            best = (int(counts[i]), u, float(np.median(off[i:i + counts[i]])))
    return best[1], best[2]


def _refit(points: np.ndarray, d: np.ndarray, offset: float, search: WallSearch,
           iterations: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Total-least-squares refits on the points within ±band (step 3): line point, direction and
    inlier mask. The direction stays within ``angle_tol_deg`` of ``d``: inliers whose own direction
    turns further are a crossing wall's cells, and the search's direction is kept for them."""
    centre, u = _normal(d) * offset, d
    inl = np.zeros(len(points), bool)
    cos_tol = np.cos(np.radians(search.angle_tol_deg))
    for _ in range(iterations):
        new = np.abs((points - centre) @ _normal(u)) <= search.band
        if new.sum() < 2 or np.array_equal(new, inl):
            break
        inl = new
        c = points[inl].mean(axis=0)
        _, _, vt = np.linalg.svd(points[inl] - c, full_matrices=False)
        v = vt[0] if vt[0] @ d >= 0 else -vt[0]
        if v @ d < cos_tol:  # the inliers' own direction turns away: keep the direction searched
            centre = c
            break
        centre, u = c, v
    return centre, u, inl


def _runs(s: np.ndarray, max_gap: float) -> list[np.ndarray]:
    """Indices of ``s`` split into runs of sorted values with no gap above ``max_gap``."""
    order = np.argsort(s)
    cuts = np.nonzero(np.diff(s[order]) > max_gap)[0] + 1
    return np.split(order, cuts)


def fit_wall(points: np.ndarray, anchor: np.ndarray, direction: np.ndarray, length: float,
             search: WallSearch = WallSearch(), exclude: WallFit | None = None) -> WallFit:
    """The wall leaving ``anchor`` along ``direction`` (a wall of ``length`` m at most) in ``points``;
    points within ``band`` of the line of ``exclude`` (a crossing wall) are left out."""
    anchor = np.asarray(anchor, dtype=float)
    d = _unit(direction)
    reach = min(search.reach, float(length))
    none = WallFit(anchor, d, anchor, anchor, 0, float("nan"), "")
    strip = _strip(np.asarray(points, dtype=float).reshape(-1, 2), anchor, d, reach, search)
    if exclude is not None and exclude.n:
        strip = strip[np.abs((strip - exclude.point) @ _normal(exclude.direction)) > search.band]
    if len(strip) < search.min_points:
        return _why(none, f"no wall evidence near the end ({len(strip)} occupied cells where the wall "
                          f"should be, within {search.halfwidth:g} m across)")
    u0, off0 = _hough(strip, d, search)
    centre, u, inl = _refit(strip, u0, off0, search)
    if inl.sum() < search.min_points:
        return _why(none, f"no wall evidence near the end: {len(strip)} occupied cells, no {search.min_points} "
                          f"of them on one line")
    s = (strip[inl] - centre) @ u
    run = max(_runs(s, search.max_gap), key=len)
    pts, s_run = strip[inl][run], s[run]
    near, far = centre + s_run.min() * u, centre + s_run.max() * u
    rms = float(np.sqrt(np.mean(((pts - centre) @ _normal(u)) ** 2)))
    fit = WallFit(centre, u, near, far, len(run), rms)
    cover = float(s_run.max() - s_run.min())
    if len(run) < search.min_points or cover < search.min_cover * reach:
        return _why(fit, f"too little wall: {cover:.2f} m of it in {len(run)} cells, "
                         f"under {search.min_cover:.0%} of the {reach:.2f} m searched")
    second = _second_line(strip, centre, u, reach, search)
    if second is not None and second[1] > search.max_second * len(run):
        return _why(fit, f"the wall is drawn twice: a second line {second[0]:.2f} m from it holds "
                         f"{second[1]} cells against its {len(run)}")
    return fit


def _second_line(strip: np.ndarray, centre: np.ndarray, u: np.ndarray, reach: float,
                 search: WallSearch) -> tuple[float, int] | None:
    """Distance (m) and cells of the strongest other wall-like line parallel to the wall in its strip:
    a run as long as a trusted wall's, over ``2 band`` from it (None if there is none)."""
    others = strip[np.abs((strip - centre) @ _normal(u)) > 2 * search.band]
    if len(others) < search.min_points:
        return None
    u2, off2 = _hough(others, u, search)
    c2, u2, inl = _refit(others, u2, off2, search)
    s = (others[inl] - c2) @ u2
    run = max(_runs(s, search.max_gap), key=len) if len(s) else np.zeros(0, int)
    if len(run) < search.min_points or float(np.ptp(s[run])) < search.min_cover * reach:
        return None
    return abs(float((c2 - centre) @ _normal(u))), len(run)


def _why(fit: WallFit, reason: str) -> WallFit:
    return WallFit(fit.point, fit.direction, fit.near_end, fit.far_end, fit.n, fit.rms, reason)


def wall_end(fit: WallFit, anchor: np.ndarray, search: WallSearch = WallSearch()) -> tuple[np.ndarray | None, str | None]:
    """Where a trusted wall stops near ``anchor``: its run's near end, unless the run reaches the
    back of the searched strip (then the map shows no end there)."""
    if not fit.trusted:
        return None, fit.reason
    back = (fit.near_end - np.asarray(anchor, dtype=float)) @ fit.direction + search.behind  # from the strip's back
    if back < search.max_gap:
        return None, f"the wall runs on past where it should stop (over {search.behind:g} m): the map shows no end"
    return fit.near_end, None


def fit_corner(points: np.ndarray, anchor: np.ndarray, arms: list[tuple[np.ndarray, float]],
               search: WallSearch = WallSearch()) -> tuple[list[WallFit], np.ndarray | None, str | None]:
    """Two walls leaving ``anchor`` (``arms``: direction, length) and where they meet.

    Each wall is fitted twice: the second time without the cells on the other wall's line, which
    near the corner belong to both strips and would tilt a short wall's fit (the corridor's 0.6 m
    deep niche: 8 deg and 6 cm at the corner with them, on a map built from perfect poses)."""
    first = [fit_wall(points, anchor, d, length, search) for d, length in arms]
    fits = [fit_wall(points, anchor, d, length, search, exclude=first[1 - i]) for i, (d, length) in enumerate(arms)]
    xy, reason = corner(fits[0], fits[1], search)
    return fits, xy, reason


def corner(a: WallFit, b: WallFit, search: WallSearch = WallSearch()) -> tuple[np.ndarray | None, str | None]:
    """Where two trusted walls meet: their lines' intersection, if both walls reach it."""
    for f in (a, b):
        if not f.trusted:
            return None, f.reason
    cross = a.direction[0] * b.direction[1] - a.direction[1] * b.direction[0]
    if abs(cross) < np.sin(np.radians(search.min_corner_angle_deg)):
        return None, f"the two walls are near parallel ({np.degrees(np.arcsin(min(1.0, abs(cross)))):.0f} deg)"
    # a.point + ta * a.direction = b.point + tb * b.direction
    ta = ((b.point - a.point)[0] * b.direction[1] - (b.point - a.point)[1] * b.direction[0]) / cross
    x = a.point + ta * a.direction
    gaps = [float((f.near_end - x) @ f.direction) for f in (a, b)]
    if max(gaps) > search.max_corner_gap:
        return None, (f"the walls stop {max(gaps):.2f} m short of their intersection "
                      f"(> {search.max_corner_gap:g} m): the map shows no corner there")
    return x, None
