"""Whole fields in bounded memory: max RSS, memory per plant, step times and wall time
against survey time, from 400 to 10,000 plants (100,000 with --huge).

Each survey runs in a child process of its own (the simulator as the source, the whole
pipeline with every output written to a temporary folder), which reports its own peak
resident set size, so one survey's memory never counts for another. A 40-plant child gives
the interpreter's and libraries' baseline; the slope per plant between the two largest
sizes extrapolates to 1,000,000 plants. The machine's speed drifts over the time the
largest size takes, so the smallest size also runs before and after it and over and over
beside it (on the other core): the step ratio the target is judged on is against its runs
beside the largest, at the same moments of the machine. Every child does its linear
algebra on one thread. Accuracy is the simulator's truth: the trajectory's RMS against dead
reckoning's (no GNSS: a large field bends along its rows, which rigid alignment cannot take
out) and the association's purity.

    python benchmarks/bench_scale.py [--sizes 400 10000] [--huge] [--seed 2]
                                     [--baseline-src ../other-checkout/src]
                                     [--set '{"slam": {"keyframes_kept": 0}}']

`--baseline-src` runs the same surveys with another checkout's code beside this one's;
`--set` changes the configuration of both (the title then says it is not the default)."""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from inspect import signature
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
BASELINE_PLANTS = 40
TARGET_PLANTS = 1_000_000
console = Console(width=170)


def child(plants: int, seed: int, changes: dict[str, Any]) -> dict[str, Any]:
    """One survey, run here: the figures the parent prints (in a child process)."""
    from agrislam.config import AgrislamConfig
    from agrislam.io.sources import open_source
    from agrislam.io.sources.simulated import simulation_uri
    from agrislam.run.pipeline import run_survey
    from agrislam.world import WorldModel

    config = AgrislamConfig.model_validate(changes)
    source = open_source(simulation_uri(plants=plants, seed=seed), config)
    # as the CLI runs it: the world lets its state go before the outputs (a checkout from
    # before release_world has no such choice)
    cli = {"release_world": True} if "release_world" in signature(run_survey).parameters else {}
    with tempfile.TemporaryDirectory() as out:
        result = run_survey(source, WorldModel(config), out, **cli)
    steps = result.snapshot.step_seconds() if result.snapshot is not None else np.zeros(0)
    times = [t.t for t in result.snapshot.trajectories.values()]
    survey = max((float(t[-1] - t[0]) for t in times if len(t)), default=0.0)
    return {
        "plants": plants,
        "mapped": len(result.snapshot.objects) if result.snapshot is not None else 0,
        "frames": result.n_frames,
        "wall": result.wall_seconds,
        "survey": survey,
        "steps_ms": (steps * 1e3).tolist(),
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        **accuracy(result.metrics or {}),
    }


def accuracy(metrics: dict[str, Any]) -> dict[str, float]:
    """Trajectory RMS (optimised, dead reckoning) and purity from a run's metrics (NaN
    where the run has none)."""
    trajectory = metrics.get("trajectory", {})
    return {
        "trajectory_m": trajectory.get("optimised", {}).get("rms_position", float("nan")),
        "dead_reckoning_m": trajectory.get("dead_reckoning", {}).get("rms_position", float("nan")),
        "purity": metrics.get("association", {}).get("purity", float("nan")),
    }


def child_command(plants: int, seed: int, src: Path, changes: dict[str, Any]) -> dict[str, Any]:
    """The arguments of subprocess.run / Popen for a child surveying `plants` with `src`
    on its path, its linear algebra on one thread (so that two children share the two
    cores evenly)."""
    threads = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    command = [sys.executable, __file__, "--child", str(plants), "--seed", str(seed)]
    command += ["--set", json.dumps(changes)]
    return {"args": command, "env": {**os.environ, **threads, "PYTHONPATH": str(src)}}


def measure(plants: int, seed: int, src: Path, changes: dict[str, Any]) -> dict[str, Any]:
    """The survey in a child process with `src` on its path; its figures."""
    start = time.perf_counter()
    done = subprocess.run(
        **child_command(plants, seed, src, changes), capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"{plants} plants with {src}: {done.stderr.strip()[-2000:]}")
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    figures["process_seconds"] = time.perf_counter() - start
    return figures


def measure_beside(
    plants: int, small: int, seed: int, src: Path, changes: dict[str, Any]
) -> tuple[dict[str, Any], np.ndarray]:
    """The survey of `plants`, with the survey of `small` plants run over and over beside
    it until it ends: its figures, and the step times (ms) of the small surveys that
    finished meanwhile, taken at the same moments of the machine."""
    with tempfile.TemporaryFile("w+") as lines:
        command = child_command(small, seed, src, changes)
        command["args"].append("--repeat")
        beside = subprocess.Popen(**command, stdout=lines, stderr=subprocess.DEVNULL, text=True)
        try:
            figures = measure(plants, seed, src, changes)
        finally:
            beside.terminate()
            beside.wait()
        lines.seek(0)
        rounds = [json.loads(line)["steps_ms"] for line in lines if line.startswith("{")]
    if not rounds:
        raise RuntimeError(f"no {small}-plant survey finished beside the {plants:,}-plant one")
    return figures, np.concatenate(rounds)


