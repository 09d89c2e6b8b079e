"""A saved `map.sqlite` read back, to continue it (`agrislam run --map`) or to show its
season (`agrislam history`). The file is checked whole before a run touches its output
folder, and each fault of it is one `MapFileError` naming the file, what is wrong with it
and what to do: not a SQLite file, cut short or with damaged pages, a file of other tables,
or the map of a run that did not finish (it holds that run's checkpoint, and is the map of
part of a survey: `--resume` finishes it)."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from contextlib import closing, contextmanager, suppress
from pathlib import Path

SQLITE_HEADER = b"SQLite format 3\x00"
MAX_PROBLEMS = 3  # of SQLite's integrity check, quoted in the message


class MapFileError(ValueError):
    """A map file that cannot be read or continued; the message says why and what to do."""


def check_map_file(path: str | Path, *, label: str = "--map", continuing: bool = True) -> None:
    """Raise `MapFileError` unless `path` is a whole SQLite file (SQLite's quick check of
    every page) that does not hold the checkpoint of an unfinished run (`continuing`: its
    map is part of a survey; to show it, a stopped run's map will do). Reads only."""
    path = Path(path)
    where = f"{label} {path}"
    if not path.is_file():
        raise MapFileError(f"{where}: no such map file")
    if path.with_name(path.name + "-journal").exists():  # a checkpoint's write cut by a kill
        raise MapFileError(_unfinished(where, path, {}))
    with path.open("rb") as f:
        header = f.read(len(SQLITE_HEADER))
    if header != SQLITE_HEADER:
        what = "is empty" if not header else "is not a SQLite file"
        raise MapFileError(f"{where} {what}: give the map.sqlite a run wrote")
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            found = [p for (p,) in db.execute(f"PRAGMA quick_check({MAX_PROBLEMS})")]
            if found != ["ok"]:  # a row may hold several lines, under a '*** in ...' title
                lines = [x for p in found for x in p.splitlines() if not x.startswith("***")]
                raise MapFileError(_damaged(where, "; ".join(lines[:MAX_PROBLEMS])))
            tables = {n for (n,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            if continuing and "checkpoint" in tables:
                wanted = "SELECT key, value FROM checkpoint WHERE key IN ('input', 'position')"
                entries = dict(db.execute(wanted))
                raise MapFileError(_unfinished(where, path, entries))
    except sqlite3.DatabaseError as err:
        raise MapFileError(_damaged(where, str(err))) from None


@contextmanager
def reading(path: str | Path, label: str = "--map") -> Iterator[None]:
    """Errors of reading a checked map file (tables of another layout, values that do not
    parse) as one `MapFileError` line naming it."""
    try:
        yield
    except MapFileError:
        raise
    except (sqlite3.Error, KeyError, IndexError, TypeError, ValueError) as err:
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        if not text.startswith(str(path)):  # load_map's own errors name the file already
            text = f"{path}: cannot be read as an agrislam map ({type(err).__name__}: {text})"
        raise MapFileError(f"{label} {text}") from None


def _damaged(where: str, why: str) -> str:
    return (
        f"{where} is damaged ({why}): it was cut short or overwritten; use an intact copy "
        "(a run writes its map.sqlite whole, so its own copy is)"
    )


def _unfinished(where: str, path: Path, entries: dict[str, bytes]) -> str:
    """What to do with the map of a run that did not finish: finish that run."""
    log = "LOG"
    with suppress(KeyError, TypeError, ValueError):
        log = json.loads(entries["input"])["input"]
    at = f" at record {int(entries['position'])}" if entries.get("position") else ""
    return (
        f"{where} is the map of a run that did not finish (killed or stopped; it holds its "
        f"checkpoint{at}), a part of its survey: finish that run first with `agrislam run "
        f"{log} --out {path.parent} --resume` (with the config it ran with), then continue "
        "its map"
    )
