"""The live graph of the incremental back end (part of `IncrementalBackend`, backend.py):
iSAM2 and what feeds it. One update with what is pending, a node it finds indeterminate
held by a weak prior, a rebuild that lets go of dead slots, Gauss-Newton iterations before
a fold, and the marginal covariances association reads."""

from __future__ import annotations

from collections import Counter

import gtsam
import numpy as np

from agrislam.backend.graph import POSE, ROW, SurveyGraph, key_kind
from agrislam.backend.incremental.conditioning import indeterminate_key, weakly_held
from agrislam.backend.incremental.isam_state import (
    Entry,
    PendingUpdate,
    SlotTable,
    isam2,
    rebuilt_isam2,
)
from agrislam.backend.incremental.marginal_cache import MarginalCache
from agrislam.backend.incremental.nodes import LIVE, NodeTable
from agrislam.config import SlamConfig

FOLD_ITERATIONS = 2  # Gauss-Newton iterations on the window before it is folded away
SLOTS_SLACK, SLOTS_FLOOR = 8, 8000  # iSAM2 rebuilt when its slots pass slack x live + floor
# a marginal covariance read for association serves this many steps of each robot if its
# object was seen since, marginal_cache.STALE times as many if not
COVARIANCE_REUSE_STEPS = 10


class LiveGraph:
    """iSAM2, the pending update, the slot table and the marginal cache, kept in step."""

    slam: SlamConfig
    graph: SurveyGraph
    issues: Counter[str]
    _nodes: NodeTable
    _isam: gtsam.ISAM2
    _pending: PendingUpdate
    _slots: SlotTable
    _marginals: MarginalCache
    _step: int

    def _solve_pending(self, extra: gtsam.NonlinearFactorGraph | None = None) -> None:
        """One iSAM2 update with what is pending (and `extra`'s factors)."""
        try:
            filled = self._pending.flush(self._isam, extra)
        except RuntimeError as err:
            filled = self._isolate(err, extra)
        if filled is not None:
            self._slots.fill(filled)
            for _, entry in filled:  # what the update measured is read again
                self._marginals.measured(entry.keys)

    def _isolate(
        self, err: RuntimeError, extra: gtsam.NonlinearFactorGraph | None, fold: bool = True
    ) -> list[tuple[int, Entry]] | None:
        """Indeterminate near a node (a row without members): iSAM2 rebuilt, the node weakly
        held, the update again; failing again, a fold's marginal gives way to weak priors."""
        key = indeterminate_key(err)
        if key is None or self._nodes.state(key) != LIVE:  # (entered nodes are live already)
            raise err
        keys = {key} | self._pending.factor_keys() | set(extra.keyVector() if extra else [])
        known = {k: self.estimate(k) for k in keys}  # read before the rebuild drops any
        self._rebuild()
        self._pending.reenter(self._isam, known)
        held = weakly_held({key: known[key]})
        held.push_back(extra if extra is not None else gtsam.NonlinearFactorGraph())
        kind = {POSE: "pose", ROW: "row"}.get(key_kind(key), "object")
        self.issues[f"{kind} held by a weak prior: indeterminate in an iSAM2 update"] += 1
        try:
            return self._pending.flush(self._isam, held)
        except RuntimeError as again:
            if extra is None or not fold:
                raise
            self.issues["a fold's marginal given up: indeterminate in an iSAM2 update"] += 1
            instead = weakly_held({k: known[k] for k in extra.keyVector()})
            return self._isolate(again, instead, fold=False)

    def _slots_piled_up(self) -> bool:
        """iSAM2 keeps a slot for every factor it ever held: past slack x live + floor, a
        rebuild lets them go."""
        return self._isam.getFactorsUnsafe().size() > SLOTS_SLACK * len(self._slots) + SLOTS_FLOOR

    def _rebuild(self) -> None:
        """A fresh iSAM2 of the live factors at the same linearisation point."""
        self._isam = rebuilt_isam2(self._isam, self._slots, self._pending, isam2(self.slam))
        self._marginals.clear()

    def _converge(self) -> None:
        """Gauss-Newton iterations relinearising everything that moved more than the
        threshold: what is folded away keeps the linearisation it has then."""
        params = gtsam.ISAM2UpdateParams()
        params.force_relinearize = True
        for _ in range(FOLD_ITERATIONS):
            self._isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), params)

    def _marginal_covariance(self, key: int) -> np.ndarray:
        """A node's marginal covariance, read again from iSAM2 (a Bayes-tree traversal)
        once each robot has taken COVARIANCE_REUSE_STEPS steps since it was read (longer
        for a node not seen since, marginal_cache.py) or a new factor touched it."""
        if (frozen := self._nodes.frozen.covariance(key)) is not None:
            return frozen
        return self._marginals.get(key, self._step, self._reuse, self._isam.marginalCovariance)

    @property
    def _reuse(self) -> int:
        """Steps a read serves: robots share the step count, so each robot's steps count."""
        return COVARIANCE_REUSE_STEPS * max(len(self.graph.robots), 1)
