"""Where a survey's memory goes: the mapping's parts and each output writer.

One survey (the simulator as the source) is mapped without outputs; then
- each part of the map's state is released in turn (the glibc heap trimmed after each),
  and the fall in resident memory is its footprint, C++ (GTSAM) and Python alike;
- each output writer runs on its own, with the peak resident memory reset before it
  (`/proc/self/clear_refs`) and tracemalloc tracing it: its rise in peak RSS above what
  the process held before it, and its peak of Python allocations.

    python benchmarks/profile_memory.py [--plants 2000] [--seed 2] [--trace]

Linux only (`/proc/self/status`, `malloc_trim`).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import importlib.util
import tempfile
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

console = Console(width=150)
LIBC = ctypes.CDLL("libc.so.6")


def status_mb(field: str) -> float:
    """VmRSS or VmHWM of this process, MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise KeyError(field)


def settle() -> float:
    """Resident MB after garbage collection and giving freed heap back to the system."""
    gc.collect()
    LIBC.malloc_trim(0)
    return status_mb("VmRSS")


def reset_peak() -> None:
    Path("/proc/self/clear_refs").write_text("5")


def measured(name: str, write: Callable[[Path], Any], out: Path, rows: list, trace: bool) -> None:
    """Run one writer; its rise in peak RSS and (`trace`) its Python allocation peak
    (tracemalloc's own bookkeeping then adds to the RSS)."""
    held = settle()
    reset_peak()
    if trace:
        tracemalloc.start()
    write(out / name)
    py_peak = tracemalloc.get_traced_memory()[1] if trace else float("nan")
    tracemalloc.stop()
    rows.append((name, status_mb("VmHWM") - held, py_peak / 2**20))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--trace", action="store_true", help="also tracemalloc each writer")
    args = parser.parse_args()

    from agrislam.config import AgrislamConfig, OutputsConfig
    from agrislam.evaluation.metrics import write_metrics
    from agrislam.io.sinks import csv, foxglove, report, ros_map
    from agrislam.io.sources import open_source
    from agrislam.io.sources.simulated import simulation_uri
    from agrislam.run import pipeline
    from agrislam.world import WorldModel

    start = settle()
    config = AgrislamConfig()
    source = open_source(simulation_uri(plants=args.plants, seed=args.seed), config)
    world = WorldModel(config)
    result = pipeline._run(source, world, None, None)
    peak_run = status_mb("VmHWM")
    mapped = settle()
    snapshot = result.snapshot
    n = args.plants
    parts: list[tuple[str, float]] = []

    writers: list[tuple[str, Callable[[Path], Any]]] = [
        ("objects.csv", lambda p: csv.write_objects_csv(snapshot, p)),
        ("trajectory.csv", lambda p: csv.write_trajectory_csv(snapshot, p)),
        ("map.sqlite", lambda p: pipeline._save_map(snapshot, p, None)),
        *pipeline.geo_writers(snapshot, OutputsConfig()),
        ("map.mcap", lambda p: ros_map.write_map_mcap(snapshot, p)),
    ]
    if importlib.util.find_spec("foxglove") is not None:
        writers.append(("map_foxglove.mcap", lambda p: foxglove.write_foxglove_mcap(snapshot, p)))
    trajectories = pipeline.Truth().trajectories()
    writers.append(
        (
            "report.png",
            lambda p: report.write_report(snapshot, p, metrics=result.metrics, truth=trajectories),
        )
    )
    writers.append(("metrics.json", lambda p: write_metrics(result.metrics or {}, p)))
    rows: list[tuple[str, float, float]] = []
    with tempfile.TemporaryDirectory() as out:
        for name, write in writers:
            measured(name, write, Path(out), rows, args.trace)

    # the mapping's parts, released one by one
    before = settle()
    for name, release in (
        ("snapshot", lambda: setattr(result, "snapshot", None)),
        ("metrics", lambda: setattr(result, "metrics", None)),
        ("spatial index", lambda: setattr(world, "index", None)),
        ("rows", lambda: setattr(world, "rows", None)),
        ("robots (odometry chains)", lambda: world.robots.clear()),
        ("step timer", lambda: setattr(world, "_timer", None)),
        ("noise calibration", lambda: setattr(world, "noise", None)),
        ("objects + beliefs", lambda: setattr(world, "objects", None)),
        ("back end (graph, values, iSAM2)", lambda: setattr(world, "backend", None)),
    ):
        if name == "snapshot":
            snapshot = None
        release()
        now = settle()
        parts.append((name, before - now))
        before = now
    world = result = source = None
    parts.append(("rest (source, truth, run)", before - settle()))

    kb = 1024 / n
    console.print(
        f"{n:,} plants: {start:.0f} MB before the run, peak {peak_run:.0f} MB while mapping, "
        f"{mapped:.0f} MB held after it"
    )
    table = Table(title="mapping state held after the run")
    for column in ("part", "MB", "KB / plant"):
        table.add_column(column, justify="right")
    for name, mb in parts:
        table.add_row(name, f"{mb:.1f}", f"{mb * kb:.2f}")
    console.print(table)
    table = Table(title="output writers (each alone; peak above what was held before it)")
    for column in ("output", "peak RSS rise MB", "KB / plant", "Python peak MB"):
        table.add_column(column, justify="right")
    for name, rss, py in rows:
        table.add_row(name, f"{rss:.1f}", f"{rss * kb:.2f}", f"{py:.1f}")
    console.print(table)


if __name__ == "__main__":
    main()
