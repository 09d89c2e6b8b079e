"""The spatial index follows the map (DESIGN step "index"): the objects a step touched
move at once, the others are read again a slice a step (or all, after a refine that moved
the whole map), and the index is rebuilt now and then."""

from __future__ import annotations

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex

FRESH_MAX = 500  # objects moved since the last rebuild that force the next
REBUILD_STEPS = 50  # steps between index rebuilds


class IndexUpkeep:
    """When the index last saw a refine of the map, and steps since its last rebuild."""

    def __init__(self) -> None:
        self._steps_since_rebuild = self._refines = 0

    def follow(
        self,
        index: SpatialIndex,
        touched: np.ndarray,
        objects: ObjectTable,
        backend: GraphBackend,
    ) -> None:
        """Move the touched objects in the index, read a slice of the others again, and
        rebuild it every REBUILD_STEPS."""
        touched = objects.active(touched)
        if len(touched):
            index.move(touched, backend.object_positions(touched))

        def drifting() -> np.ndarray:  # the objects whose estimates may still move
            settled = backend.settled_objects()  # held on a frozen keyframe
            return np.setdiff1d(objects.active_ids(), settled, assume_unique=True)

        if (refines := backend.refines) != self._refines:  # the map moved
            whole, self._refines = backend.whole_refine > self._refines, refines
            swept = objects.active_ids() if whole else drifting()  # what it moved
        else:
            swept = objects.active(index.due(drifting))
        if len(swept):
            index.settle(swept, backend.object_positions(swept))
        self._steps_since_rebuild += 1
        if self._steps_since_rebuild >= REBUILD_STEPS or index.n_fresh > FRESH_MAX:
            index.rebuild()
            self._steps_since_rebuild = 0
