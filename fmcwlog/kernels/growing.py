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
    view of those appended so far (valid until the next :meth:`append`).

    A row given as a tuple (immutable: its values cannot change before they are stored) waits in a
    short list and is stored with the others in one assignment (:data:`BATCH` rows, or at the next
    read): numpy converts a tuple of numbers once per assignment, not once per row. Any other row
    (an array the caller may change afterwards) is stored at once."""

    BATCH = 64

    def __init__(self, dtype: np.dtype | type, row_shape: tuple[int, ...] = (), capacity: int = 1024):
        self._data = np.zeros((capacity, *row_shape), dtype)
        self._n = 0
        self._waiting: list[tuple] = []

    def __len__(self) -> int:
        return self._n + len(self._waiting)

    def append(self, row) -> None:
        if type(row) is tuple:
            self._waiting.append(row)
            if len(self._waiting) >= self.BATCH:
                self._store_waiting()
            return
        if self._waiting:
            self._store_waiting()
        self._reserve(1)
        self._data[self._n] = row
        self._n += 1

    def _reserve(self, k: int) -> None:
        """Room for ``k`` more rows (doubling as often as needed)."""
        size = len(self._data)
        if self._n + k <= size:
            return
        while self._n + k > size:
            size = max(2 * size, 1)
        grown = np.zeros((size, *self._data.shape[1:]), self._data.dtype)
        grown[: self._n] = self._data[: self._n]
        self._data = grown

    def _store_waiting(self) -> None:
        """The waiting tuple rows into the array, in order, in one assignment."""
        rows, self._waiting = self._waiting, []
        self._reserve(len(rows))
        self._data[self._n : self._n + len(rows)] = rows
        self._n += len(rows)

    @property
    def values(self) -> np.ndarray:
        if self._waiting:
            self._store_waiting()
        return self._data[: self._n]
