"""A robot carried away: sweeps that stop fitting the map where the motion prior puts them.

A robot lifted and carried (kidnapped, pushed on a trolley with its wheels off the floor) sees
another place while its wheel ticks say it stood still or drove on; its Doppler says the same.
Every later sweep is then matched where the prior puts it, against a map of somewhere else: the
first such sweep fits badly, enters the map at the wrong place, and the sweeps after it fit that
misplaced keyframe, so the trajectory goes on as if nothing happened, metres off, without a word.

Here a sweep whose fit after the ICP and the recovery's search (:mod:`.recovery`) is below
``max_inlier_fraction`` (the share of its points with a map point within the recovery's
``inlier_distance``) is *suspect*: it keeps the prior's pose and stays out of the map. ``sweeps``
suspect sweeps in a row are a jump. The last of them is then searched for over the whole local map
(a correlative search :mod:`fmcwlog.kernels.correlative` of ``±linear_window`` m and every heading
around the prior), the ICP refines the best pose, and

- where that fits as well as a sweep normally does (``min_inlier_fraction``), and a separate peak of
  the search that scores within ``max_second_ratio`` of the best (a look-alike place: the other end
  of a symmetric hall) fits less than that share of it once refined by the ICP too, the robot is
  *relocalised*: the sweep
  takes the pose found, and the front end goes on from there in the same map;
- otherwise it was carried into a place the local map does not hold: a *new piece* starts, from the
  prior's pose with a fresh local map, and the poses after the jump are relative to an unknown offset.

Either way the jump is reported (a warning naming its time and, where relocalised, its size;
``run.json``'s ``jumps``; the report's header), the sweep that ends it carries
:attr:`~fmcwlog.types.SweepResult.jump`, and the back end gives the odometry edge across it no
weight (:mod:`fmcwlog.backend.pipeline`): no edge claims that the robot drove the jump.

On clean logs a sweep's fit after the recovery is 0.55 at the lowest (the baseline in the crowd
sample, 0.70 the improved method; ``sample_logs/*.mcap``); a sweep carried 8 m fits 0.03-0.11.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Checked, param
from ..geometry import between
from ..kernels.correlative import CorrelativeParams

RELOCALISED = "relocalised"  # the sweep that ends a jump was found in the local map
NEW_PIECE = "new piece"  # it was not: the trajectory goes on from the prior, at an unknown offset


@dataclass(frozen=True)
class RelocaliseParams(Checked):
    """enabled: watch for jumps (False: a sweep that does not fit is placed, and mapped, where the
        ICP leaves it).
    max_inlier_fraction: a sweep whose fit after the recovery is below this is suspect (0-1).
    sweeps: this many suspect sweeps in a row are a jump (≥ 1).
    linear_window: the wide search's half-width in x and y around the prior (m).
    resolution: its grid cell and finest step (m).
    sigma: its likelihood's width (m).
    min_inlier_fraction: the match it finds, refined by the ICP, is confident from this fit (0-1).
    max_second_ratio: a separate peak that scores more than this share of the best is refined too,
        and must fit less than this share of the best's fit (0-1).
    """

    enabled: bool = True
    max_inlier_fraction: float = param(0.3, "", ge=0.0, le=1.0)
    sweeps: int = param(5, "sweeps", ge=1, le=1000)
    linear_window: float = param(15.0, "m", gt=0.0, le=20.0)
    resolution: float = param(0.1, "m", ge=0.02, le=1.0)
    sigma: float = param(0.15, "m", gt=0.0, le=1.0)
    min_inlier_fraction: float = param(0.6, "", ge=0.0, le=1.0)
    max_second_ratio: float = param(0.9, "", ge=0.0, le=1.0)

    def search(self) -> CorrelativeParams:
        """The wide search: ``±linear_window`` and every heading, four levels of branch and bound."""
        return CorrelativeParams(linear_window=self.linear_window, angular_window_deg=180.0,
                                 resolution=self.resolution, coarse_factor=4, levels=4, sigma=self.sigma,
                                 max_points=300, max_rotations=721, peak_separation=1.0, peak_separation_deg=10.0)


@dataclass(frozen=True)
class Jump:
    """A jump: ``start`` (s, log time) the stamp of its first suspect sweep, ``found`` (s) that of the
    sweep that ended it, ``kind`` :data:`RELOCALISED` or :data:`NEW_PIECE`; where relocalised, the
    pose found in the frame of the prior's (``motion``: x, y in m, yaw in rad)."""

    start: float
    found: float
    kind: str
    motion: tuple[float, float, float] | None = None
    suspects: int = 1  # the suspect sweeps in a row, the one that ended it included

    @property
    def distance(self) -> float | None:
        """How far (m) the robot was found from where the prior put it; None for a new piece."""
        return None if self.motion is None else math.hypot(self.motion[0], self.motion[1])

    def to_json(self) -> dict:
        out: dict = {"start_s": round(self.start, 6), "found_s": round(self.found, 6), "kind": self.kind}
        if self.motion is not None:
            out["distance_m"] = round(float(self.distance or 0.0), 4)
            out["rotation_deg"] = round(math.degrees(self.motion[2]), 3)
        return out


