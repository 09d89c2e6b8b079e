"""Checkpoints and `--resume` against their targets, with the real CLI.

A 2,000-plant survey (`sim:?plants=2000`) is recorded to a JSONL log with
`agrislam simulate --record`; then, each `agrislam run LOG` in its own process:

- the uninterrupted run with the default config (checkpoints at least every
  `checkpoint.every_frames` frames, further apart as the state grows): the reference map;
- the same run without checkpoints (`checkpoint.every_frames: 0`), interleaved with it
  `--repeats` times (the best of each), the baseline of the
  overhead: wall time with and without, beside the time the run itself spent in
  checkpoints (metrics.json), which does not depend on what else the machine is doing;
- `--kills` runs killed with SIGKILL at random moments (seeded) of the reference's wall
  time, each then resumed with `--resume`: the killed run's map.sqlite must pass
  `PRAGMA integrity_check`, and the resumed run's final map must equal the reference
  (same ids, positions within 1e-6 m).

Targets: every resumed map equal to the reference; checkpoints at most 5 % of the wall time.

    nice python benchmarks/bench_resume.py [--plants 2000] [--kills 10] [--seed 7] [--repeats 2]
                                           [--workdir /tmp/bench_resume]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from agrislam.config import AgrislamConfig
from agrislam.io.sinks.sqlite import load_map

TOLERANCE_M = 1e-6
OVERHEAD_TARGET = 0.05
AGRISLAM = [sys.executable, "-c", "from agrislam.cli import app; app()"]


def agrislam(*args: str) -> float:
    """Run the CLI to its end; its wall time."""
    start = time.perf_counter()
    subprocess.run([*AGRISLAM, *args], check=True, capture_output=True)
    return time.perf_counter() - start


def killed(args: list[str], after: float) -> bool:
    """Start the CLI and SIGKILL it `after` seconds in; False if it ended before."""
    proc = subprocess.Popen(
        [*AGRISLAM, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        proc.wait(timeout=after)
        return False
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        return True


def integrity(path: Path) -> str:
    if not path.exists():
        return "no map.sqlite yet"
    with sqlite3.connect(path) as db:
        ok = db.execute("PRAGMA integrity_check").fetchone()[0]
        tables = {n for (n,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        position = None
        if "checkpoint" in tables:
            row = db.execute("SELECT value FROM checkpoint WHERE key = 'position'").fetchone()
            position = None if row is None else int(bytes(row[0]))
    return f"{ok}, checkpoint at record {position}" if ok == "ok" else f"CORRUPT: {ok}"


def difference(reference: Path, other: Path) -> tuple[bool, float]:
    """(same ids, largest position difference in m) of two map.sqlite files."""
    a, b = load_map(reference).objects, load_map(other).objects
    if not np.array_equal(a.ids, b.ids):
        return False, float("inf")
    return True, float(np.abs(a.xy - b.xy).max(initial=0.0))


def checkpoint_seconds(out: Path) -> tuple[float, float, int]:
    run = json.loads((out / "metrics.json").read_text())["run"]
    ck = run.get("checkpoints") or {}
    return run["wall_seconds"], ck.get("seconds", 0.0), ck.get("taken", 0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=2000)
    parser.add_argument("--kills", type=int, default=10)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--repeats", type=int, default=2, help="runs with and without")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/bench_resume"))
    args = parser.parse_args()
    work = args.workdir
    work.mkdir(parents=True, exist_ok=True)
    log = work / f"survey_{args.plants}.jsonl"
    if not log.exists():
        agrislam("simulate", "--plants", str(args.plants), "--record", str(log),
                 "--out", str(work / "simulated"), "--force")  # fmt: skip
    no_checkpoints = work / "no_checkpoints.json"
    no_checkpoints.write_text(json.dumps({"checkpoint": {"every_frames": 0}}))

    reference, baseline = work / "reference", work / "baseline"
    walls: dict[str, list[float]] = {"with": [], "without": []}
    runs: dict[str, list[float]] = {"with": [], "without": []}
    for _ in range(args.repeats):  # interleaved: the machine's load falls on both alike
        walls["with"].append(agrislam("run", str(log), "--out", str(reference), "--force"))
        runs["with"].append(checkpoint_seconds(reference)[0])
        walls["without"].append(
            agrislam("run", str(log), "--out", str(baseline), "-c", str(no_checkpoints), "--force")
        )
        runs["without"].append(checkpoint_seconds(baseline)[0])
    wall_with, wall_without = min(walls["with"]), min(walls["without"])
    run_with, run_without = min(runs["with"]), min(runs["without"])
    _, spent, taken = checkpoint_seconds(reference)
    same, moved = difference(baseline / "map.sqlite", reference / "map.sqlite")
    print(f"survey: {log} ({log.stat().st_size / 1e6:.1f} MB), {args.plants} plants")
    print(f"best of {args.repeats}, interleaved:")
    print(f"uninterrupted, with checkpoints:    process {wall_with:6.1f} s, mapping "
          f"{run_with:6.1f} s, {taken} checkpoints taking {spent:.2f} s")  # fmt: skip
    print(f"uninterrupted, without checkpoints: process {wall_without:6.1f} s, mapping "
          f"{run_without:6.1f} s")  # fmt: skip
    share = spent / checkpoint_seconds(reference)[0]
    print(f"checkpoint overhead: {share:.1%} of the run's mapping time (in-run), "
          f"{run_with / run_without - 1:+.1%} mapping time with against without, "
          f"{wall_with / wall_without - 1:+.1%} process wall time; target <= 5 %")  # fmt: skip
    print(f"map with against without checkpoints: same ids {same}, positions differ by "
          f"{moved:.2e} m (a checkpoint rebuilds iSAM2; see agrislam/checkpoint.py)")  # fmt: skip
    first = AgrislamConfig().checkpoint.every_frames  # frames before the first checkpoint
    steps = [sum(load_map(f / "map.sqlite").step_times.values()) for f in (reference, baseline)]
    before, after = (steps[0][part].sum() / steps[1][part].sum() for part in (
        slice(0, first), slice(first, None)))  # fmt: skip
    print(f"step time with / without checkpoints, last runs: {before:.2f} before the first "
          f"checkpoint (the same work: the machine's load), {after:.2f} after it")  # fmt: skip
    for name, folder in (("with", reference), ("without", baseline)):
        times = load_map(folder / "map.sqlite").step_times
        stages = ", ".join(f"{k} {v.sum():.1f}" for k, v in times.items() if v.sum() > 1.0)
        print(f"step time (s) {name} checkpoints, last run: {stages}")

    rng = np.random.default_rng(args.seed)
    moments = np.sort(rng.uniform(1.0, wall_with, args.kills))
    equal = 0
    print(f"\n{'kill at':>8}  {'killed map.sqlite':<36} {'resume':>8}  same ids  max |dxy|")
    for n, moment in enumerate(moments.tolist()):
        out = work / f"killed_{n}"
        run_args = ["run", str(log), "--out", str(out)]
        for leftover in out.glob("*") if out.exists() else []:
            leftover.unlink()
        was_killed = killed(run_args, moment)
        state = integrity(out / "map.sqlite") if was_killed else "finished before the kill"
        took = agrislam(*run_args, "--resume") if was_killed else 0.0
        same, moved = difference(reference / "map.sqlite", out / "map.sqlite")
        good = same and moved <= TOLERANCE_M
        equal += good
        print(f"{moment:7.1f}s  {state:<36} {took:7.1f}s  {same!s:<8}  {moved:.2e}"
              f"{'' if good else '  DIFFERENT'}")  # fmt: skip
    print(f"\nresumed maps equal to the uninterrupted one: {equal}/{len(moments)} "
          f"(target {len(moments)}/{len(moments)}, within {TOLERANCE_M:g} m); "
          f"checkpoint overhead {share:.1%} (target <= {OVERHEAD_TARGET:.0%})")  # fmt: skip


if __name__ == "__main__":
    main()
