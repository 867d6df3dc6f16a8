"""People and carts that walk or roll back and forth along polylines.

A mover goes from the first point of its path to the last at constant speed,
turns round and comes back, for ever (``phase`` is how far along it is at
t = 0, in metres). People are circles seen from above; carts are rectangles
that keep their long side along the direction of travel. Their velocity is
what the LiDAR's Doppler sees of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mover:
    kind: str  # "person" or "cart"
    path: np.ndarray  # (K, 2) waypoints, m
    speed: float  # m/s
    phase: float = 0.0  # m along the back-and-forth cycle at t = 0
    radius: float = 0.25  # m, people
    length: float = 1.0  # m, carts
    width: float = 0.6  # m, carts

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", np.asarray(self.path, dtype=float).reshape(-1, 2))

    @property
    def path_length(self) -> float:
        return float(np.linalg.norm(np.diff(self.path, axis=0), axis=1).sum())

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre (N, 2) and velocity (N, 2) in ``map`` at times ``t`` (N,), in s."""
        t = np.asarray(t, dtype=float)
        seg = np.diff(self.path, axis=0)
        seg_len = np.linalg.norm(seg, axis=1)
        total = seg_len.sum()
        if total < 1e-9 or self.speed == 0.0:
            return np.broadcast_to(self.path[0], t.shape + (2,)).copy(), np.zeros(t.shape + (2,))
        cyc = np.mod(self.phase + self.speed * t, 2.0 * total)
        back = cyc > total
        s = np.where(back, 2.0 * total - cyc, cyc)
        starts = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])
        i = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(seg) - 1)
        direction = seg[i] / seg_len[i, None]
        pos = self.path[i] + direction * (s - starts[i])[:, None]
        vel = direction * (self.speed * np.where(back, -1.0, 1.0))[:, None]
        return pos, vel
