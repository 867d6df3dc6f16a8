"""Is the scanner mounted as the calibration says? Its scan mirrored (upside down) or turned round.

Not in the paper. A scanner mounted upside down sees the world mirrored about its x axis (a
point's y negated; its Doppler stays with it); one whose ``lidar_yaw`` is off by π sees it turned
round. Either way the scans *and* Doppler (measured in the same frame) move as the wheels never
did, and the sensor checks (:mod:`.sensor_checks`), where Doppler and the scans outvote the wheels,
would blame the wheels. This check asks the scans which frame they are in: over windows of
``window_sweeps`` intervals the window's last sweep is carried into its first sweep's frame by the
wheels' motion, read in the scan frame of each hypothesis (the frame as calibrated; mirrored
``y -> -y``; turned by π ``(x, y) -> (-x, -y)``; both ``x -> -x``), and the hypothesis whose points
land on the first sweep's (mean capped nearest-neighbour distance below ``witness_ratio`` of the
calibrated frame's) wins the window. A mirror shows in turns only (driving straight along the
lidar's x axis looks the same mirrored); a frame turned by π in any motion.

The wheels have faults that look alike: ticks left and right swapped turn the wheels' motion the
way a mirror turns the scans' (for a lidar on base_link's x axis, facing along it or against it,
exactly: the two explain the same log), ticks negated nearly as a frame turned by π (straight,
exactly; in turns the heading change keeps its sign under a turned frame and flips under negated
ticks). So each window also carries the sweep by the wheels' motion with that fault, in the frame
as calibrated, and the check says which explanation the scans prefer: the scanner (the wheels are
not to be blamed, :meth:`.sensor_checks.SensorChecks.exonerate_wheels`), the wheels (nothing is
said here: the sensor checks say it), or either (the warning names both, with the calibration
key for the scanner).

A mirror is ``lidar_upside_down`` the other way (the sensor rolled by π about its x axis, whose
sweeps are read mirrored back: :class:`fmcwlog.io.inputs.LogInputs`); a frame turned by π is
``lidar_yaw`` plus π; the warning gives the keys and their values. The cost: a nearest-point grid
(a KD-tree with the numpy kernels) over 256 points and seven queries of 256 points once per window
of moving sweeps, at most ``max_checks`` per log; nothing once a verdict is reached.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..config import Checked, param
from ..geometry import compose, inverse, transform_points
from ..kernels import compiled

SCANNER, WHEELS, EITHER = "scanner", "wheels", "either"  # who the scans blame for a frame that is not the calibrated one
MIRRORED, TURNED, MIRRORED_TURNED = "mirrored", "turned_by_pi", "mirrored_and_turned_by_pi"


def _mirror(p: np.ndarray) -> np.ndarray:
    """A motion (x, y, yaw) seen in the frame mirrored about its x axis."""
    return np.array([p[0], -p[1], -p[2]])


def _turn(p: np.ndarray) -> np.ndarray:
    """A motion seen in the frame turned by π."""
    return np.array([-p[0], -p[1], p[2]])


def _mirror_turn(p: np.ndarray) -> np.ndarray:
    """A motion seen in the frame mirrored about its y axis (mirrored and turned by π)."""
    return np.array([-p[0], p[1], -p[2]])


# hypothesis -> (a motion in the calibrated scan frame as the faulty frame sees it, the wheel fault
# that mimics it: each interval's motion as such wheels would report it, the fault in words for wheel
# ticks and for odometry)
_Twin = Callable[[np.ndarray], np.ndarray]
HYPOTHESES: dict[str, tuple[_Twin, _Twin, str, str]] = {
    MIRRORED: (_mirror, _mirror, "left and right swapped", "turning the wrong way"),
    TURNED: (_turn, inverse, "counting backwards", "running backwards"),
    MIRRORED_TURNED: (_mirror_turn, lambda b: _mirror(inverse(b)), "counting backwards with left and right swapped",
                      "running backwards"),
}


@dataclass(frozen=True)
class MountCheckParams(Checked):
    """Parameters of the check of the scanner's frame (:mod:`.mirror_check`).

    enabled: whether the check runs; off, a mirrored or turned scanner goes unsaid and the sensor
        checks may blame the wheels for it.
    window_sweeps: intervals between sweeps in a window (>= 2); windows do not overlap.
    min_motion: a window is judged where the wheels say the lidar moved this far, or turned
        ``min_turn`` (m, > 0).
    min_turn: ... (rad, > 0).
    witness_ratio: a hypothesis wins a window where its mean capped nearest-neighbour distance is
        below this fraction of the other's, in (0, 1].
    witness_min_gap: ... and below it by at least this much (m, >= 0).
    witness_cap: each nearest-neighbour distance counts at most this much (m, > 0).
    witness_points: at most this many of a sweep's points are carried (a strided subset, >= 10).
    min_evidence: windows a hypothesis must win against the calibrated frame before it is said (>= 1).
    verdict_fraction: ... and the share of the windows decided between the two it must win, in (0.5, 1].
    max_checks: windows judged per log at most (>= 0).
    """

    enabled: bool = True
    window_sweeps: int = param(10, "sweeps", ge=2, le=10000)
    min_motion: float = param(0.3, "m", gt=0, le=100)
    min_turn: float = param(0.15, "rad", gt=0, le=10)
    witness_ratio: float = param(0.7, "", gt=0, le=1)
    witness_min_gap: float = param(0.01, "m", ge=0, le=1)
    witness_cap: float = param(0.3, "m", gt=0, le=10)
    witness_points: int = param(256, "points", ge=10, le=1000000)
    min_evidence: int = param(3, "windows", ge=1, le=1000000)
    verdict_fraction: float = param(0.8, "", gt=0.5, le=1)
    max_checks: int = param(200, "windows", ge=0, le=1000000000)


class Witness:
    """A sweep's points (N, 2) to measure other points' nearest distances against, up to ``cap`` (m):
    the compiled kernels' ``TargetGrid`` where :func:`fmcwlog.kernels.compiled.core` selects them (the
    KD-tree's distances, to the rounding of the moved points), else a ``cKDTree`` (the reference)."""

    def __init__(self, points: np.ndarray, cap: float):
        self.cap = cap
        self._core = compiled.core()
        self._index: object
        if self._core is not None:
            self._index = self._core.TargetGrid(np.ascontiguousarray(points, dtype=float), cap)
        else:
            from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports

            self._index = cKDTree(points)

    def distances(self, pts: np.ndarray, motion: np.ndarray) -> np.ndarray:
        """Each of ``pts`` (M, 2), carried by ``motion`` (x, y, yaw), to its nearest point (m); inf
        where none is nearer than ``cap``."""
        if self._core is None:
            d, _ = self._index.query(transform_points(motion, pts), k=1, distance_upper_bound=self.cap)  # type: ignore[attr-defined]
            return d
        src = np.ascontiguousarray(pts, dtype=float)
        n = len(src)
        moved, index, dist = np.empty((n, 2)), np.empty(n, np.int64), np.empty(n)
        x, y, yaw = (float(v) for v in motion)
        self._core.nearest(self._index, src, x, y, yaw, moved, index, dist)
        return dist


