"""A column of rows appended one at a time and read as one array (DESIGN.md "State
layout"): per-frame history (dead reckoning, step times, a chain's pose times) without a
Python object per row. Capacity doubles, so appending is amortised O(1)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, DTypeLike


class GrowingRows:
    """Rows of shape `row` (() for scalars), appended in order; `array` is a view of them."""

    def __init__(self, row: tuple[int, ...] = (), dtype: DTypeLike = float) -> None:
        self._data = np.zeros((16, *row), dtype=dtype)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, row: ArrayLike) -> None:
        if self._n == len(self._data):
            grown = np.zeros((2 * self._n, *self._data.shape[1:]), dtype=self._data.dtype)
            grown[: self._n] = self._data
            self._data = grown
        self._data[self._n] = row
        self._n += 1

    @property
    def array(self) -> np.ndarray:
        """(n, *row) the rows so far (a view: copy it to keep it)."""
        return self._data[: self._n]
