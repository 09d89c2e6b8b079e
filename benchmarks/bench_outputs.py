"""Wall time of the output writers on a whole field, and what `release_free_heap` hands back
of a fragmented C heap: the figures the unit tests check only the causes of.

    python benchmarks/bench_outputs.py [--rows 100] [--per-row 1000] [--steps 10000]

The field is synthetic (straight rows 1 m apart, plants 0.3 m apart, peaked beliefs, two
robots, an interest surface): 100,000 plants and 10,000 steps by default.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from agrislam.config import COLOURS, SIZES, FieldSchema, SemanticsConfig
from agrislam.io.sinks.csv import write_objects_csv, write_trajectory_csv
from agrislam.io.sinks.report import write_report
from agrislam.run.collector import release_free_heap
from agrislam.semantics.continuous import entropy_normalised
from agrislam.semantics.heuristic import interest, interest_surface
from agrislam.snapshot import MapSnapshot, ObjectMap, RowLines, Trajectory

STAGES = ("predict", "associate", "update", "optimise", "maintain")
console = Console(width=120)


def field_snapshot(n_rows: int, per_row: int, n_steps: int, seed: int = 0) -> MapSnapshot:
    """`n_rows` rows of `per_row` plants with colour, size and length beliefs."""
    rng = np.random.default_rng(seed)
    k = n_rows * per_row
    xy = np.column_stack(
        [np.tile(np.arange(per_row) * 0.3, n_rows), np.repeat(np.arange(n_rows), per_row)]
    ) + rng.normal(0.0, 0.02, (k, 2))
    cov = np.zeros((k, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = rng.uniform(1e-4, 2.5e-3, k), rng.uniform(1e-4, 2.5e-3, k)

    def peaked(n_values: int) -> np.ndarray:
        p = rng.dirichlet(np.ones(n_values), k) * 0.3
        p[np.arange(k), rng.integers(0, n_values, k)] += 0.7
        return p

    schema = FieldSchema.model_validate(
        {
            "attributes": {
                "colour": {"kind": "discrete", "values": COLOURS},
                "size": {"kind": "discrete", "values": SIZES},
                "length": {"kind": "continuous", "min": 0.0, "max": 0.6},
            }
        }
    )
    discrete = {"colour": peaked(len(COLOURS)), "size": peaked(len(SIZES))}
    length = (rng.uniform(0.1, 0.5, k), rng.uniform(1e-4, 4e-3, k))
    n_meas = rng.integers(1, 12, k)
    semantics = SemanticsConfig()
    h = interest(n_meas, discrete.values(), [entropy_normalised(length[1], 0.6)], semantics)
    t = np.arange(n_steps, dtype=float)
    x = np.linspace(-0.5, per_row * 0.3, n_steps)
    trajectories = {
        robot: Trajectory(robot, t, np.column_stack([x, np.full(n_steps, y), np.zeros(n_steps)]))
        for robot, y in (("spot", 0.5), ("husky", n_rows - 1.5))
    }
    return MapSnapshot(
        schema=schema,
        objects=ObjectMap(
            ids=np.arange(k, dtype=np.int64),
            xy=xy,
            cov=cov,
            n_meas=n_meas,
            interest=h,
            row=np.repeat(np.arange(n_rows, dtype=np.int64), per_row),
            discrete=discrete,
            continuous={"length": length},
        ),
        trajectories=trajectories,
        dead_reckoning=trajectories,
        rows=RowLines(angle=0.0, offsets=np.arange(n_rows, dtype=float)),
        interest_surface=interest_surface(xy, h, semantics),
        step_times={stage: rng.uniform(1e-3, 5e-2, n_steps) for stage in STAGES},
    )


def timed(write, snapshot: MapSnapshot, path: Path) -> float:
    start = time.perf_counter()
    write(snapshot, path)
    return time.perf_counter() - start


def resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def heap_handed_back_mb(blocks: int = 40_000, size: int = 4000) -> float | None:
    """Resident memory `release_free_heap` hands back after freeing all but every 64th of
    `blocks` malloc'd blocks (the heap cannot shrink from its top); None without glibc."""
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return None
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.malloc.restype = ctypes.c_void_p
    libc.free.argtypes = [ctypes.c_void_p]
    held = [libc.malloc(size) for _ in range(blocks)]
    for n, block in enumerate(held):
        ctypes.memset(block, 1, size)  # resident
        if n % 64:
            libc.free(block)
    before = resident_mb()
    release_free_heap()
    handed_back = before - resident_mb()
    for block in held[::64]:
        libc.free(block)
    return handed_back


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=100)
    parser.add_argument("--per-row", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=10_000)
    args = parser.parse_args()
    snapshot = field_snapshot(args.rows, args.per_row, args.steps)
    table = Table(title=f"{len(snapshot.objects):,} plants, {args.steps:,} steps")
    table.add_column("output")
    table.add_column("wall time (s)", justify="right")
    table.add_column("target at 100,000 plants (s)", justify="right")
    with tempfile.TemporaryDirectory() as tmp:
        for name, write, target in (
            ("objects.csv", write_objects_csv, "< 5"),
            ("trajectory.csv", write_trajectory_csv, ""),
            ("report.png", write_report, "< 20"),
        ):
            table.add_row(name, f"{timed(write, snapshot, Path(tmp) / name):.2f}", target)
    console.print(table)
    back = heap_handed_back_mb()
    if back is None:
        console.print("release_free_heap: no glibc, nothing to measure")
    else:
        console.print(
            f"release_free_heap: {back:.0f} MB of a fragmented ~160 MB heap handed back"
            " (target > 100 MB)"
        )


if __name__ == "__main__":
    main()
