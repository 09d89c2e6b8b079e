"""Marginal covariances read from iSAM2 for association, kept for a few steps: each read
is a Bayes-tree traversal, and a frame reads one for each of its candidates.

A covariance serves `reuse` steps if a detection has joined its object since the read,
`STALE` times as long otherwise: a node without a factor of its own changes only through
its neighbours (a robot's drift, a loop), and an older covariance only overstates the
uncertainty (the gate is the wider for it). A new factor makes a node read again at once,
except on an object already seen `SETTLED` times: one more sighting shrinks its
covariance by about a `SETTLED + 1`-th."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import gtsam
import numpy as np

from agrislam.backend.key_table import KeyTable

SETTLED = 5  # sightings after which one more does not call for a fresh read
STALE = 10  # a covariance with no new factor on its node serves STALE x `reuse` steps


class MarginalCache:
    """key -> the marginal covariance last read, with the step and the sightings then."""

    def __init__(self) -> None:
        # live nodes' only: the step read at, the covariance, the node's sightings then
        self._read: dict[int, tuple[int, np.ndarray, int]] = {}
        self._sightings = KeyTable()  # object key -> detections so far

    def __getstate__(self) -> dict[str, object]:
        """A pickle keeps the sightings; the covariances are read again."""
        return {"_read": {}, "_sightings": self._sightings}

    def get(self, key: int, step: int, reuse: int, read: Callable[[int], np.ndarray]) -> np.ndarray:
        """The covariance of `key` as last read, or from `read` now if it is due."""
        if self._due(key, step, reuse):
            self._read[key] = (step, read(key), self._sightings.get(key, 0))
        return self._read[key][1]

    def read_jointly(self, keys: list[int], step: int, reuse: int, isam: gtsam.ISAM2) -> None:
        """The covariances of `keys` that `get` would read now, read at once from their
        joint marginal: one Bayes-tree walk for them all, not one each."""
        due = list(dict.fromkeys(key for key in keys if self._due(key, step, reuse)))
        if len(due) > 1:
            joint = isam.jointMarginalCovariance(due)
            seen = self._sightings.get
            self._read.update((key, (step, joint.at(key, key), seen(key, 0))) for key in due)

    def _due(self, key: int, step: int, reuse: int) -> bool:
        cached = self._read.get(key)
        if cached is None:
            return True
        read_at, _, seen = cached
        sighted = self._sightings.get(key, 0) > seen  # since the read (a pose: never)
        return step - read_at >= (reuse if sighted else STALE * reuse)

    def held(self) -> set[int]:
        """The keys whose covariance is kept."""
        return set(self._read)

    def kept(self, key: int) -> tuple[int, np.ndarray] | None:
        """The step the kept covariance of `key` was read at, and it (None: none is kept)."""
        cached = self._read.get(key)
        return None if cached is None else cached[:2]

    def sighted(self, obj: int) -> None:
        """A detection factor joins object `obj`."""
        self._sightings[obj] = self._sightings.get(obj, 0) + 1

    def measured(self, keys: Iterable[int]) -> None:
        """New factors on `keys` were solved: read them again, settled objects aside."""
        for key in keys:
            if self._sightings.get(key, 0) <= SETTLED:
                self._read.pop(key, None)

    def drop(self, key: int) -> None:
        """`key` left the live graph: its covariance is read elsewhere from now on."""
        self._read.pop(key, None)

    def forget(self, key: int) -> None:
        """Node `key` is gone."""
        self._read.pop(key, None)
        self._sightings.pop(key, None)

    def clear(self) -> None:
        """The solution changed at once (a refine, a rebuild): every covariance is stale."""
        self._read.clear()
