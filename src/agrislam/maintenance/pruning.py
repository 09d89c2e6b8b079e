"""Pruning (sec. 2.6.3): objects seen only a few times whose interest heuristic (eq. 2)
stays high after a grace period go; and the work a fold's step leaves to the next."""

from __future__ import annotations

import numpy as np

from agrislam.config import MaintenanceConfig
from agrislam.mapping.objects import ObjectTable


class AfterFold:
    """Objects whose row and merge work a fold's step leaves to the next step: a row
    constraint or a merge on an object the fold retired re-enters it, computing its
    deferred covariance, which a step that already folds should not do too."""

    def __init__(self) -> None:
        self.waiting = np.empty(0, dtype=np.int64)

    def ready(self, touched: np.ndarray, folded: bool) -> np.ndarray:
        """The objects to work on now: those waiting and `touched`, unless `folded`."""
        ids = np.union1d(self.waiting, touched).astype(np.int64)
        self.waiting, ready = (ids, ids[:0]) if folded else (ids[:0], ids)
        return ready


def prune_due(
    objects: ObjectTable, t: float, config: MaintenanceConfig, grace: float | None = None
) -> list[int]:
    """Objects to prune now, among those the pruner watches (`objects.young`): seen at most
    `prune_max_meas` times, unseen for the grace period, and with an interest heuristic
    still at or above `prune_min_interest`. Objects that grew out of youth, and those
    judged now, are no longer watched. `grace` overrides the configured grace period (0
    at the end of a survey)."""
    grace = config.prune_grace_s if grace is None else grace
    young = objects.young
    ids = np.flatnonzero(young)
    if len(ids) == 0:
        return []
    n_meas = objects.n_meas[ids]
    grown = ids[n_meas > config.prune_max_meas]
    expired = ids[(n_meas <= config.prune_max_meas) & (objects.last_update[ids] <= t - grace)]
    young[grown] = False
    if len(expired) == 0:
        return []
    young[expired] = False
    h = objects.beliefs.interest(expired, t)
    return expired[h >= config.prune_min_interest].tolist()
