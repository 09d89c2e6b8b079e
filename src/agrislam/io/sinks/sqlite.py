"""`map.sqlite`: the persistent map store a later survey resumes from, as plain tables a
farmer can query with any SQLite tool; `load_map` gives back exactly the `MapSnapshot` that
`save_map` was given, and saving is atomic (sinks.atomic)."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Iterator
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.config import FieldSchema
from agrislam.io.sinks.atomic import atomic_path
from agrislam.io.sinks.readouts import discrete_columns
from agrislam.records import Anchor
from agrislam.semantics.heuristic import InterestSurface
from agrislam.snapshot import MapSnapshot, ObjectMap, RowLines, Trajectory

FORMAT_NAME = "agrislam-map"
FORMAT_VERSION = 1
TRAJECTORY_KINDS = ("optimised", "dead_reckoning")
CHUNK = 4096  # rows turned into Python values at a time

TABLES = """
CREATE TABLE format_version (name TEXT NOT NULL, version INTEGER NOT NULL);
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE objects (
    seq INTEGER PRIMARY KEY, id INTEGER NOT NULL UNIQUE, x REAL, y REAL,
    cov_xx REAL, cov_xy REAL, cov_yy REAL, n_meas INTEGER NOT NULL,
    row INTEGER NOT NULL, interest REAL);
CREATE TABLE attributes (
    position INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE,
    kind TEXT NOT NULL CHECK (kind IN ('discrete', 'continuous')), n_values INTEGER);
CREATE TABLE discrete_beliefs (
    object_id INTEGER NOT NULL REFERENCES objects(id), attribute TEXT NOT NULL,
    value_index INTEGER NOT NULL, value TEXT NOT NULL, probability REAL,
    PRIMARY KEY (object_id, attribute, value_index)) WITHOUT ROWID;
CREATE TABLE continuous_beliefs (
    object_id INTEGER NOT NULL REFERENCES objects(id), attribute TEXT NOT NULL,
    mean REAL, var REAL, PRIMARY KEY (object_id, attribute)) WITHOUT ROWID;
CREATE TABLE trajectories (
    position INTEGER PRIMARY KEY, kind TEXT NOT NULL, robot TEXT NOT NULL,
    UNIQUE (kind, robot));
CREATE TABLE poses (
    trajectory INTEGER NOT NULL REFERENCES trajectories(position), seq INTEGER NOT NULL,
    t REAL, x REAL, y REAL, theta REAL, PRIMARY KEY (trajectory, seq)) WITHOUT ROWID;
CREATE TABLE rows (row INTEGER PRIMARY KEY, offset REAL);
CREATE TABLE arrays (name TEXT PRIMARY KEY, dtype TEXT NOT NULL, shape TEXT NOT NULL,
    data BLOB NOT NULL);
"""


def save_map(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write the snapshot to `path` (replacing any file there) atomically: the tables and
    their rows in one transaction of a new file beside the target, which replaces it once
    on disk (`sinks.atomic`), so a killed run leaves the old map or the new one."""
    path = Path(path)
    with atomic_path(path) as tmp, closing(sqlite3.connect(tmp, isolation_level=None)) as db:
        db.execute("PRAGMA journal_mode = OFF")  # a new file: the rename is the commit
        db.execute("PRAGMA synchronous = OFF")  # atomic_path syncs the file before it
        db.execute("BEGIN")
        for statement in TABLES.split(";"):
            if statement.strip():
                db.execute(statement)
        _write(db, snapshot)
        db.execute("COMMIT")
    return path


