"""The motion prior's physically impossible jumps, caught as the messages are read.

A motion-prior message moves the robot at most :data:`~fmcwlog.io.sweeps.MAX_SPEED` (100 m/s)
since the last one, plus 2 ticks or 1 cm of quantisation; a 32-bit counter wrap (a jump of
exactly ±2^32 ticks) is unwrapped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry import compose, inverse
from ..types import WheelCalibration
from .sweeps import MAX_SPEED

_WRAP = 1 << 32


@dataclass
class Gate:
    """A motion-prior stream's physically impossible jumps (module docstring).

    A message that moves farther than ``MAX_SPEED`` allows since the last accepted one is
    skipped; if the next message moves plausibly from the skipped one, the jump was real (a
    counter reset, odometry re-zeroed): the skipped message becomes a new origin placed on the
    last accepted one, and the motion across the jump is lost (counted as a rebase).
    """

    last: tuple[float, Any] | None = None  # (s, value) of the last accepted message, after offsets
    pending: tuple[float, Any] | None = None  # the skipped message, raw
    rebases: int = 0


class TickGate(Gate):
    def __init__(self, wheels: WheelCalibration):
        super().__init__()
        # ticks per metre of each wheel
        self.per_m = tuple(wheels.ticks_per_revolution / (2 * math.pi * r)
                           for r in (wheels.wheel_radius_left, wheels.wheel_radius_right))
        # added to the counts read (python ints, as the int64 counts are); set at the first message to
        # start the counts at 0: the prior integrates differences of counts held as int64 and float64,
        # exact only below 2**53, and a counter that started near 2**63 overflowed int64 after a reset
        self.offset: tuple[int, int] | None = None
        self.wraps = 0

    def _plausible(self, t0: float, c0: tuple[int, int], t1: float, c1: tuple[int, int]) -> bool:
        return all(abs(b - a) <= k * MAX_SPEED * (t1 - t0) + 2 for a, b, k in zip(c0, c1, self.per_m))

    def feed(self, t: float, left: int, right: int) -> tuple[int, int] | None:
        """The counts to integrate (unwrapped, rebased), or None to skip this message."""
        if self.offset is None:
            self.offset = (-left, -right)
        counts = (left + self.offset[0], right + self.offset[1])
        if self.last is None:
            return self._accept(t, counts)
        t0, c0 = self.last
        if self._plausible(t0, c0, t, counts):
            return self._accept(t, counts)
        # the nearest counts modulo 2^32: the same if the jump was exactly one 32-bit wrap
        near = tuple(a + (b - a + _WRAP // 2) % _WRAP - _WRAP // 2 for a, b in zip(c0, counts))
        if all(abs(n - c) in (0, _WRAP) for n, c in zip(near, counts)) and self._plausible(t0, c0, t, near):
            self.wraps += sum(n != c for n, c in zip(near, counts))
            self.offset = (self.offset[0] + near[0] - counts[0], self.offset[1] + near[1] - counts[1])
            return self._accept(t, (near[0], near[1]))
        raw = (left, right)
        if self.pending is not None and self._plausible(self.pending[0], self.pending[1], t, raw):
            self.offset = (c0[0] - self.pending[1][0], c0[1] - self.pending[1][1])
            self.rebases += 1
            return self._accept(t, (left + self.offset[0], right + self.offset[1]))
        self.pending = (t, raw)
        return None

    def _accept(self, t: float, counts: tuple[int, int]) -> tuple[int, int]:
        self.last = (t, counts)
        self.pending = None
        return counts


class PoseGate(Gate):
    def __init__(self) -> None:
        super().__init__()
        self.offset: np.ndarray | None = None  # applied once a jump has been rebased

    def feed(self, t: float, raw: np.ndarray) -> np.ndarray | None:
        pose = compose(self.offset, raw) if self.offset is not None else raw
        if self.last is None or self._plausible(self.last, t, pose):
            self.last, self.pending = (t, pose), None
            return pose
        if self.pending is not None and self._plausible((self.pending[0], self.pending[1]), t, raw):
            self.offset = compose(self.last[1], inverse(self.pending[1]))
            self.rebases += 1
            pose = compose(self.offset, raw)
            self.last, self.pending = (t, pose), None
            return pose
        self.pending = (t, raw)
        return None

    @staticmethod
    def _plausible(last: tuple[float, np.ndarray], t: float, pose: np.ndarray) -> bool:
        return bool(math.hypot(*(pose[:2] - last[1][:2])) <= MAX_SPEED * (t - last[0]) + 0.01)
