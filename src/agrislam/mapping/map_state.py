"""The object map the stages share: the table of objects with their beliefs, the spatial
index over their estimates (DESIGN step 4's first cut), and when each was started."""

from __future__ import annotations

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.mapping.births import Births
from agrislam.mapping.index_upkeep import IndexUpkeep
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex
from agrislam.semantics.beliefs import BeliefTable

INDEX_MARGIN = 0.3  # m an estimate may move between spatial index rebuilds
INDEX_SWEEP_STEPS = 100  # steps over which every object's place in the index is read again


class MapState:
    """Objects, their index and their births; a retired object leaves the index."""

    def __init__(self, objects: ObjectTable, births: Births) -> None:
        self.objects, self.births = objects, births
        self.index = SpatialIndex(INDEX_MARGIN, INDEX_SWEEP_STEPS)
        self.upkeep = IndexUpkeep()
        objects.on_retire(self.index.forget)

    @property
    def beliefs(self) -> BeliefTable:
        """The objects' semantic beliefs (the object table's semantic columns)."""
        return self.objects.beliefs

    def add(self, xy: np.ndarray, t: float, tentative: bool, backend: GraphBackend) -> np.ndarray:
        """New objects at map positions `xy` (k, 2), in the table, the graph and the index;
        their ids."""
        new_ids = self.objects.add(len(xy), t, tentative=tentative)
        for obj, at in zip(new_ids.tolist(), xy, strict=True):
            backend.add_object(obj, at)
        self.births.record(t, len(self.objects))
        self.index.move(new_ids, xy)
        return new_ids

    def follow(self, touched: np.ndarray, backend: GraphBackend) -> None:
        """The index follows the estimates the back end moved (mapping/index_upkeep.py)."""
        self.upkeep.follow(self.index, touched, self.objects, backend)
