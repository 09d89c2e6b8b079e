"""A non-negative integer per node of the survey graph, held in arrays: a whole field has
too many nodes for a dict entry each (docs/decisions.md, "State as arrays").

A key (GTSAM's symbol, backend/graph.py's layout) numbers its node densely in its low
NODE_BITS bits within its kind and robot, the bits above: one array per kind and robot,
indexed by that number, MISSING where the table holds nothing. A plain id (below 2^40)
is a key of its own: the graph's table of each object's row is keyed by object id."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from agrislam.growing import grown

NODE_BITS = 40  # a node's number within its kind and robot (graph.POSES_PER_ROBOT)
MISSING = -1
FEW = 16  # keys `get_many` looks up one by one (numpy's overhead costs more)
_NUMBER = (1 << NODE_BITS) - 1


class KeyTable:
    """key -> int >= 0, read and written as a dict's `get`, `pop`, `in` and `[]`; `get_many`
    reads many keys at once."""

    def __init__(self) -> None:
        self._columns: dict[int, np.ndarray] = {}  # a key's bits above NODE_BITS -> values
        self._len = 0

    def __len__(self) -> int:
        return self._len

    def __contains__(self, key: object) -> bool:
        return isinstance(key, (int, np.integer)) and self.get(int(key)) is not None

    def __getitem__(self, key: int) -> int:
        value = self.get(key)
        if value is None:
            raise KeyError(key)
        return value

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, KeyTable):
            return NotImplemented
        return dict(self.items()) == dict(other.items())

    def items(self) -> Iterator[tuple[int, int]]:
        """(key, value) of every key held."""
        for high, column in self._columns.items():
            for number in np.flatnonzero(column != MISSING).tolist():
                yield (high << NODE_BITS) | number, int(column[number])

    def get(self, key: int, default: int | None = None) -> int | None:
        key = int(key)
        column = self._columns.get(key >> NODE_BITS)
        number = key & _NUMBER
        if column is None or number >= len(column) or column[number] == MISSING:
            return default
        return int(column[number])

    def __setitem__(self, key: int, value: int) -> None:
        if value < 0:
            raise ValueError(f"a key table holds integers >= 0, not {value}")
        key = int(key)
        high, number = key >> NODE_BITS, key & _NUMBER
        column = self._columns.get(high)
        if column is None or number >= len(column):
            old = column if column is not None else np.empty(0, dtype=np.int64)
            column = self._columns[high] = grown(old, max(number + 1, 2 * len(old), 16), MISSING)
        self._len += int(column[number] == MISSING)
        column[number] = value

    def pop(self, key: int, default: int | None = None) -> int | None:
        value = self.get(key)
        if value is None:
            return default
        key = int(key)
        self._columns[key >> NODE_BITS][key & _NUMBER] = MISSING
        self._len -= 1
        return value

    def put_many(self, keys: np.ndarray, value: int) -> None:
        """`value` for each of the distinct `keys` at once."""
        keys = np.asarray(keys).astype(np.uint64, copy=False)
        high = keys >> np.uint64(NODE_BITS)
        number = (keys & np.uint64(_NUMBER)).astype(np.int64)
        for h in np.unique(high).tolist():
            at = number[high == h]
            self[(h << NODE_BITS) | int(at.max())] = value  # the column grown to hold them
            column = self._columns[h]
            self._len += int((column[at] == MISSING).sum())
            column[at] = value

    def get_many(self, keys: Iterable[int] | np.ndarray) -> np.ndarray:
        """(k,) the value of each key, MISSING where there is none."""
        if not isinstance(keys, np.ndarray):
            keys = list(keys)
            if len(keys) <= FEW:
                return np.array([self.get(k, MISSING) for k in keys], dtype=np.int64)
        keys = np.asarray(keys).astype(np.uint64, copy=False)
        out = np.full(len(keys), MISSING, dtype=np.int64)
        if not len(keys):
            return out
        high = keys >> np.uint64(NODE_BITS)
        number = (keys & np.uint64(_NUMBER)).astype(np.int64)
        kinds = high[:1] if (high == high[0]).all() else np.unique(high)  # mostly one kind
        for h in kinds.tolist():
            column = self._columns.get(h)
            if column is None:
                continue
            at = np.flatnonzero(high == h)
            inside = number[at] < len(column)
            out[at[inside]] = column[number[at[inside]]]
        return out
