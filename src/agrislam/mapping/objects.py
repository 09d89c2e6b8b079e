"""The object table: every object the map has ever had, one row each, as a struct of arrays
grown by doubling (DESIGN.md "State layout"); all that is known of an object apart from
its position (the back end's): its beliefs, status, sightings, and confirmation."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agrislam.growing import Doubling
from agrislam.semantics.beliefs import BeliefTable
from agrislam.snapshot import STATUS_ACTIVE

NO_ROBOT = -1
NO_OBJECTS = np.empty(0, dtype=np.int64)  # an empty set of ids, shared: never written
NO_OBJECTS.setflags(write=False)


@dataclass(frozen=True, slots=True)
class Sightings:
    """Where one robot last saw objects, as far as it was the last to see them."""

    known: np.ndarray  # (k,) the robot was the last to see each object
    drift: np.ndarray  # (k, 3, 3, 3) its chain's drift parts then (zeros where not known)
    xy: np.ndarray  # (k, 2) the detection, in the robot's dead-reckoning frame
    cov: np.ndarray  # (k, 2, 2) its configured covariance in that frame


# each column's row shape, dtype and value in rows not used yet
_COLUMNS: dict[str, tuple[tuple[int, ...], type, float]] = {
    "_status": ((), np.int8, STATUS_ACTIVE),
    "_merged_into": ((), np.int64, -1),
    "_n_frames": ((), np.int64, 0),
    "_seen_by": ((), np.int64, NO_ROBOT),
    "_seen_drift": ((3, 3, 3), np.float64, 0),
    "_seen_xy": ((2,), np.float64, 0),
    "_seen_cov": ((2, 2), np.float64, 0),
    "_young": ((), bool, False),
    "_tentative": ((), bool, False),
    "_views": ((), np.int64, 0),
}


class ObjectTable:
    """Rows of objects: lifecycle, sightings and beliefs; ids are row numbers, never reused."""

    def __init__(self, beliefs: BeliefTable, capacity: int = 1024) -> None:
        self.beliefs = beliefs
        self._n = len(beliefs)
        capacity = max(capacity, self._n, 1)
        for name, (shape, dtype, fill) in _COLUMNS.items():
            setattr(self, name, np.full((capacity, *shape), fill, dtype=dtype))
        self._doubling = Doubling({name: fill for name, (_, _, fill) in _COLUMNS.items()})
        self._on_retire: list[Callable[[np.ndarray], None]] = []

    def __len__(self) -> int:
        return self._n

    # ------------------------------------------------------------------ columns
    @property
    def status(self) -> np.ndarray:
        """STATUS_ACTIVE, STATUS_MERGED or STATUS_PRUNED per object (n,)."""
        return self._status[: self._n]

    @property
    def n_frames(self) -> np.ndarray:
        """Frames each object was seen in (n,): what rows wait for before a plant joins."""
        return self._n_frames[: self._n]

    @property
    def n_meas(self) -> np.ndarray:
        """Measurements per object (n,), the count of eq. (2)."""
        return self.beliefs.n_meas

    @property
    def last_update(self) -> np.ndarray:
        """Time of each object's last measurement (n,)."""
        return self.beliefs.last_update

    @property
    def seen_by(self) -> np.ndarray:
        """The robot (its index) that saw each object last, NO_ROBOT if none (n,)."""
        return self._seen_by[: self._n]

    @property
    def seen_cov(self) -> np.ndarray:
        """The covariance of each object's last detection (configured, zeros if never
        seen) (n, 2, 2)."""
        return self._seen_cov[: self._n]

    @property
    def young(self) -> np.ndarray:
        """Objects the pruner still watches (n,), read-write for the pruner."""
        return self._young[: self._n]

    @property
    def tentative(self) -> np.ndarray:
        """Objects not yet confirmed by their sightings (n,), read-write for
        maintenance.Existence; a saved map's plants never are."""
        return self._tentative[: self._n]

    @property
    def views(self) -> np.ndarray:
        """Frames of this survey each object was in the camera's view in (n,), counted
        while it is active (maintenance.Existence)."""
        return self._views[: self._n]

    # ---------------------------------------------------------------- lifecycle
    def add(self, count: int, t: float, tentative: bool = False) -> np.ndarray:
        """`count` new active objects at time t, watched by the pruner, tentative if asked;
        their ids."""
        ids = self.beliefs.add(count, t)
        self._reserve(len(self.beliefs))
        self._status[ids] = STATUS_ACTIVE
        self._merged_into[ids] = -1
        self._n_frames[ids] = 0
        self._seen_by[ids] = NO_ROBOT
        self._young[ids] = True
        self._tentative[ids] = tentative
        self._views[ids] = 0
        self._n = len(self.beliefs)
        return ids

    def seen(
        self, ids: np.ndarray, robot: int, drift: np.ndarray, xy: np.ndarray, cov: np.ndarray
    ) -> None:
        """The objects (unique ids) were seen in one frame of robot `robot` (its index),
        at `xy` (k, 2) with covariances `cov` (k, 2, 2) in its dead-reckoning frame, whose
        chain had accumulated the drift parts `drift` (3, 3, 3) then."""
        self._n_frames[ids] += 1
        self._seen_by[ids] = robot
        self._seen_drift[ids] = drift
        self._seen_xy[ids] = xy
        self._seen_cov[ids] = cov

    def absorb(self, keep: int, drop: int) -> None:
        """`keep` now stands for `drop` too: it was last seen when `drop` was, if later
        by the same robot's chain (or seen by no robot of its own). It is tentative while
        both were, in view as often as the more often viewed, detected in the frames of both."""
        self._tentative[keep] &= self._tentative[drop]
        self._n_frames[keep] += self._n_frames[drop]
        self._views[keep] = max(self._views[keep], self._views[drop])
        robot = self._seen_by[drop]
        if robot == NO_ROBOT:
            return
        later = (
            self._seen_drift[drop].trace(axis1=1, axis2=2).sum()
            > self._seen_drift[keep].trace(axis1=1, axis2=2).sum()
        )
        if self._seen_by[keep] != robot or later:
            for column in (self._seen_by, self._seen_drift, self._seen_xy, self._seen_cov):
                column[keep] = column[drop]

    def retire(self, ids: np.ndarray, status: int, into: int = -1) -> None:
        """Objects leave the map: merged into `into`, or pruned. Subscribers hear of it."""
        ids = np.atleast_1d(np.asarray(ids, dtype=np.int64))
        self._status[ids] = status
        self._merged_into[ids] = into
        self._seen_by[ids] = NO_ROBOT
        self._young[ids] = False
        self._tentative[ids] = False
        for listener in self._on_retire:
            listener(ids)

    def on_retire(self, listener: Callable[[np.ndarray], None]) -> None:
        """Call `listener(ids)` whenever objects are retired."""
        self._on_retire.append(listener)

    # ------------------------------------------------------------------ queries
    def active_ids(self) -> np.ndarray:
        return np.flatnonzero(self.status == STATUS_ACTIVE)

    def active(self, ids: np.ndarray) -> np.ndarray:
        """The given ids that are still active."""
        return ids[self._status[ids] == STATUS_ACTIVE]

    def resolve(self, ids: np.ndarray) -> np.ndarray:
        """The object each id stands for now, following merges."""
        ids = np.array(ids, dtype=np.int64, copy=True)
        while True:
            target = self._merged_into[ids]
            moved = target >= 0
            if not moved.any():
                return ids
            ids[moved] = target[moved]

    def last_seen(self, ids: np.ndarray, robot: int) -> Sightings:
        """Where and with what drift `robot` (index) last saw each object, if it was the
        last to see it."""
        known = self._seen_by[ids] == robot
        drift = np.where(known[:, None, None, None], self._seen_drift[ids], 0.0)
        return Sightings(known, drift, self._seen_xy[ids], self._seen_cov[ids])

    # ------------------------------------------------------------------ storage
    def _reserve(self, n: int) -> None:
        """Room for n rows; capacity doubles, so growing is amortised O(1) per object."""
        self._doubling.reserve_attributes(self, n, len(self._status))
