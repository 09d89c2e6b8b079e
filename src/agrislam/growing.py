"""A column of rows appended one at a time and read as one array (DESIGN.md "State
layout"): per-frame history (dead reckoning, step times, a chain's pose times) without a
Python object per row. Capacity doubles, so appending is amortised O(1)."""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

AHEAD = 8  # a table's doubled columns are made over the last 1/AHEAD of its capacity


def grown(old: np.ndarray, size: int, fill: float) -> np.ndarray:
    """`old` with room for `size` rows, the new ones `fill`ed (a table's columns, grown by
    doubling where they are kept)."""
    shape = (size, *old.shape[1:])
    # zeros come from calloc, whose pages are touched only when written: doubling a whole
    # field's table then costs the copy of the old rows alone, not a fill too
    new = np.zeros(shape, dtype=old.dtype) if fill == 0 else np.full(shape, fill, old.dtype)
    new[: len(old)] = old
    return new


class Doubling:
    """How a table's columns grow: doubled when full (amortised O(1) a row), the doubled arrays
    made ahead, since memory touched for the first time is what a doubling costs: over the last
    1/AHEAD of the capacity each reserve writes a slice of the doubled columns (their fill, or
    zeros where the copy goes), so the row that fills the table only copies. `fills`: the
    value of a column's unused rows (zero where it names no column)."""

    def __init__(self, fills: Mapping[Hashable, float] | None = None) -> None:
        self.fills = dict(fills or {})
        self._next: dict[Hashable, np.ndarray] = {}
        self._made = 0  # leading rows of the doubled columns written so far

    def __getstate__(self) -> dict[str, object]:
        """A pickle (a checkpoint) leaves the doubled columns out: they are made again."""
        return {"fills": self.fills, "_next": {}, "_made": 0}

    @property
    def made(self) -> int:
        """Rows of the doubled columns made ahead so far (0 outside the last 1/AHEAD)."""
        return self._made

    def reserve(
        self, n: int, capacity: int, columns: Callable[[], Mapping[Hashable, np.ndarray]]
    ) -> dict[Hashable, np.ndarray] | None:
        """Room for `n` rows in the table's `columns()` (of `capacity` rows): None while
        they hold them, else the grown columns, to put in their place."""
        window = capacity // AHEAD
        if n <= capacity - window:
            return None
        current = columns()
        if n > 2 * capacity:  # a bulk load: no gradual growth to spread the copy over
            self._next, self._made = {}, 0
            size = max(n, 2 * capacity)
            return {name: grown(c, size, self._fill(name)) for name, c in current.items()}
        if len(next(iter(self._next.values()), ())) != 2 * capacity:  # none, or stale
            self._next = {
                name: _unwritten(c, 2 * capacity, self._fill(name)) for name, c in current.items()
            }
            self._made = 0
        self._make(2 * capacity * min(1.0, (n - capacity + window) / max(window, 1)))
        if n <= capacity:
            return None
        doubled, self._next, self._made = self._next, {}, 0
        for name, column in current.items():
            doubled[name][:capacity] = column
        return doubled

    def reserve_attributes(self, owner: object, n: int, capacity: int) -> None:
        """`reserve` for columns kept as attributes of `owner`, named as the fills."""
        doubled = self.reserve(n, capacity, lambda: {k: getattr(owner, k) for k in self.fills})
        for name, column in (doubled or {}).items():
            setattr(owner, str(name), column)

    def _fill(self, name: Hashable) -> float:
        return self.fills.get(name, 0)

    def _make(self, rows: float) -> None:
        """Write the doubled columns up to row `rows`: a zero-filled one (calloc's, whose
        untouched pages hold zeros) only as far as the copy will reach."""
        rows = int(rows)
        for name, column in self._next.items():
            fill = self._fill(name)
            end = rows if fill != 0 else min(rows, len(column) // 2)
            column[min(self._made, end) : end] = fill
        self._made = max(self._made, rows)


def _unwritten(like: np.ndarray, size: int, fill: float) -> np.ndarray:
    """A column like `like` of `size` rows, its pages not yet touched (zeros if `fill` is)."""
    shape, dtype = (size, *like.shape[1:]), like.dtype
    return np.zeros(shape, dtype=dtype) if fill == 0 else np.empty(shape, dtype=dtype)


class GrowingRows:
    """Rows of shape `row` (() for scalars), appended in order; `array` is a view of them."""

    def __init__(self, row: tuple[int, ...] = (), dtype: DTypeLike = float) -> None:
        self._data = np.zeros((16, *row), dtype=dtype)
        self._n = 0
        self._doubling = Doubling()

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
        doubled = self._doubling.reserve(n, len(self._data), lambda: {"data": self._data})
        if doubled:
            self._data = doubled["data"]

    @property
    def array(self) -> np.ndarray:
        """(n, *row) the rows so far (a view: copy it to keep it)."""
        return self._data[: self._n]