@dataclass
class MountCheck:
    """The scans asked which frame they are in, window by window (module docstring).

    ``mount``: the lidar in base_link as calibrated (m, m, rad); ``upside_down``: as calibrated
    (``lidar_upside_down``: the sweeps fed are mirrored back already). Feed :meth:`sweep` each sweep's
    points (lidar frame) and :meth:`interval` the wheels' motion between consecutive sweeps, in
    time order; :meth:`verdict` is the hypothesis found (None: the calibrated frame, or too little
    evidence), :meth:`blame` whom the scans blame for it.
    """

    mount: np.ndarray
    params: MountCheckParams = field(default_factory=MountCheckParams)
    upside_down: bool = False
    judged: int = 0  # windows judged
    won: dict[str, int] = field(default_factory=lambda: dict.fromkeys(HYPOTHESES, 0))  # ... won against the calibrated frame
    lost: dict[str, int] = field(default_factory=lambda: dict.fromkeys(HYPOTHESES, 0))  # ... lost to it
    scanner: dict[str, int] = field(default_factory=lambda: dict.fromkeys(HYPOTHESES, 0))  # the scanner's fault fits better
    wheels: dict[str, int] = field(default_factory=lambda: dict.fromkeys(HYPOTHESES, 0))  # the wheels' fault fits better
    found_at: float | None = None  # stamp (s) of the window that settled the verdict
    _t0: float | None = None
    _sweeps: dict[float, np.ndarray] = field(default_factory=dict)
    _window: list[tuple[float, float, np.ndarray]] = field(default_factory=list)  # (t_prev, stamp, wheels' motion)

    def sweep(self, stamp: float, xy: np.ndarray) -> None:
        """The sweep at ``stamp`` (s): its points (N, 2) in the lidar frame (m), a strided subset kept."""
        if self._t0 is None:
            self._t0 = stamp
        if not self.params.enabled or self.settled:
            return
        # a strided view, not a copy: a window judges only its first and last sweep (``_judge``)
        self._sweeps[stamp] = xy[:: max(1, len(xy) // self.params.witness_points)]
        while len(self._sweeps) > self.params.window_sweeps + 2:
            del self._sweeps[min(self._sweeps)]

    def interval(self, t_prev: float, stamp: float, wheels: np.ndarray | None) -> None:
        """base_link's motion from the sweep at ``t_prev`` to the one at ``stamp`` (s) by the wheels
        (x, y, yaw in its frame at ``t_prev``; None: none, a gap). Judges the window ending here when full."""
        p = self.params
        if not p.enabled or self.settled:
            return
        motion = None if wheels is None else [float(v) for v in wheels[:3]]
        usable = motion is not None and all(map(math.isfinite, motion))
        if not usable or (self._window and self._window[-1][1] != t_prev):
            self._window.clear()
            if not usable:
                return
        self._window.append((t_prev, stamp, np.array(motion)))
        if len(self._window) < p.window_sweeps:
            return
        window, self._window = self._window, []
        if self.judged < p.max_checks:
            self._judge(window)

    @property
    def settled(self) -> bool:
        """A verdict was reached and whom it blames, or the checks ran out."""
        return (self.found_at is not None and self.blame() != EITHER) or self.judged >= self.params.max_checks

    def _judge(self, window: list[tuple[float, float, np.ndarray]]) -> None:
        first, last = self._sweeps.get(window[0][0]), self._sweeps.get(window[-1][1])
        if first is None or last is None or len(first) < 10 or len(last) < 10:
            return
        base = _chain(b for _, _, b in window)
        p = self.params
        if math.hypot(base[0], base[1]) < p.min_motion and abs(base[2]) < p.min_turn:
            return
        self.judged += 1
        tree = Witness(first, p.witness_cap)
        lidar = self._in_lidar(base)
        calibrated = self._misfit(tree, last, lidar)
        e_wheels: float | None = None  # the best of the wheel faults, in the calibrated frame
        for name, (seen, _, _, _) in HYPOTHESES.items():
            e_scan = self._misfit(tree, last, seen(lidar))
            if self._beats(e_scan, calibrated):
                self.won[name] += 1
            elif self._beats(calibrated, e_scan):
                self.lost[name] += 1
                continue
            else:
                continue
            if e_wheels is None:
                e_wheels = min(self._misfit(tree, last, self._in_lidar(_chain(f(b) for _, _, b in window)))
                               for _, f, _, _ in HYPOTHESES.values())
            if self._beats(e_scan, e_wheels):
                self.scanner[name] += 1
            elif self._beats(e_wheels, e_scan):
                self.wheels[name] += 1
        if self.found_at is None and self.verdict() is not None:
            self.found_at = window[-1][1] - (self._t0 or 0.0)

    @property
    def _yaw(self) -> float:
        return float(self.mount[2])

    def _in_lidar(self, base: np.ndarray) -> np.ndarray:
        """base_link's motion as the (calibrated) lidar frame moved."""
        return compose(compose(inverse(self.mount), base), self.mount)

    def _beats(self, a: float, b: float) -> bool:
        p = self.params
        return a < p.witness_ratio * b and b - a > p.witness_min_gap

    def _misfit(self, tree: Witness, pts: np.ndarray, motion: np.ndarray) -> float:
        """Mean distance (m), each capped at ``witness_cap``, from ``pts`` carried by ``motion`` to the witness's points."""
        cap = self.params.witness_cap
        return float(np.mean(np.minimum(tree.distances(pts, motion), cap)))

    def verdict(self) -> str | None:
        """The hypothesis the scans chose over the calibrated frame: won ``min_evidence`` windows,
        ``verdict_fraction`` of those decided between the two, and more than any other; else None."""
        p = self.params
        best = max(HYPOTHESES, key=lambda n: self.won[n])
        if any(self.won[n] >= self.won[best] for n in HYPOTHESES if n != best):
            return None  # two frames fit alike (driving straight, mirrored and turned can): a turn tells
        ok = self.won[best] >= p.min_evidence and self.won[best] >= p.verdict_fraction * (self.won[best] + self.lost[best])
        return best if ok else None

    def blame(self) -> str | None:
        """Whom the scans blame for :meth:`verdict`: :data:`SCANNER` (its frame fits the wheels' motion
        better than any of the wheel faults fits the calibrated frame, in ``verdict_fraction`` of the
        windows that tell them apart), :data:`WHEELS` (the other way round), :data:`EITHER`."""
        name = self.verdict()
        if name is None:
            return None
        s, w = self.scanner[name], self.wheels[name]
        if s >= 2 and s >= self.params.verdict_fraction * (s + w):
            return SCANNER
        if w >= 2 and w >= self.params.verdict_fraction * (s + w):
            return WHEELS
        return EITHER

    def warning(self, prior_name: str) -> str | None:
        """The finding in one line, with its numbers and the calibration key; None without one, or
        where the scans blame the wheels (the sensor checks say that)."""
        name, who = self.verdict(), self.blame()
        if name is None or who == WHEELS:
            return None
        fault = self._wheel_fault(name, prior_name)
        if who == SCANNER:
            return (f"{self._found(name, prior_name)}, and better than with the {prior_name} {fault} or any such fault "
                    f"({self.scanner[name]} of {self.scanner[name] + self.wheels[name]} windows that tell the two apart): "
                    f"the LiDAR is {_fix(name, self._yaw, self.upside_down)}; the {prior_name} are not to blame "
                    "(Doppler, measured in the scan's frame, shares the fault)")
        verb = "are" if prior_name.endswith("s") else "is"
        return (f"{self._found(name, prior_name)}: the LiDAR is {_fix(name, self._yaw, self.upside_down)}; or the {prior_name} "
                f"{verb} {fault} (at this mount the two look the same)")

    def alternative(self, prior_name: str) -> str | None:
        """The scanner's side of an :data:`EITHER` verdict, to be said with the line that blames the wheels."""
        name = self.verdict()
        if name is None or self.blame() != EITHER:
            return None
        return (f"or the LiDAR is {_fix(name, self._yaw, self.upside_down)}, which at this mount looks the same: "
                f"{self._found(name, prior_name)}")

    def _found(self, name: str, prior_name: str) -> str:
        n = self.won[name] + self.lost[name]
        return (f"scan matching fits the motion of the {prior_name} only with the scan {_words(name)} "
                f"({self.won[name]} of {n} windows of {self.params.window_sweeps} sweeps that tell, by {self.found_at:.1f} s)")

    @staticmethod
    def _wheel_fault(name: str, prior_name: str) -> str:
        _, _, ticks, odometry = HYPOTHESES[name]
        return ticks if "tick" in prior_name else odometry

    def summary(self) -> dict:
        """The counts and the verdict, for ``run.json``."""
        name = self.verdict()
        return {"windows": self.judged, "won": dict(self.won), "lost": dict(self.lost),
                "scanner_fits_better": dict(self.scanner), "wheels_fault_fits_better": dict(self.wheels),
                "verdict": name, "blame": self.blame(), "found_at_s": self.found_at}


def _chain(motions) -> np.ndarray:
    out = np.zeros(3)
    for m in motions:
        out = compose(out, m)
    return out


def _words(name: str) -> str:
    return {MIRRORED: "mirrored about the lidar's x axis (y -> -y)", TURNED: "turned by 180 degrees",
            MIRRORED_TURNED: "mirrored about the lidar's y axis (x -> -x)"}[name]


def _fix(name: str, yaw: float, upside_down: bool = False) -> str:
    """What the mount is and the calibration keys that say it (``upside_down``: as calibrated)."""
    turned = math.atan2(math.sin(yaw + math.pi), math.cos(yaw + math.pi))
    mirror = ("mounted upright, not upside down as calibrated (its scan mirrored)" if upside_down
              else "mounted upside down (its scan mirrored)")
    flag = f"lidar_upside_down: {'false' if upside_down else 'true'}"
    if name == MIRRORED:
        return f"{mirror}: set {flag} in the calibration (--calibration)"
    if name == TURNED:
        return f"facing the other way: set lidar_yaw: {turned:.6f} (not {yaw:.6f}) in the calibration (--calibration)"
    return (f"{mirror} and facing the other way: set {flag} and lidar_yaw: {turned:.6f} (not {yaw:.6f}) in the "
            "calibration (--calibration)")
