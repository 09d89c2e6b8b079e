"""Every factor of a survey's graph as rows of arrays: a whole field records millions of
detections, too many for a Python object each (docs/decisions.md, "State as
arrays").

A row holds a factor's kind, its keys (one or two), its value and its covariance (a
matrix, or a scalar sigma for the row kinds); ids are row numbers, never reused, and a
removed row is marked dead. Value and covariance (the *payload*, most of a row) never
change and are read again only by a refine, a merge's rewiring, a checkpoint or an
export: they are kept `chunk_rows` rows at a time, the newest chunk in memory and every
full one in an anonymous temporary file (`PayloadChunks`).

The factors touching a node are a linked list through the rows (`_head[key]`, a
`KeyTable`, then `_next[row, slot]`), unlinked lazily: a walk skips and splices out the
dead rows it meets.
`FactorStore` is a mapping id -> `Factor` (built on access), so the graph's readers see
the records they always did."""

from __future__ import annotations

import os
import tempfile
from collections import Counter
from collections.abc import Iterator, MutableMapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agrislam.backend.key_table import KeyTable
from agrislam.growing import Doubling, grown

NONE = -1
DEAD = -1
# a GNSS factor holds six numbers (the fix in the map frame and the lever arm)
MAX_KEYS, MAX_VALUE, MAX_COV = 2, 6, 3
PAYLOAD = MAX_VALUE + MAX_COV * MAX_COV  # a row's value, then its covariance
CHUNK_ROWS = 1 << 15  # payload rows a chunk holds
# the columns are made for this many rows at once: zeros, whose pages the system gives
# only when a row is first written, so a small survey costs what it uses and a whole
# field's store does not double (a doubling holds the old and the new columns together)
RESERVED_ROWS = 1 << 24
COLUMNS = ("_kind", "_arity", "_keys", "_value_len", "_cov_dim", "_next")


@dataclass(slots=True)
class Factor:
    kind: str
    keys: tuple[int, ...]
    value: np.ndarray
    cov: np.ndarray | float


class PayloadChunks:
    """Rows of PAYLOAD floats, append-only, `chunk_rows` at a time: the newest chunk in
    memory, every full one written to an anonymous temporary file (gone with the process).
    A chunk the file cannot take (a full disk) stays in memory, with an issue."""

    def __init__(self, chunk_rows: int, issues: Counter[str]) -> None:
        self.chunk_rows = chunk_rows
        self.issues = issues
        self._open = np.zeros((chunk_rows, PAYLOAD))
        self._sealed = 0  # chunks before the open one
        self._held: dict[int, np.ndarray] = {}  # sealed chunks the file could not take
        self._file: Any = None

    def write(self, row: int, payload: np.ndarray) -> None:
        """Row `row` (the next one: rows come in order)."""
        chunk, at = divmod(row, self.chunk_rows)
        if chunk > self._sealed:
            self._seal()
        self._open[at] = payload

    def load(self, rows: np.ndarray) -> None:
        """Rows 0 .. len(rows) at once, into a store that holds none (`all` read back)."""
        for start in range(0, len(rows), self.chunk_rows):
            if start:
                self._seal()
            part = rows[start : start + self.chunk_rows]
            self._open[: len(part)] = part

    def read(self, row: int) -> np.ndarray:
        chunk, at = divmod(row, self.chunk_rows)
        if chunk == self._sealed:
            return self._open[at].copy()
        if chunk in self._held:
            return self._held[chunk][at].copy()
        return self._from_file(row, 1)[0].copy()

    def all(self, n: int) -> np.ndarray:
        """(n, PAYLOAD) the first n rows at once (a checkpoint's state)."""
        rows = np.empty((n, PAYLOAD))
        for chunk in range(self._sealed):
            part = slice(chunk * self.chunk_rows, (chunk + 1) * self.chunk_rows)
            held = self._held.get(chunk)
            rows[part] = held if held is not None else self._from_file(part.start, self.chunk_rows)
        start = self._sealed * self.chunk_rows
        rows[start:] = self._open[: n - start]
        return rows

    def _from_file(self, row: int, count: int) -> np.ndarray:
        """(count, PAYLOAD) rows from `row` on, read from the file (read-only)."""
        row_bytes = PAYLOAD * 8
        data = os.pread(self._file.fileno(), count * row_bytes, row * row_bytes)
        return np.frombuffer(data, dtype=np.float64).reshape(count, PAYLOAD)

    def _seal(self) -> None:
        """The open chunk to the file (or, failing that, kept as it is); a new one opens."""
        try:
            if self._file is None:
                # held open for the store's life, closed (and gone) with it
                self._file = tempfile.TemporaryFile(prefix="agrislam-factors-")  # noqa: SIM115
            self._file.seek(self._sealed * self._open.nbytes)
            self._file.write(self._open.tobytes())
            self._file.flush()
        except OSError as err:
            reason = err.strerror or type(err).__name__
            self.issues[f"factor record kept in memory: the temporary file failed ({reason})"] += 1
            self._held[self._sealed] = self._open
        self._sealed += 1
        self._open = np.zeros_like(self._open)

    def __getstate__(self) -> dict[str, Any]:
        raise TypeError("PayloadChunks is pickled by its FactorStore")


