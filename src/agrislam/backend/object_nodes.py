"""The object nodes of the survey graph (graph.SurveyGraph.objects): object id -> the
map-frame position it was added at, as arrays instead of a dict holding a numpy array
per plant (docs/decisions.md, "State as arrays").

Object ids are the object table's row numbers: small non-negative integers, so a slot
array indexed by id answers membership; the ids are kept in the order they were added
(as a dict would iterate them), a removed one marked and skipped."""

from __future__ import annotations

from collections.abc import Iterator, KeysView

import numpy as np
from numpy.typing import ArrayLike

from agrislam.growing import Doubling, GrowingRows

REMOVED = -1


class ObjectNodes:
    """A mapping object id -> initial (2,) position, in the order the ids were added."""

    def __init__(self) -> None:
        self._slot = np.full(16, REMOVED, dtype=np.int64)  # id -> its row, REMOVED: none
        self._doubling = Doubling({"_slot": REMOVED})
        self._ids = GrowingRows(dtype=np.int64)  # row -> id (REMOVED once removed)
        self._xy = GrowingRows((2,))
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def __contains__(self, object_id: object) -> bool:
        if not isinstance(object_id, (int, np.integer)):
            return False
        return 0 <= object_id < len(self._slot) and self._slot[object_id] != REMOVED

    def missing(self, object_ids: ArrayLike) -> np.ndarray:
        """Those of `object_ids` that are not nodes, in their order (at once, for many)."""
        ids = np.asarray(object_ids, dtype=np.int64).reshape(-1)
        inside = (ids >= 0) & (ids < len(self._slot))
        present = np.zeros(len(ids), dtype=bool)
        present[inside] = self._slot[ids[inside]] != REMOVED
        return ids[~present]

    def ids(self) -> np.ndarray:
        """The ids, in the order they were added (a new array)."""
        ids = self._ids.array
        return ids[ids != REMOVED]

    def __iter__(self) -> Iterator[int]:
        return iter(self.ids().tolist())

    def keys(self) -> KeysView[int]:
        return dict.fromkeys(self).keys()

    def __getitem__(self, object_id: int) -> np.ndarray:
        if object_id not in self:
            raise KeyError(object_id)
        return self._xy.array[self._slot[object_id]].copy()

    def __setitem__(self, object_id: int, xy: ArrayLike) -> None:
        if object_id < 0:
            raise ValueError(f"object id must be non-negative, got {object_id}")
        if object_id in self:  # as a dict: the id keeps its place
            self._xy.array[self._slot[object_id]] = np.asarray(xy, dtype=float).reshape(2)
            return
        self._doubling.reserve_attributes(self, object_id + 1, len(self._slot))
        self._slot[object_id] = len(self._ids)
        self._ids.append(object_id)
        self._xy.append(np.asarray(xy, dtype=float).reshape(2))
        self._n += 1

    def __delitem__(self, object_id: int) -> None:
        if object_id not in self:
            raise KeyError(object_id)
        self._ids.array[self._slot[object_id]] = REMOVED
        self._slot[object_id] = REMOVED
        self._n -= 1
        if self._n < len(self._ids) // 2:
            self._compact()

    def _compact(self) -> None:
        """Drop the removed rows once they are the majority (merges, pruning)."""
        ids, xy = self._ids.array, self._xy.array
        kept = ids != REMOVED
        self._ids, self._xy = GrowingRows(dtype=np.int64), GrowingRows((2,))
        self._ids.extend(ids[kept])
        self._xy.extend(xy[kept])
        self._slot[ids[kept]] = np.arange(int(kept.sum()))
