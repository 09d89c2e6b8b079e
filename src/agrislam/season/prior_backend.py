"""The back end of a survey that continues a saved map: saved plants wait outside the graph,
answered from their saved position and covariance, until the survey sees one; it then
enters the graph with a prior of its saved covariance (a GTSAM PriorFactorPoint2), so a
whole field's map loads at once and the solver holds only the plants met again."""

from __future__ import annotations

from typing import Any

import numpy as np

from agrislam.backend import GraphBackend, Measurement
from agrislam.backend.base import BackendBase


class PriorBackend:
    """Wraps a back end; every call it does not handle goes to the wrapped one (the members
    GraphBackend lists are forwarded on the class, so it is a GraphBackend to a static look)."""

    def __init__(self, inner: BackendBase, ids: np.ndarray, xy: np.ndarray, cov: np.ndarray):
        self.inner = inner
        self._held = {int(i): k for k, i in enumerate(np.asarray(ids).tolist())}
        self._xy, self._cov = np.asarray(xy, dtype=float), np.asarray(cov, dtype=float)
        self.entered: set[int] = set()  # saved plants the survey brought into the graph

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def held(self, object_ids: np.ndarray) -> np.ndarray:
        """(k,) whether each object is a saved plant not yet in the graph."""
        return np.fromiter((int(i) in self._held for i in object_ids), bool, len(object_ids))

    def _enter(self, object_id: int) -> None:
        row = self._held.pop(int(object_id), None)
        if row is None:
            return
        self.inner.add_object(object_id, self._xy[row])
        self.inner.add_object_prior(object_id, self._xy[row], self._cov[row])
        self.entered.add(int(object_id))

    # ------------------------------------------------------------- what changes
    def add_observation(self, robot: str, object_id: int, measurement: Measurement) -> None:
        self._enter(object_id)
        self.inner.add_observation(robot, object_id, measurement)

    def merge_objects(self, keep: int, drop: int) -> None:
        self._enter(keep)
        self._enter(drop)
        self.inner.merge_objects(keep, drop)

    def remove_object(self, object_id: int) -> None:
        if self._held.pop(int(object_id), None) is None:
            self.inner.remove_object(object_id)

    # ------------------------------------------------------------------ queries
    def object_positions(self, object_ids: np.ndarray) -> np.ndarray:
        return self._answer(object_ids, self._xy, self.inner.object_positions, (2,))

    def object_covariances(self, object_ids: np.ndarray) -> np.ndarray:
        return self._answer(object_ids, self._cov, self.inner.object_covariances, (2, 2))

    def _answer(self, object_ids, saved: np.ndarray, ask, shape: tuple[int, ...]) -> np.ndarray:
        object_ids = np.asarray(object_ids, dtype=np.int64)
        held = self.held(object_ids)
        out = np.empty((len(object_ids), *shape))
        if held.any():
            out[held] = saved[[self._held[int(i)] for i in object_ids[held]]]
        if (~held).any():
            out[~held] = ask(object_ids[~held])
        return out


def _forwarded(name: str) -> Any:
    """GraphBackend's member `name` on PriorBackend, passed to the wrapped back end."""
    if callable(getattr(GraphBackend, name, None)):

        def method(self: PriorBackend, *args: Any, **kwargs: Any) -> Any:
            return getattr(self.inner, name)(*args, **kwargs)

        method.__name__ = name
        return method
    return property(
        lambda self: getattr(self.inner, name),
        lambda self, value: setattr(self.inner, name, value),
    )


for _name in [*GraphBackend.__annotations__, *vars(GraphBackend)]:
    if not _name.startswith("_") and _name not in vars(PriorBackend):
        setattr(PriorBackend, _name, _forwarded(_name))