class FactorStore(MutableMapping[int, Factor]):
    """Factor id -> Factor, stored as columns grown by doubling (amortised O(1) per add);
    the payloads in `PayloadChunks`."""

    def __init__(
        self,
        capacity: int = RESERVED_ROWS,
        issues: Counter[str] | None = None,
        chunk_rows: int = CHUNK_ROWS,
    ) -> None:
        self.issues: Counter[str] = Counter() if issues is None else issues
        self._payload = PayloadChunks(chunk_rows, self.issues)
        self._kinds: list[str] = []  # kind code -> name
        self._code: dict[str, int] = {}
        self._n = 0  # rows used (ids handed out)
        self._alive = 0
        # rows past the used ones are written by `append` before any read: they are zeros,
        # whose pages stay untouched until then (a fill would write them all)
        self._kind = np.zeros(capacity, dtype=np.int8)
        self._arity = np.zeros(capacity, dtype=np.int8)
        self._keys = np.zeros((capacity, MAX_KEYS), dtype=np.uint64)
        self._value_len = np.zeros(capacity, dtype=np.int8)
        self._cov_dim = np.zeros(capacity, dtype=np.int8)  # 0: a scalar, the payload's first
        self._next = np.zeros((capacity, MAX_KEYS), dtype=np.int32)
        self._doubling = Doubling(dict.fromkeys(COLUMNS, 0))
        self._head = KeyTable()  # node key -> its latest factor's row

    def __getstate__(self) -> dict[str, Any]:
        """The rows in use (a pickle of the reserved columns would write them all)."""
        state = self.__dict__.copy()
        state.update({name: getattr(self, name)[: self._n] for name in COLUMNS})
        state["_payload"] = (self._payload.chunk_rows, self._payload.all(self._n))
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        chunk_rows, rows = state.pop("_payload")
        self.__dict__.update(state)
        for name in COLUMNS:
            column = state[name]
            setattr(self, name, grown(column, max(RESERVED_ROWS, len(column)), 0))
        self._payload = PayloadChunks(chunk_rows, self.issues)
        self._payload.load(rows)

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
        payload = self._payload.read(r)
        value, flat = payload[:n_value], payload[MAX_VALUE:]
        cov = flat[: d * d].reshape(d, d) if d else float(flat[0])
        return Factor(self._kinds[self._kind[r]], keys, value, cov)

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
        payload = np.zeros(PAYLOAD)
        payload[: len(value)] = value
        flat = np.ravel(cov)
        self._cov_dim[r] = 0 if scalar else np.shape(cov)[0]
        payload[MAX_VALUE : MAX_VALUE + len(flat)] = flat
        self._payload.write(r, payload)
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
            elif previous == NONE and following == NONE:  # the list held dead rows only
                self._head.pop(key, None)
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
        """Bytes of the rows in use (without the per-node list heads and the payload
        chunk being filled)."""
        return sum(getattr(self, name)[: self._n].nbytes for name in COLUMNS)

    # -------------------------------------------------------------- helpers
    def _live(self, row: int) -> bool:
        return bool(self._kind[row] != DEAD)

    def _slot(self, row: int, key: int) -> int:
        """Which of the row's keys is `key` (a factor's keys are distinct)."""
        return 0 if int(self._keys[row, 0]) == key else 1

    def _reserve(self, n: int) -> None:
        self._doubling.reserve_attributes(self, n, len(self._kind))