def load_map(path: str | Path) -> MapSnapshot:
    """Read a map written by `save_map`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such map file")
    with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
        _check_format(db, path)
        meta = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")}
        objects = _read_objects(db)
        trajectories = _read_trajectories(db)
        arrays = _read_arrays(db)
        offsets = db.execute("SELECT offset FROM rows ORDER BY row").fetchall()
    surface = meta.get("interest_surface")
    return MapSnapshot(
        schema=None if meta["schema"] is None else FieldSchema.model_validate(meta["schema"]),
        objects=objects,
        trajectories=trajectories["optimised"],
        dead_reckoning=trajectories["dead_reckoning"],
        anchor=None if meta["anchor"] is None else Anchor(**meta["anchor"]),
        rows=None
        if meta["rows_angle"] is None
        else RowLines(meta["rows_angle"], _floats([o for (o,) in offsets])),
        interest_surface=None
        if surface is None
        else InterestSurface(
            surface["x0"], surface["y0"], surface["resolution"], arrays["interest_surface"]
        ),
        step_times={stage: arrays[f"step_times/{stage}"] for stage in meta["step_stages"]},
    )


# ------------------------------------------------------------------------------ write


def _write(db: sqlite3.Connection, snapshot: MapSnapshot) -> None:
    db.execute("INSERT INTO format_version VALUES (?, ?)", (FORMAT_NAME, FORMAT_VERSION))
    surface = snapshot.interest_surface
    meta: dict[str, Any] = {
        "schema": None if snapshot.schema is None else snapshot.schema.model_dump(mode="json"),
        "anchor": None if snapshot.anchor is None else _anchor_dict(snapshot.anchor),
        "rows_angle": None if snapshot.rows is None else float(snapshot.rows.angle),
        "interest_surface": None
        if surface is None
        else {"x0": surface.x0, "y0": surface.y0, "resolution": surface.resolution},
        "step_stages": list(snapshot.step_times),
    }
    db.executemany("INSERT INTO meta VALUES (?, ?)", ((k, json.dumps(v)) for k, v in meta.items()))
    _write_objects(db, snapshot)
    _write_trajectories(db, snapshot)
    if snapshot.rows is not None:
        offsets = np.asarray(snapshot.rows.offsets, dtype=float).tolist()
        db.executemany("INSERT INTO rows VALUES (?, ?)", enumerate(offsets))
    arrays = {f"step_times/{stage}": t for stage, t in snapshot.step_times.items()}
    if surface is not None:
        arrays["interest_surface"] = surface.values
    db.executemany("INSERT INTO arrays VALUES (?, ?, ?, ?)", map(_array_row, arrays.items()))


def _write_objects(db: sqlite3.Connection, snapshot: MapSnapshot) -> None:
    objects = snapshot.objects
    discrete = discrete_columns(snapshot)  # checks shapes and value names against the schema
    ids = np.asarray(objects.ids).astype(np.int64)
    unique, counts = np.unique(ids, return_counts=True)
    if np.any(counts > 1):
        dup = unique[counts > 1][:10].tolist()
        raise ValueError(f"objects.ids are not unique: {dup} appear more than once")
    cov = np.asarray(objects.cov, dtype=float).reshape(-1, 2, 2)
    xy = np.asarray(objects.xy, dtype=float).reshape(-1, 2)
    db.executemany(
        "INSERT INTO objects VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        _rows(
            np.arange(len(ids)),
            ids,
            xy[:, 0],
            xy[:, 1],
            cov[:, 0, 0],
            0.5 * (cov[:, 0, 1] + cov[:, 1, 0]),  # a covariance is symmetric: keep one entry
            cov[:, 1, 1],
            np.asarray(objects.n_meas).astype(np.int64),
            np.asarray(objects.row).astype(np.int64),
            np.asarray(objects.interest, dtype=float),
        ),
    )
    attributes = [(name, "discrete", b.shape[1]) for name, (_, b) in discrete.items()]
    attributes += [(name, "continuous", None) for name in objects.continuous]
    db.executemany("INSERT INTO attributes VALUES (?, ?, ?, ?)", _enumerated(attributes))
    for name, (values, belief) in discrete.items():
        n = belief.shape[1]
        db.executemany(
            "INSERT INTO discrete_beliefs VALUES (?, ?, ?, ?, ?)",
            _rows(
                np.repeat(ids, n),
                np.full(belief.size, name, dtype=object),
                np.tile(np.arange(n), len(ids)),
                np.tile(np.asarray(values, dtype=object), len(ids)),
                belief.ravel(),
            ),
        )
    for name, (mean, var) in objects.continuous.items():
        db.executemany(
            "INSERT INTO continuous_beliefs VALUES (?, ?, ?, ?)",
            _rows(ids, np.full(len(ids), name, dtype=object), _floats(mean), _floats(var)),
        )


def _write_trajectories(db: sqlite3.Connection, snapshot: MapSnapshot) -> None:
    heads = [
        (kind, traj)
        for kind, trajs in zip(
            TRAJECTORY_KINDS, (snapshot.trajectories, snapshot.dead_reckoning), strict=True
        )
        for traj in trajs.values()
    ]
    db.executemany(
        "INSERT INTO trajectories VALUES (?, ?, ?)",
        _enumerated((kind, traj.robot) for kind, traj in heads),
    )
    for position, (_, traj) in enumerate(heads):
        poses = np.asarray(traj.poses, dtype=float).reshape(-1, 3)
        m = len(poses)
        db.executemany(
            "INSERT INTO poses VALUES (?, ?, ?, ?, ?, ?)",
            _rows(np.full(m, position), np.arange(m), _floats(traj.t), *poses.T),
        )


# ------------------------------------------------------------------------------- read


def _check_format(db: sqlite3.Connection, path: Path) -> None:
    try:
        row = db.execute("SELECT name, version FROM format_version").fetchone()
    except sqlite3.DatabaseError as err:
        raise ValueError(f"{path}: not an agrislam map ({err})") from None
    if row is None or row[0] != FORMAT_NAME:
        raise ValueError(f"{path}: not an agrislam map (format_version holds {row!r})")
    if row[1] != FORMAT_VERSION:
        raise ValueError(
            f"{path}: map format version {row[1]}, this agrislam reads version {FORMAT_VERSION}"
        )


def _read_objects(db: sqlite3.Connection) -> ObjectMap:
    rows = db.execute(
        "SELECT id, x, y, cov_xx, cov_xy, cov_yy, n_meas, row, interest FROM objects ORDER BY seq"
    ).fetchall()
    k = len(rows)
    columns = list(zip(*rows, strict=True)) if rows else [()] * 9
    ids, n_meas, row = (np.array(columns[i], dtype=np.int64) for i in (0, 6, 7))
    x, y, cxx, cxy, cyy, interest = (_floats(columns[i]) for i in (1, 2, 3, 4, 5, 8))
    cov = np.stack([cxx, cxy, cxy, cyy], axis=1).reshape(k, 2, 2)
    by_id = np.argsort(ids)
    discrete: dict[str, np.ndarray] = {}
    continuous: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, kind, n_values in db.execute(
        "SELECT name, kind, n_values FROM attributes ORDER BY position"
    ).fetchall():
        if kind == "discrete":
            belief = np.full((k, n_values), np.nan)
            cells = db.execute(
                "SELECT object_id, value_index, probability FROM discrete_beliefs "
                "WHERE attribute = ?",
                (name,),
            ).fetchall()
            if cells:
                obj, j, p = zip(*cells, strict=True)
                belief[_rows_of(ids, by_id, obj), list(j)] = _floats(p)
            discrete[name] = belief
        else:
            mean, var = np.full(k, np.nan), np.full(k, np.nan)
            cells = db.execute(
                "SELECT object_id, mean, var FROM continuous_beliefs WHERE attribute = ?",
                (name,),
            ).fetchall()
            if cells:
                obj, m, v = zip(*cells, strict=True)
                where = _rows_of(ids, by_id, obj)
                mean[where], var[where] = _floats(m), _floats(v)
            continuous[name] = (mean, var)
    return ObjectMap(
        ids=ids,
        xy=np.column_stack([x, y]).reshape(k, 2),
        cov=cov,
        n_meas=n_meas,
        interest=interest,
        row=row,
        discrete=discrete,
        continuous=continuous,
    )


def _read_trajectories(db: sqlite3.Connection) -> dict[str, dict[str, Trajectory]]:
    out: dict[str, dict[str, Trajectory]] = {kind: {} for kind in TRAJECTORY_KINDS}
    heads = db.execute("SELECT position, kind, robot FROM trajectories ORDER BY position")
    for position, kind, robot in heads.fetchall():
        rows = db.execute(
            "SELECT t, x, y, theta FROM poses WHERE trajectory = ? ORDER BY seq", (position,)
        ).fetchall()
        table = _floats(rows).reshape(-1, 4)
        out[kind][robot] = Trajectory(robot, table[:, 0].copy(), table[:, 1:].copy())
    return out


def _read_arrays(db: sqlite3.Connection) -> dict[str, np.ndarray]:
    return {
        name: np.frombuffer(data, dtype=np.dtype(dtype)).reshape(json.loads(shape)).copy()
        for name, dtype, shape, data in db.execute("SELECT name, dtype, shape, data FROM arrays")
    }


# ---------------------------------------------------------------------------- helpers


def _rows(*columns: np.ndarray) -> Iterator[tuple[Any, ...]]:
    """Row tuples of plain Python values from equal-length columns (NaN is stored as NULL),
    converted CHUNK rows at a time: no list of Python values per column of the whole map."""
    arrays = [np.asarray(c) for c in columns]
    lengths = {len(a) for a in arrays}
    if len(lengths) > 1:
        raise ValueError(f"columns of different lengths {sorted(lengths)}")
    for start in range(0, max(lengths, default=0), CHUNK):
        yield from zip(*(a[start : start + CHUNK].tolist() for a in arrays), strict=True)


def _rows_of(ids: np.ndarray, by_id: np.ndarray, wanted: Iterable[int]) -> np.ndarray:
    """Array rows of the objects with ids `wanted` (`by_id` = argsort of `ids`)."""
    return by_id[np.searchsorted(ids, np.asarray(wanted, dtype=np.int64), sorter=by_id)]


def _enumerated(rows: Iterable[tuple[Any, ...]]) -> Iterable[tuple[Any, ...]]:
    return ((i, *row) for i, row in enumerate(rows))


def _floats(values: Any) -> np.ndarray:
    """float64 array; SQLite NULL (how it keeps NaN) comes back as NaN."""
    return np.array(values, dtype=float)


def _array_row(item: tuple[str, np.ndarray]) -> tuple[str, str, str, bytes]:
    name, array = item
    array = np.ascontiguousarray(array)
    return name, array.dtype.str, json.dumps(array.shape), array.tobytes()


def _anchor_dict(anchor: Anchor) -> dict[str, float]:
    return {"lat": anchor.lat, "lon": anchor.lon, "h": anchor.h, "yaw_deg": anchor.yaw_deg}


# ------------------------------------------------------------------------- checkpoints

CHECKPOINT_TABLE = "CREATE TABLE checkpoint (key TEXT PRIMARY KEY, value BLOB NOT NULL)"


def write_checkpoint(
    path: str | Path, entries: dict[str, bytes], snapshot: MapSnapshot | None = None
) -> None:
    """A run in progress: its map so far (`snapshot`, replacing the file's tables) and what
    resumes it (`entries`, the `checkpoint` table), in one transaction of the file at
    `path` with a rollback journal, so a process killed while it writes leaves the previous
    checkpoint whole (SQLite rolls the journal back when the file is next opened)."""
    with closing(sqlite3.connect(path, isolation_level=None)) as db:
        db.execute("PRAGMA journal_mode = DELETE")
        db.execute("PRAGMA synchronous = FULL")
        db.execute("BEGIN IMMEDIATE")
        old = db.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()
        for (name,) in old:
            if snapshot is not None or name == "checkpoint":
                db.execute(f'DROP TABLE "{name}"')
        if snapshot is not None:
            for statement in TABLES.split(";"):
                if statement.strip():
                    db.execute(statement)
            _write(db, snapshot)
        db.execute(CHECKPOINT_TABLE)
        db.executemany("INSERT INTO checkpoint VALUES (?, ?)", entries.items())
        db.execute("COMMIT")


def read_checkpoint(path: str | Path) -> dict[str, bytes] | None:
    """The `checkpoint` table of `path`: None for a map without one (a finished run's),
    empty for a file without tables (its first checkpoint was cut). A checkpoint cut by a
    killed write is rolled back to the one before it first."""
    with closing(sqlite3.connect(path, isolation_level=None)) as db:
        tables = {n for (n,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "checkpoint" not in tables:
            return None if tables else {}
        return {k: bytes(v) for k, v in db.execute("SELECT key, value FROM checkpoint")}
