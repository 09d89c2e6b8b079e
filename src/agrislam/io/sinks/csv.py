"""`objects.csv` and `trajectory.csv` (DESIGN.md "Outputs of a run"): the map as plain tables,
from `sinks.columns`' arrays, formatted a chunk of rows at a time and written by the standard
library's csv writer (RFC 4180 quoting)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from agrislam.io.sinks.columns import object_columns, trajectory_columns
from agrislam.snapshot import MapSnapshot

FLOAT_FORMAT = "{:.9g}".format  # 9 significant digits: 0.1 mm at 10 km, 1e-9 in probabilities
NUMERIC_KINDS = "fiub"  # numpy kinds written as numbers: float, int, unsigned, bool
CHUNK = 4096  # rows formatted at a time


def write_objects_csv(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write `objects.csv`: one row per mapped object (DESIGN.md "Outputs of a run")."""
    return write_table(object_columns(snapshot), path)


def write_trajectory_csv(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write `trajectory.csv`: the optimised and dead-reckoned poses of every robot."""
    return write_table(trajectory_columns(snapshot), path)


def write_table(columns: dict[str, np.ndarray], path: str | Path) -> Path:
    """Write equal-length columns as CSV with a header line; a field with a comma, quote or
    line break is quoted (RFC 4180); lines end in a bare newline. Rows are formatted
    CHUNK at a time: no list of strings per column of the whole table."""
    path = Path(path)
    arrays = [np.asarray(c) for c in columns.values()]
    lengths = {len(a) for a in arrays}
    if len(lengths) > 1:
        raise ValueError(f"columns of different lengths {sorted(lengths)}")
    with path.open("w", encoding="utf-8", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        # before Python 3.13 the writer quotes only the line terminator's own characters, so
        # a lone \r would go out bare and split the row for a reader: quote such a row whole
        quoted = csv.writer(f, lineterminator="\n", quoting=csv.QUOTE_ALL)
        (quoted if any("\r" in v for v in columns) else writer).writerow(list(columns))
        for start in range(0, max(lengths, default=0), CHUNK):
            text = [_format_column(a[start : start + CHUNK]) for a in arrays]
            names = [
                t for a, t in zip(arrays, text, strict=True) if a.dtype.kind not in NUMERIC_KINDS
            ]
            if not any("\r" in v for c in names for v in c):
                writer.writerows(zip(*text, strict=True))
                continue
            for row in zip(*text, strict=True):
                (quoted if any("\r" in v for v in row) else writer).writerow(row)
    return path


def _format_column(column: np.ndarray) -> list[str]:
    if column.dtype.kind == "f":
        return list(map(FLOAT_FORMAT, column.tolist()))
    if column.dtype.kind in NUMERIC_KINDS:
        return list(map(str, column.astype(np.int64).tolist()))
    return column.astype(str).tolist()
