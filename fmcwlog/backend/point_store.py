"""Data that only grows with a log's length, moved out of memory until it is needed again.

:class:`PointStore`: the back end's nodes' points (:mod:`fmcwlog.backend.keyframes`) in an
unnamed temporary file (the system's temporary folder; removed when closed or when the process
ends, so nothing is left beside the outputs), read back as the same bytes.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from ..errors import OutputError, os_reason


@contextmanager
def _reported() -> Iterator[None]:
    """The temporary file's failures (a full or missing temporary folder) as one line naming it."""
    try:
        yield
    except OSError as exc:
        try:
            folder = tempfile.gettempdir()
        except OSError:
            folder = "the temporary folder"
        raise OutputError(f"{folder}: cannot keep fmcwlog's temporary point store: {os_reason(exc)} "
                          "(TMPDIR chooses another folder)") from None


class PointStore:
    """Nodes' points moved out of memory into an unnamed temporary file (deleted when closed or
    when the process ends), read back as the same float32 bytes when a node is used again.

    A node's points are read when it is matched (the few latest nodes, kept in memory), when it
    is near a loop-closure candidate and when the final map is rebuilt; between those they are
    bytes that only grow with the log's length (about 4 kB a node, a node per 0.5 m).
    """

    def __init__(self) -> None:
        with _reported():
            self._file = tempfile.TemporaryFile(prefix="fmcwlog-nodes-")
        self._end = 0

    def put(self, points: np.ndarray) -> tuple[int, int]:
        """Append ``points`` (N, 2) float32 (as they are: nothing is converted); returns where they
        lie (byte offset, N)."""
        if points.dtype != np.float32 or points.ndim != 2 or points.shape[1] != 2:
            raise ValueError(f"a point store holds (N, 2) float32 points, not {points.shape} {points.dtype}")
        data = np.ascontiguousarray(points).tobytes()
        with _reported():
            self._file.seek(self._end)
            self._file.write(data)
        where = (self._end, len(points))
        self._end += len(data)
        return where

    def get(self, where: tuple[int, int]) -> np.ndarray:
        """The points (N, 2) float32 stored at ``where`` (read-only)."""
        offset, n = where
        self._file.seek(offset)
        data = self._file.read(8 * n)
        if len(data) != 8 * n:  # the temporary file cut short under us: say so rather than mis-shape
            raise OSError(f"fmcwlog's temporary point store {self._file.name!r} lost data")
        return np.frombuffer(data, np.float32).reshape(n, 2)

    def close(self) -> None:
        self._file.close()
