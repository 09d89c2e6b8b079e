"""Every factor of a survey's graph as rows of arrays (DESIGN.md "State layout"): a field of
100,000 plants records millions of detections, and one Python object per factor (with its
arrays and a set per node of the factors touching it) cost about 1 KB each (issue 14).

A row holds a factor's kind, its keys (one or two), its value and its covariance (a
matrix, or a scalar sigma for the row kinds); ids are row numbers, never reused, and a
removed row is marked dead. The factors touching a node are a linked list through the
rows (`_head[key]`, then `_next[row, slot]`), unlinked lazily: a walk skips and splices
out the dead rows it meets. `FactorStore` is a mapping id -> `Factor` (built on access),
so the graph's readers see the records they always did."""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from dataclasses import dataclass

import numpy as np

NONE = -1
DEAD = -1
# a GNSS factor holds six numbers (the fix in the map frame and the lever arm, issue 13)
MAX_KEYS, MAX_VALUE, MAX_COV = 2, 6, 3


@dataclass(slots=True)
class Factor:
    kind: str
    keys: tuple[int, ...]
    value: np.ndarray
    cov: np.ndarray | float


class FactorStore(MutableMapping[int, Factor]):
    """Factor id -> Factor, stored as columns grown by doubling (amortised O(1) per add)."""

    def __init__(self, capacity: int = 1024) -> None:
        self._kinds: list[str] = []  # kind code -> name
        self._code: dict[str, int] = {}
        self._n = 0  # rows used (ids handed out)
        self._alive = 0
        self._kind = np.full(capacity, DEAD, dtype=np.int8)
        self._arity = np.zeros(capacity, dtype=np.int8)
        self._keys = np.zeros((capacity, MAX_KEYS), dtype=np.uint64)
        self._value_len = np.zeros(capacity, dtype=np.int8)
        self._value = np.zeros((capacity, MAX_VALUE))
        self._cov_dim = np.zeros(capacity, dtype=np.int8)  # 0: a scalar in _cov[r, 0, 0]
        self._cov = np.zeros((capacity, MAX_COV, MAX_COV))
        self._next = np.full((capacity, MAX_KEYS), NONE, dtype=np.int64)
        self._head: dict[int, int] = {}  # node key -> its latest factor's row

    # --------------------------------------------------------------- mapping
    def __len__(self) -> int:
        return self._alive

    def __contains__(self, fid: object) -> bool:
        return isinstance(fid, (int, np.integer)) and 0 <= fid < self._n and self._live(int(fid))

    def __iter__(self) -> Iterator[int]:
        return iter(np.flatnonzero(self._kind[: self._n] != DEAD).tolist())

    def __getitem__(self, fid: int) -> Factor:
        if fid not in self:
            raise KeyError(fid)
        r = int(fid)
        arity, n_value, d = int(self._arity[r]), int(self._value_len[r]), int(self._cov_dim[r])
        keys = tuple(int(k) for k in self._keys[r, :arity])
        cov = self._cov[r, :d, :d].copy() if d else float(self._cov[r, 0, 0])
        return Factor(self._kinds[self._kind[r]], keys, self._value[r, :n_value].copy(), cov)

    def __setitem__(self, fid: int, factor: Factor) -> None:
        if fid != self._n:
            raise KeyError(f"factor ids are handed out in order: expected {self._n}, got {fid}")
        self.append(factor)

    def __delitem__(self, fid: int) -> None:
        if fid not in self:
            raise KeyError(fid)
        self._kind[int(fid)] = DEAD
        self._alive -= 1

    # ----------------------------------------------------------------- rows
    def append(self, factor: Factor) -> int:
        """Store `factor`; its id."""
        keys = tuple(factor.keys)
        value = np.asarray(factor.value, dtype=float).ravel()
        cov = factor.cov
        scalar = np.ndim(cov) == 0
        if len(keys) > MAX_KEYS or len(value) > MAX_VALUE:
            raise ValueError(f"a {factor.kind} factor with {len(keys)} keys cannot be stored")
        if not scalar and (np.shape(cov)[0] > MAX_COV or np.ndim(cov) != 2):
            raise ValueError(f"a {factor.kind} factor's covariance must be at most 3x3")
        r = self._n
        self._reserve(r + 1)
        if factor.kind not in self._code:
            self._code[factor.kind] = len(self._kinds)
            self._kinds.append(factor.kind)
        self._kind[r] = self._code[factor.kind]
        self._arity[r] = len(keys)
        self._keys[r, : len(keys)] = keys
        self._value_len[r] = len(value)
        self._value[r, : len(value)] = value
        if scalar:
            self._cov_dim[r] = 0
            self._cov[r, 0, 0] = float(cov)
        else:
            d = np.shape(cov)[0]
            self._cov_dim[r] = d
            self._cov[r, :d, :d] = cov
        for slot, key in enumerate(keys):
            self._next[r, slot] = self._head.get(key, NONE)
            self._head[key] = r
        self._n += 1
        self._alive += 1
        return r

    def ids_of(self, key: int) -> list[int]:
        """The live factors touching node `key`, oldest first; dead rows met are unlinked."""
        found: list[int] = []
        previous, row = NONE, self._head.get(key, NONE)
        while row != NONE:
            slot = self._slot(row, key)
            following = int(self._next[row, slot])
            if self._live(row):
                found.append(row)
                previous = row
            elif previous == NONE:  # splice the dead row out of the list
                self._head[key] = following
            else:
                self._next[previous, self._slot(previous, key)] = following
            row = following
        if not found:
            self._head.pop(key, None)
        return found[::-1]

    def keys_of(self, kind: str) -> np.ndarray:
        """(k, MAX_KEYS) the keys of every live factor of `kind`, all at once (a factor's
        slots past its own keys hold 0)."""
        if kind not in self._code:
            return np.zeros((0, MAX_KEYS), dtype=np.uint64)
        return self._keys[np.flatnonzero(self._kind[: self._n] == self._code[kind])]

    def kind(self, fid: int) -> str:
        """The kind of live factor `fid`."""
        if fid not in self:
            raise KeyError(fid)
        return self._kinds[self._kind[int(fid)]]

    def forget(self, key: int) -> None:
        """Node `key` is gone (its factors must already be removed)."""
        self._head.pop(key, None)

    def nbytes(self) -> int:
        """Bytes of the columns (without the per-node list heads)."""
        columns = (self._kind, self._arity, self._keys, self._value_len, self._value)
        return sum(c.nbytes for c in (*columns, self._cov_dim, self._cov, self._next))

    # -------------------------------------------------------------- helpers
    def _live(self, row: int) -> bool:
        return bool(self._kind[row] != DEAD)

    def _slot(self, row: int, key: int) -> int:
        """Which of the row's keys is `key` (a factor's keys are distinct)."""
        return 0 if int(self._keys[row, 0]) == key else 1

    def _reserve(self, n: int) -> None:
        capacity = len(self._kind)
        if n <= capacity:
            return
        size = max(n, 2 * capacity)
        for name, fill in (
            ("_kind", DEAD),
            ("_arity", 0),
            ("_keys", 0),
            ("_value_len", 0),
            ("_value", 0.0),
            ("_cov_dim", 0),
            ("_cov", 0.0),
            ("_next", NONE),
        ):
            old = getattr(self, name)
            new = np.full((size, *old.shape[1:]), fill, dtype=old.dtype)
            new[:capacity] = old
            setattr(self, name, new)
