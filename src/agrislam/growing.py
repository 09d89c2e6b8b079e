"""A column of rows appended one at a time and read as one array (DESIGN.md "State
layout"): per-frame history (dead reckoning, step times, a chain's pose times) without a
Python object per row. Capacity doubles, so appending is amortised O(1)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, DTypeLike


def grown(old: np.ndarray, size: int, fill: float) -> np.ndarray:
    """`old` with room for `size` rows, the new ones `fill`ed (a table's columns, grown by
    doubling where they are kept)."""
    shape = (size, *old.shape[1:])
    # zeros come from calloc, whose pages are touched only when written: doubling a whole
    # field's table (tens of MB) then costs the copy of the old rows alone, not a fill too
    new = np.zeros(shape, dtype=old.dtype) if fill == 0 else np.full(shape, fill, old.dtype)
    new[: len(old)] = old
    return new


class GrowingRows:
    """Rows of shape `row` (() for scalars), appended in order; `array` is a view of them."""

    def __init__(self, row: tuple[int, ...] = (), dtype: DTypeLike = float) -> None:
        self._data = np.zeros((16, *row), dtype=dtype)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, row: ArrayLike) -> None:
        self._reserve(self._n + 1)
        self._data[self._n] = row
        self._n += 1

    def extend(self, rows: ArrayLike) -> None:
        """Append each of `rows` ((k, *row))."""
        rows = np.asarray(rows, dtype=self._data.dtype)
        self._reserve(self._n + len(rows))
        self._data[self._n : self._n + len(rows)] = rows
        self._n += len(rows)

    def _reserve(self, n: int) -> None:
        if n > len(self._data):
            self._data = grown(self._data, max(n, 2 * len(self._data)), 0)

    @property
    def array(self) -> np.ndarray:
        """(n, *row) the rows so far (a view: copy it to keep it)."""
        return self._data[: self._n]