class JumpWatch:
    """Counts the suspect sweeps in a row and keeps the jumps found (module docstring)."""

    def __init__(self, params: RelocaliseParams):
        self.params = params
        self.streak: list[float] = []  # the stamps (s) of the suspect sweeps in a row
        self.jumps: list[Jump] = []

    def suspect(self, fit: float) -> bool:
        """Whether a sweep with this fit (inlier fraction) does not fit where the prior put it."""
        return self.params.enabled and fit < self.params.max_inlier_fraction

    def observe(self, stamp: float, suspect: bool) -> bool:
        """One registered sweep, in order; True when it makes ``sweeps`` suspect ones in a row."""
        if not suspect:
            self.streak.clear()
            return False
        self.streak.append(stamp)
        return len(self.streak) >= self.params.sweeps

    def close(self, score: float, second_score: float) -> bool:
        """Whether the wide search's best separate peak scores within ``max_second_ratio`` of its best."""
        return second_score > self.params.max_second_ratio * score

    def confident(self, fit: float, other_fit: float) -> bool:
        """Whether the wide search's match places the sweep: its ICP ``fit`` (inlier fraction), and that
        of a separate peak the search scored nearly as high (0 where none did)."""
        p = self.params
        return fit >= p.min_inlier_fraction and other_fit <= p.max_second_ratio * fit

    def record(self, stamp: float, kind: str, predicted: np.ndarray | None = None,
               found: np.ndarray | None = None) -> Jump:
        """The jump ended by the sweep at ``stamp`` (s)."""
        motion = None
        if predicted is not None and found is not None:
            d = between(predicted, found)
            motion = (float(d[0]), float(d[1]), float(d[2]))
        jump = Jump(self.streak[0] if self.streak else stamp, stamp, kind, motion, max(len(self.streak), 1))
        self.jumps.append(jump)
        self.streak.clear()
        return jump

    def warnings(self) -> list[str]:
        """One line per jump."""
        out = []
        for j in self.jumps:
            if j.kind == RELOCALISED:
                assert j.motion is not None
                out.append(f"the robot was carried at {j.start:.3f} s: its sweeps stopped fitting the map where the "
                           f"motion prior put them, and were found {j.distance:.2f} m and "
                           f"{math.degrees(j.motion[2]):.1f}° away at {j.found:.3f} s (relocalised; no odometry edge "
                           "across the jump)")
            else:
                out.append(f"the robot was carried at {j.start:.3f} s: its sweeps stopped fitting the map where the "
                           f"motion prior put them and fit nowhere in the local map; from {j.found:.3f} s the poses "
                           "are a new piece, relative to an unknown offset from those before")
        return out