def slope_mb_per_plant(rows: list[dict[str, Any]], base_mb: float) -> float:
    """MB per plant between the two largest sizes (the baseline and the smallest size
    when only one was measured): what each further plant costs."""
    points = [(BASELINE_PLANTS, base_mb)] + [(r["plants"], r["max_rss_mb"]) for r in rows]
    (n0, m0), (n1, m1) = points[-2:]
    return (m1 - m0) / (n1 - n0)


def table(name: str, rows: list[dict[str, Any]], base_mb: float) -> Table:
    out = Table(title=f"{name}: baseline ({BASELINE_PLANTS} plants) {base_mb:.0f} MB max RSS")
    for column in (
        "plants",
        "frames",
        "max RSS MB",
        "KB / plant above base",
        "step median / p95 / max ms",
        "steps > 100 ms",
        "wall s",
        "survey s",
        "survey / wall",
        "frames at 1 fps / wall",
        "trajectory / DR m",
        "purity",
    ):
        out.add_column(column, justify="right")
    for r in rows:
        ms = np.asarray(r["steps_ms"])
        per_plant = (r["max_rss_mb"] - base_mb) * 1024 / r["plants"]
        out.add_row(
            f"{r['plants']:,}",
            f"{r['frames']:,}",
            f"{r['max_rss_mb']:.0f}",
            f"{per_plant:.1f}",
            f"{np.median(ms):.1f} / {np.percentile(ms, 95):.1f} / {ms.max():.0f}",
            str(int((ms > 100).sum())),
            f"{r['wall']:.0f}",
            f"{r['survey']:.0f}",
            f"{r['survey'] / max(r['wall'], 1e-9):.0f}x",
            f"{r['frames'] / max(r['wall'], 1e-9):.0f}x",
            f"{r['trajectory_m']:.3f} / {r['dead_reckoning_m']:.2f}",
            f"{r['purity']:.3f}",
        )
    return out


def step_ratios(large: np.ndarray, small: np.ndarray) -> tuple[float, float]:
    """Median and p95 step of `large` over those of `small`."""
    return tuple(float(f(large) / f(small)) for f in (np.median, lambda ms: np.percentile(ms, 95)))


def report(name: str, src: Path, sizes: list[int], seed: int, changes: dict[str, Any]) -> None:
    base = measure(BASELINE_PLANTS, seed, src, changes)["max_rss_mb"]
    rows, beside = [measure(sizes[0], seed, src, changes)], None
    for plants in sizes[1:]:
        row, beside = measure_beside(plants, sizes[0], seed, src, changes)
        rows.append(row)
        console.print(f"{name}: {plants:,} plants done in {row['process_seconds']:.0f} s")
    again = measure(sizes[0], seed, src, changes) if len(sizes) > 1 else None
    console.print(table(name, rows + ([again] if again else []), base))
    slope = slope_mb_per_plant(rows, base)
    largest = rows[-1]
    million = (largest["max_rss_mb"] + slope * (TARGET_PLANTS - largest["plants"])) / 1024
    large = np.asarray(largest["steps_ms"])
    smallest = np.concatenate([r["steps_ms"] for r in (rows[0], again) if r is not None])
    before_after = step_ratios(large, smallest)
    console.print(
        f"{name}: slope {slope * 1024:.2f} KB per plant between the largest sizes (target <= 4); "
        f"{TARGET_PLANTS:,} plants -> about {million:.1f} GB max RSS; "
        f"max step {max(max(r['steps_ms']) for r in rows):.0f} ms at any size (target <= 100)"
    )
    ratios = f"{before_after[0]:.2f}x / {before_after[1]:.2f}x against its runs before and after"
    if beside is not None:
        paired = step_ratios(large, beside)
        ratios += (
            f", {paired[0]:.2f}x / {paired[1]:.2f}x against its {beside.size:,} steps beside it "
            f"(median / p95 {np.median(beside):.1f} / {np.percentile(beside, 95):.1f} ms)"
        )
    console.print(
        f"{name}: step median / p95 at {largest['plants']:,} vs {rows[0]['plants']:,} plants "
        f"(target <= 1.5x): {ratios}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[400, 10_000])
    parser.add_argument(
        "--huge", action="store_true", help="also 100,000 plants (about 40 minutes here)"
    )
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--baseline-src", type=Path, help="another checkout's src folder")
    parser.add_argument(
        "--set", type=json.loads, default={}, metavar="JSON", help="config changes (both runs)"
    )
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--repeat", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        while True:  # --repeat: over and over beside a larger survey, until it ends
            print(json.dumps(child(args.child, args.seed, args.set)), flush=True)
            if not args.repeat:
                return
    sizes = sorted(set(args.sizes + ([100_000] if args.huge else [])))
    if args.set:
        console.print(f"NOT the default configuration: {json.dumps(args.set)}")
    report("this checkout", ROOT / "src", sizes, args.seed, args.set)
    if args.baseline_src is not None:
        src = args.baseline_src.resolve()
        report(f"baseline {args.baseline_src}", src, sizes, args.seed, args.set)


if __name__ == "__main__":
    main()
