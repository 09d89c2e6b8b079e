"""The season's history in `map.sqlite`: one row per survey (`surveys`) and one row per plant
per survey (`plant_history`: position, beliefs, interest, what happened to it), tables of
their own written into the same atomic file after `sqlite.save_map`. For example:

    SELECT survey, status, x, y, json_extract(beliefs, '$.length[0]') AS length
    FROM plant_history WHERE plant_id = 17 ORDER BY survey;"""

from __future__ import annotations

import itertools
import json
import sqlite3
from collections.abc import Iterable, Iterator
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

STATUSES = ("first", "seen", "new", "unconfirmed", "gone", "not_looked_at")
HISTORY_TABLES = """
CREATE TABLE surveys (
    survey INTEGER PRIMARY KEY, t_abs REAL NOT NULL, localised INTEGER NOT NULL,
    summary TEXT NOT NULL);
CREATE TABLE plant_history (
    plant_id INTEGER NOT NULL, survey INTEGER NOT NULL REFERENCES surveys(survey),
    status TEXT NOT NULL CHECK (status IN ('first', 'seen', 'new', 'unconfirmed', 'gone',
        'not_looked_at')),
    x REAL, y REAL, cov_xx REAL, cov_xy REAL, cov_yy REAL, n_meas INTEGER,
    interest REAL, p_gone REAL, beliefs TEXT NOT NULL,
    PRIMARY KEY (plant_id, survey)) WITHOUT ROWID;
CREATE INDEX plant_history_by_survey ON plant_history (survey, status);
"""
ROWS_AT_ONCE = 4096  # plants turned into rows at a time
COLUMNS = (
    "plant_id, survey, status, x, y, cov_xx, cov_xy, cov_yy, n_meas, interest, p_gone, beliefs"
)


@dataclass
class History:
    """Every survey and every plant row of a map's history (rows as tuples of COLUMNS,
    iterable more than once: a list, `PlantRows` or `ChainedRows`)."""

    surveys: list[tuple[int, float, int, str]] = field(default_factory=list)
    rows: Iterable[tuple[Any, ...]] = field(default_factory=list)

    @property
    def next_survey(self) -> int:
        return 1 + max((s[0] for s in self.surveys), default=-1)

    def t_abs(self) -> float | None:
        """Absolute time of the latest survey's beliefs."""
        return self.surveys[-1][1] if self.surveys else None

    def plant(self, plant_id: int) -> list[dict[str, Any]]:
        """One plant's rows, oldest first, as dicts (beliefs decoded)."""
        names = COLUMNS.split(", ")
        out = [dict(zip(names, r, strict=True)) for r in self.rows if r[0] == plant_id]
        for row in out:
            row["beliefs"] = json.loads(row["beliefs"])
        return sorted(out, key=lambda r: r["survey"])


@dataclass(frozen=True)
class PlantRows:
    """History rows of one survey, made from its arrays as they are read (iterable again and
    again), so a whole field's rows never sit in memory at once as tuples and JSON. `beliefs`:
    name -> (k, n) discrete probabilities or continuous (mean, var), stored as JSON per plant."""

    survey: int
    ids: np.ndarray
    status: np.ndarray
    xy: np.ndarray
    cov: np.ndarray
    n_meas: np.ndarray
    interest: np.ndarray
    p_gone: np.ndarray
    beliefs: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.ids)

    def __iter__(self) -> Iterator[tuple[Any, ...]]:
        for start in range(0, len(self.ids), ROWS_AT_ONCE):
            yield from self._rows(slice(start, start + ROWS_AT_ONCE))

    def _rows(self, part: slice) -> Iterator[tuple[Any, ...]]:
        names = list(self.beliefs)
        n = len(self.ids[part])
        per_plant = (
            zip(*(np.round(self.beliefs[b][part], 6).tolist() for b in names), strict=True)
            if names
            else (() for _ in range(n))
        )
        for i, s, p, c, m, h, g, b in zip(
            self.ids[part].tolist(),
            self.status[part].tolist(),
            self.xy[part].tolist(),
            self.cov[part].reshape(-1, 4)[:, [0, 1, 3]].tolist(),
            self.n_meas[part].tolist(),
            self.interest[part].tolist(),
            self.p_gone[part].tolist(),
            per_plant,
            strict=True,
        ):
            gone = None if not np.isfinite(g) else g
            belief = json.dumps(dict(zip(names, b, strict=True)))
            yield (i, self.survey, str(s), *p, *c, m, h, gone, belief)


def plant_rows(
    survey: int,
    ids: np.ndarray,
    status: list[str] | np.ndarray,
    xy: np.ndarray,
    cov: np.ndarray,
    n_meas: np.ndarray,
    interest: np.ndarray,
    p_gone: np.ndarray,
    beliefs: dict[str, np.ndarray],
) -> PlantRows:
    """History rows of one survey, made as they are read (`PlantRows`)."""
    return PlantRows(
        survey,
        np.asarray(ids, dtype=np.int64),
        np.asarray(status, dtype=object),
        np.asarray(xy, dtype=float).reshape(-1, 2),
        np.asarray(cov, dtype=float).reshape(-1, 2, 2),
        np.asarray(n_meas, dtype=np.int64),
        np.asarray(interest, dtype=float),
        np.asarray(p_gone, dtype=float),
        beliefs,
    )


@dataclass(frozen=True)
class ChainedRows:
    """Several surveys' rows read one after the other, as often as asked."""

    parts: tuple[Iterable[tuple[Any, ...]], ...]

    def __iter__(self) -> Iterator[tuple[Any, ...]]:
        return itertools.chain.from_iterable(self.parts)


def write_history(path: str | Path, history: History) -> None:
    """Add the history tables to a map file `save_map` has just written (one transaction)."""
    with closing(sqlite3.connect(path, isolation_level=None)) as db:
        db.execute("BEGIN")
        for statement in HISTORY_TABLES.split(";"):
            if statement.strip():
                db.execute(statement)
        db.executemany("INSERT INTO surveys VALUES (?, ?, ?, ?)", history.surveys)
        db.executemany(
            f"INSERT INTO plant_history ({COLUMNS}) VALUES ({', '.join('?' * 12)})", history.rows
        )
        db.execute("COMMIT")


def read_history(path: str | Path) -> History:
    """The history of a map file; empty for a map without history tables (an older one)."""
    with closing(sqlite3.connect(f"{Path(path).resolve().as_uri()}?mode=ro", uri=True)) as db:
        tables = {
            name for (name,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")
        }
        if "surveys" not in tables:
            return History()
        surveys = db.execute(
            "SELECT survey, t_abs, localised, summary FROM surveys ORDER BY survey"
        )
        rows = db.execute(f"SELECT {COLUMNS} FROM plant_history ORDER BY survey, plant_id")
        return History(surveys.fetchall(), rows.fetchall())
