"""Voxel thinning: one point per square voxel, the first in the order given, or the voxel's centroid.

Points ``xy`` (N, 2) in any frame, in metres; a voxel is the square cell ``floor(xy / size)``.
:func:`voxel_downsample` keeps a measured point per voxel, the first in the order given (in a
sweep's beam order: the one nearest the voxel's edge the scan enters by); :func:`voxel_centroids`
the mean of each voxel's points, which does not depend on their order (the front end's
``source_thinning = "centroid"``; docs/design/frontend-params.md).
"""

from __future__ import annotations

import numpy as np

from . import compiled


def voxel_keys(xy: np.ndarray, size: float) -> np.ndarray:
    """One int64 key per point naming its square voxel of side ``size`` (m)."""
    ij = np.floor(xy / size).astype(np.int64)
    return (ij[:, 0] << 32) ^ (ij[:, 1] & 0xFFFFFFFF)


def voxel_downsample(xy: np.ndarray, size: float) -> np.ndarray:
    """The first point (in order) of each occupied voxel: (M, 2) with M <= N, in the order given.

    ``size`` <= 0 or an empty input returns ``xy`` itself. The compiled kernel where
    :func:`fmcwlog.kernels.compiled.core` selects it and ``xy`` is float64 (N, 2) (one pass with a
    hash set: the same points in the same order), else :func:`voxel_downsample_numpy`.
    """
    if len(xy) == 0 or size <= 0:
        return xy
    core = _core_for(xy)
    if core is not None:
        return core.voxel_downsample(np.ascontiguousarray(xy), float(size))
    return voxel_downsample_numpy(xy, size)


def voxel_downsample_numpy(xy: np.ndarray, size: float) -> np.ndarray:
    """:func:`voxel_downsample` in numpy: the reference the compiled kernel is tested against."""
    if len(xy) == 0 or size <= 0:
        return xy
    _, first = np.unique(voxel_keys(xy, size), return_index=True)
    return xy[np.sort(first)]


def voxel_centroids(xy: np.ndarray, size: float) -> np.ndarray:
    """The centroid of each occupied voxel's points: (M, 2), in the order of each voxel's first point.

    ``size`` <= 0 or an empty input returns ``xy`` itself. The compiled kernel where
    :func:`fmcwlog.kernels.compiled.core` selects it and ``xy`` is float64 (N, 2) (one pass with a
    hash map, the sums in the order given: the same floats), else :func:`voxel_centroids_numpy`.
    """
    if len(xy) == 0 or size <= 0:
        return xy
    core = _core_for(xy)
    if core is not None:
        return core.voxel_centroids(np.ascontiguousarray(xy), float(size))
    return voxel_centroids_numpy(xy, size)


def voxel_centroids_numpy(xy: np.ndarray, size: float) -> np.ndarray:
    """:func:`voxel_centroids` in numpy: the reference the compiled kernel is tested against (each
    voxel's coordinates summed in the order given, then divided by its count)."""
    if len(xy) == 0 or size <= 0:
        return xy
    _, first, inverse = np.unique(voxel_keys(xy, size), return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    count = np.bincount(inverse)
    mean = np.stack([np.bincount(inverse, xy[:, 0]), np.bincount(inverse, xy[:, 1])], axis=1) / count[:, None]
    return mean[np.argsort(first, kind="stable")]


def _core_for(xy: np.ndarray):
    """The compiled module where :func:`fmcwlog.kernels.compiled.core` selects it and ``xy`` is a
    float64 (N, 2) array, the kernels' input; else None (the numpy reference runs)."""
    core = compiled.core()
    if core is not None and type(xy) is np.ndarray and xy.dtype == np.float64 and xy.ndim == 2 and xy.shape[1] == 2:
        return core
    return None
