"""An append-only numpy array that grows by doubling: a few numbers per sweep kept for a whole log.

A Python list of per-sweep values holds an object per value (a ``float`` or ``numpy.float64``:
24-32 bytes, plus the list's 8-byte slot, and a 3-pose array ~130 bytes); this holds the same
values in place, in their own dtype (8 bytes a float64), so that what ``process`` keeps per sweep
stays small on a long log. The values are stored as given (a float64 stays that float64): nothing
is rounded.
"""

from __future__ import annotations

import numpy as np


class GrowingArray:
    """Rows of shape ``row_shape`` and dtype ``dtype``, appended one at a time; :attr:`values` is a
    view of those appended so far (valid until the next :meth:`append`)."""

    def __init__(self, dtype: np.dtype | type, row_shape: tuple[int, ...] = (), capacity: int = 1024):
        self._data = np.zeros((capacity, *row_shape), dtype)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, row) -> None:
        if self._n == len(self._data):
            grown = np.zeros((2 * len(self._data), *self._data.shape[1:]), self._data.dtype)
            grown[: self._n] = self._data
            self._data = grown
        self._data[self._n] = row
        self._n += 1

    @property
    def values(self) -> np.ndarray:
        return self._data[: self._n]
