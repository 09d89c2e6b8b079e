"""The stages a world model is assembled from, built for one survey from its effective
settings (config/effective.py): the shared object map and graph back end, then the front
end, the associator, the estimators and the maintainer. Nothing is configured after it is
built."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from agrislam.association.associator import Associator
from agrislam.association.loop_closure import RECENT_S, LoopCloser
from agrislam.association.range_outliers import RangeOutliers
from agrislam.association.rejoin import Rejoiner
from agrislam.association.returning import Returns
from agrislam.backend import GraphBackend, make_backend
from agrislam.config import FieldSchema, Settings
from agrislam.estimation.estimators import Estimators
from agrislam.frontend.doubt import MotionDoubt
from agrislam.frontend.frontend import FrontEnd
from agrislam.maintenance.maintainer import Maintainer
from agrislam.maintenance.merger import Merger
from agrislam.mapping.births import Births
from agrislam.mapping.map_state import MapState
from agrislam.mapping.objects import ObjectTable
from agrislam.records import RobotStart
from agrislam.season.prior_backend import PriorBackend
from agrislam.season.prior_map import PriorMap
from agrislam.semantics.beliefs import BeliefTable
from agrislam.snapshot import STATUS_PRUNED


@dataclass(frozen=True)
class Stages:
    """One survey's stages, in the order a frame meets them."""

    map: MapState
    backend: GraphBackend
    estimators: Estimators
    frontend: FrontEnd
    associator: Associator
    maintainer: Maintainer


def build_stages(
    settings: Settings,
    schema: FieldSchema | None,
    prior: tuple[PriorMap, float] | None,
    starts: dict[str, RobotStart],
    issues: Counter[str],
) -> Stages:
    """The stages of a survey with `settings`, mapping `schema`'s attributes; continuing
    `prior` (a saved map and the time its beliefs refer to, in this survey's clock) if
    given; robots starting at `starts`; counting what happened in `issues`."""
    backend = make_backend(settings.slam, settings.rows)
    backend.issues.update(issues)  # the back end counts into the run's issues from here
    issues = backend.issues
    if prior is None:
        map_state = MapState(ObjectTable(BeliefTable(schema, settings.semantics)), Births(RECENT_S))
        first_own = 0
    else:
        map_state, backend = _continued(prior, settings, backend)
        first_own = int(prior[0].ids.max(initial=-1)) + 1  # the saved plants come first
    estimators = Estimators(settings, map_state, backend)
    association, landmarks = settings.association, settings.landmarks
    doubt = MotionDoubt(map_state, issues)
    frontend = FrontEnd(
        settings.sensor, schema, association.innovation_gate, backend, estimators, doubt, issues
    )
    frontend.use_starts(starts)
    # without a field prior's plant spacing or rows, the association's safeguards are on
    gate = association.gate_chi2 if landmarks else None
    rejoiner = Rejoiner(map_state.index, map_state.births, issues, gate)
    outliers = RangeOutliers(enabled=landmarks)
    loops = LoopCloser(map_state.births, issues, gate, estimators.spacing)
    returns = Returns(map_state, estimators.spacing, issues, enabled=gate is not None)
    tentative = settings.maintenance.existence
    associator = Associator(
        association,
        map_state,
        backend,
        frontend,
        estimators,
        (rejoiner, outliers, returns),
        tentative,
        issues,
    )
    maintainer = Maintainer(
        settings.maintenance,
        map_state,
        backend,
        estimators.spacing,
        (Merger(spare_together=landmarks), loops, outliers, returns),
        first_own,
    )
    return Stages(map_state, backend, estimators, frontend, associator, maintainer)


def _continued(
    prior: tuple[PriorMap, float], settings: Settings, backend: GraphBackend
) -> tuple[MapState, GraphBackend]:
    """The saved plants as objects with their ids and beliefs (stamped with the saved
    survey's time: App. B carries them when read), answered by the prior back end until
    seen again."""
    saved, belief_time = prior
    objects = ObjectTable(saved.belief_table(settings.semantics, belief_time))
    map_state = MapState(objects, Births(RECENT_S))
    objects.young[:] = False
    gaps = np.setdiff1d(np.arange(len(objects)), saved.ids)
    if len(gaps):
        objects.retire(gaps, STATUS_PRUNED)
    backend = PriorBackend(backend, saved.ids, saved.xy, saved.cov)
    map_state.index.rebuild(saved.ids, saved.xy)
    map_state.births.record(-np.inf, len(objects))  # started in an earlier survey
    return map_state, backend
