"""What the front end's stages read of a sweep before any of them runs, in one pass over it.

A sweep's points ``xy`` (N, 2) in the lidar frame at their own capture times ``t`` (N,) (s after
its stamp): their ranges (m) and the body mask (ranges below ``min_range``), the unit bearings the
Doppler stages use (:func:`~.egomotion.unit_bearings`), the sweep's last capture time (s; how long
its twist acts) and its middle time (s; the tracker's time of the sweep,
:func:`~.tracking.middle_time`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..kernels import compiled
from .egomotion import _points, unit_bearings_numpy
from .tracking import middle_time


class SweepGeometry(NamedTuple):
    """One sweep's geometry (module docstring); ``xy`` the points it was read from."""

    xy: np.ndarray  # (N, 2) m
    ranges: np.ndarray  # (N,) m, np.hypot of the rows
    near: np.ndarray  # (N,) bool, ranges < min_range
    bearings: np.ndarray | None  # (N, 2) unit bearings, where asked for
    last_time: float  # s, np.maximum.reduce(t, initial=0.0)
    middle_time: float | None  # s, middle_time(t), where asked for


def sweep_geometry(xy: np.ndarray, t: np.ndarray, min_range: float, bearings: bool, middle: bool) -> SweepGeometry:
    """:class:`SweepGeometry` of the points ``xy`` (N, 2) seen at ``t`` (N,): the bearings where
    ``bearings``, the middle time where ``middle``.

    The compiled kernel where :func:`fmcwlog.kernels.compiled.core` selects it (one call: the same
    ``hypot``, comparison and division, the same bits; the times' maximum and middle value where they
    are finite and sorted, else numpy's), else :func:`sweep_geometry_numpy`."""
    core = compiled.core()
    if (core is not None and _points(xy) and type(t) is np.ndarray and t.dtype == np.float64
            and t.shape == xy.shape[:1] and t.flags.c_contiguous):
        ranges, near, u, last, mid = core.sweep_geometry(xy, t, float(min_range), bool(bearings))
        if last is None:
            last = float(np.maximum.reduce(t, initial=0.0))
        if middle and mid is None:
            mid = middle_time(t)
        return SweepGeometry(xy, ranges, near, u, last, mid if middle else None)
    return sweep_geometry_numpy(xy, t, min_range, bearings, middle)


def sweep_geometry_numpy(xy: np.ndarray, t: np.ndarray, min_range: float, bearings: bool,
                         middle: bool) -> SweepGeometry:
    """:func:`sweep_geometry` in numpy: the reference."""
    ranges = np.hypot(xy[:, 0], xy[:, 1])
    return SweepGeometry(xy, ranges, ranges < min_range, unit_bearings_numpy(xy) if bearings else None,
                         float(np.maximum.reduce(t, initial=0.0)), middle_time(t) if middle else None)
