"""What a survey adds to the season's history: `map.sqlite`'s history tables (the earlier
surveys' rows carried over, this survey's appended), `changes.csv` and the season figure.
Used by every run, so a first survey starts the history."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.config import AgrislamConfig
from agrislam.io.sinks.csv import write_table
from agrislam.io.sinks.history import ChainedRows, History, plant_rows, read_history, write_history
from agrislam.io.sinks.season_figures import growth_attribute, write_season_figure
from agrislam.io.sinks.sqlite import load_map
from agrislam.run.saved_map import check_map_file, reading
from agrislam.run.season import SeasonRun
from agrislam.season.prior_map import PriorMap
from agrislam.snapshot import MapSnapshot
from agrislam.world import WorldModel


def survey_history(season: SeasonRun | None, world: WorldModel, snapshot: MapSnapshot) -> History:
    """The earlier history and this survey's rows: every plant of the map, and the plants
    found gone with their P(gone)."""
    earlier = History()
    if season is not None and season.merged and season.history is not None:
        earlier = season.history
    survey = earlier.next_survey
    o = snapshot.objects
    t = float(world.objects.last_update[o.ids].max(initial=0.0)) if len(o.ids) else 0.0
    t_abs = (world.survey_start or 0.0) + t
    beliefs = {**o.discrete, **{n: np.column_stack(mv) for n, mv in o.continuous.items()}}
    changes = season.changes if season is not None else None
    if changes is None:
        status = np.full(len(o.ids), "first" if survey == 0 else "new", dtype=object)
    else:
        status = np.full(len(o.ids), "seen", dtype=object)
        status[np.isin(o.ids, changes.new)] = "new"
        status[np.isin(o.ids, changes.unconfirmed)] = "unconfirmed"
        status[np.isin(o.ids, changes.unseen)] = "not_looked_at"
    mine = plant_rows(
        survey,
        o.ids,
        status,
        o.xy,
        o.cov,
        o.n_meas,
        o.interest,
        np.full(len(o.ids), np.nan),
        beliefs,
    )
    parts = [earlier.rows, mine]
    if changes is not None and len(changes.gone):
        gone = changes.gone
        g_beliefs = {
            **world.beliefs.discrete_beliefs(gone, t),
            **{
                n: np.column_stack(mv)
                for n, mv in world.beliefs.continuous_beliefs(gone, t).items()
            },
        }
        gone_rows = plant_rows(
            survey,
            gone,
            ["gone"] * len(gone),
            world.backend.object_positions(gone),
            world.backend.object_covariances(gone),
            world.objects.n_meas[gone],
            world.beliefs.interest(gone, t),
            changes.p_gone,
            g_beliefs,
        )
        parts.append(gone_rows)
    summary = season.summary() if season is not None else {"survey": survey, "localised": None}
    summary["survey"] = survey
    surveys = [
        *earlier.surveys,
        (survey, t_abs, int(bool(season and season.merged)), json.dumps(summary)),
    ]
    return History(surveys, ChainedRows(tuple(parts)))


def season_outputs(
    season: SeasonRun | None, world: WorldModel, snapshot: MapSnapshot | None
) -> list[tuple[str, Callable[[Path], Any]]]:
    """Extra writers for `pipeline.write_outputs`."""
    if snapshot is None:
        return []
    history = survey_history(season, world, snapshot)
    out: list[tuple[str, Callable[[Path], Any]]] = [
        ("map.sqlite", lambda p: write_history(p, history))
    ]
    if season is not None and season.changes is not None:
        survey = history.surveys[-1][0]
        mine = [r for r in history.rows if r[1] == survey and r[2] in ("new", "gone")]
        table = {
            "plant_id": [r[0] for r in mine],
            "change": [r[2] for r in mine],
            "x": [r[3] for r in mine],
            "y": [r[4] for r in mine],
            "p_gone": [np.nan if r[10] is None else r[10] for r in mine],
        }
        out.append(("changes.csv", lambda p: write_table(table, p)))
    if len(history.surveys) > 1:
        shown = growth_attribute(snapshot.schema)
        out.append(("season.png", lambda p: write_season_figure(history, p, shown)))
    return out


def load_season(path: str | Path, config: AgrislamConfig) -> SeasonRun:
    """A saved map.sqlite as the prior of the next survey, with its history. A map without
    history tables (an older one) has no absolute time: its beliefs are taken as of the new
    survey's start. `MapFileError` for a file that cannot be continued (run/saved_map.py)."""
    check_map_file(path)
    with reading(path):
        history = read_history(path)
        t_abs = history.t_abs()
        prior = PriorMap.from_snapshot(
            load_map(path), np.nan if t_abs is None else t_abs, history.next_survey or 1
        )
    season = SeasonRun(prior, config)
    season.history = history
    return season
