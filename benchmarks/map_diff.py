"""Whether two saved maps are the same, bit for bit: every table of two `map.sqlite` files
compared row by row (ids, positions, covariances, beliefs, trajectories), so that a change
meant to keep behaviour can show that it did.

    python benchmarks/map_diff.py RUN_A/map.sqlite RUN_B/map.sqlite

Exit 0 when every table is identical; 1 with each differing table, its first differing row
and the largest difference of its numbers otherwise.
"""

from __future__ import annotations

import argparse
import math
import sqlite3
import sys
from contextlib import closing
from pathlib import Path

# tables whose content is the map; `meta` and `format_version` say how it was written
MAP_TABLES = (
    "objects",
    "attributes",
    "discrete_beliefs",
    "continuous_beliefs",
    "trajectories",
    "poses",
    "rows",
    "arrays",
)


# arrays that time the run rather than describe the map
TIMINGS = "step_times/"


def table_rows(path: Path, table: str) -> list[tuple] | None:
    """Every row of `table` in primary-key order (the run's step times left out); None when
    the file has no such table."""
    with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
        found = db.execute(
            "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?", (table,)
        ).fetchone()
        if found is None:
            return None
        rows = db.execute(f'SELECT * FROM "{table}" ORDER BY 1, 2').fetchall()
    if table == "arrays":
        rows = [r for r in rows if not str(r[0]).startswith(TIMINGS)]
    return rows


def shown(row: tuple) -> str:
    """A row as text, its blobs by size only."""
    return str(tuple(f"<{len(v)} bytes>" if isinstance(v, bytes) else v for v in row))


def largest_difference(a: list[tuple], b: list[tuple]) -> float:
    """The largest absolute difference between numbers at the same place of two tables."""
    worst = 0.0
    for row_a, row_b in zip(a, b, strict=False):
        for x, y in zip(row_a, row_b, strict=False):
            if isinstance(x, float | int) and isinstance(y, float | int) and x != y:
                if math.isnan(x) and math.isnan(y):
                    continue
                worst = max(worst, abs(x - y))
    return worst


def compare(path_a: Path, path_b: Path) -> list[str]:
    """What differs between two saved maps, one line per table; empty when identical."""
    found = []
    for table in MAP_TABLES:
        a, b = table_rows(path_a, table), table_rows(path_b, table)
        if a == b:
            continue
        if a is None or b is None:
            found.append(f"{table}: only in {'B' if a is None else 'A'}")
            continue
        first = next(
            (i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b))
        )
        found.append(
            f"{table}: {len(a)} / {len(b)} rows, first difference at row {first} "
            f"({shown(a[first]) if first < len(a) else '-'} / "
            f"{shown(b[first]) if first < len(b) else '-'}), "
            f"largest numeric difference {largest_difference(a, b):.3g}"
        )
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("a", type=Path)
    parser.add_argument("b", type=Path)
    args = parser.parse_args()
    differences = compare(args.a, args.b)
    for line in differences:
        print(line)
    if not differences:
        counts = {t: len(table_rows(args.a, t) or []) for t in ("objects", "poses")}
        print(f"identical: {counts['objects']} objects, {counts['poses']} poses")
    return 1 if differences else 0


if __name__ == "__main__":
    sys.exit(main())
