"""The fuzzing target for hostile input: at least 10,000 mutated survey logs through the
whole lenient pipeline (read, map, write every output), with zero uncaught exceptions and
zero runs without outputs.

Each run takes a small simulated survey (30 plants, about 230 lines), changes one field or
one line of it (tests/log_mutations.py: numbers to NaN, inf, huge, strings, negative;
covariances zero, indefinite, asymmetric; fields deleted or of another type; lines cut,
garbage, nested, duplicated, swapped, not UTF-8...), runs `run_survey` on it in lenient
mode into a fresh folder and sorts the outcome:

- outputs: the run ended with its outputs (objects.csv, trajectory.csv, map.sqlite,
  metrics.json at least);
- stopped at a bad meta: a clear LogError at the meta line, which lenient mode does not
  skip (the meta line is the survey's contract), and nothing written;
- uncaught: any other exception (a bug), with the mutation to replay it;
- no outputs: a run that ended without raising and without its outputs (a bug).

Then it prints the skipped lines by reason over all runs. report.png, the dearest output of
a small run, is drawn in every `--report-every`-th run (default 10); the other runs write a
placeholder in its place.

    python benchmarks/fuzz_logs.py [--runs 10000] [--workers 2] [--seed 1] [--report-every 10]
"""

from __future__ import annotations

import argparse
import io
import json
import random
import sys
import tempfile
import time
import traceback
from collections import Counter
from multiprocessing import Pool
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the mutations the fuzz tests use

import agrislam.run.pipeline as pipeline  # noqa: E402
from agrislam.io.sinks.jsonl import record_to_json  # noqa: E402
from agrislam.io.sources.jsonl import LogError, read_log  # noqa: E402
from agrislam.run.pipeline import RunError, run_survey  # noqa: E402
from agrislam.sim.config import SimConfig  # noqa: E402
from agrislam.sim.simulator import Simulator  # noqa: E402
from agrislam.world import WorldModel  # noqa: E402
from log_mutations import N_KINDS, as_log, mutate  # noqa: E402

REQUIRED = {"objects.csv", "trajectory.csv", "map.sqlite", "metrics.json"}
LINES: list[str] = []
DRAW = {"every": 10, "report": pipeline.write_report}


def _survey(seed: int) -> list[str]:
    cfg = SimConfig.model_validate({"field": {"n_plants": 30, "n_rows": 3}, "seed": seed})
    return [json.dumps(record_to_json(r)) for r in Simulator(cfg).records()]


def _init(seed: int, report_every: int) -> None:
    LINES[:] = _survey(seed)
    DRAW["every"] = report_every


def _placeholder(snapshot: Any, path: Path, **kwargs: Any) -> Path:
    Path(path).write_bytes(b"report.png not drawn in this fuzzing run\n")
    return Path(path)


def run_one(job: tuple[int, tuple[int, int, int]]) -> dict[str, Any]:
    """One mutated log through the lenient pipeline: its outcome and skips by reason."""
    k, change = job
    pipeline.write_report = DRAW["report"] if k % DRAW["every"] == 0 else _placeholder
    data = as_log(mutate(LINES, *change))
    reader = read_log(io.BytesIO(data), strict=False)
    with tempfile.TemporaryDirectory(prefix="agrislam-fuzz-") as folder:
        try:
            result = run_survey(reader, WorldModel(), Path(folder) / "run")
        except RunError as err:
            cause = err.__cause__
            if isinstance(cause, LogError) and cause.fatal:
                return {"outcome": "stopped at a bad meta", "skipped": {}}
            return _uncaught(change, cause or err)
        except Exception as err:
            return _uncaught(change, err)
        written = {p.name for p in result.outputs}
    outcome = "outputs" if written >= REQUIRED and not result.output_errors else "no outputs"
    return {"outcome": outcome, "skipped": dict(reader.report.skipped), "change": change}


def _uncaught(change: tuple[int, int, int], err: BaseException) -> dict[str, Any]:
    trace = "".join(traceback.format_exception(err)[-3:])
    return {"outcome": "uncaught", "skipped": {}, "change": change, "error": trace}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10_000)
    parser.add_argument("--workers", type=int, default=2, help="at most 2 on a shared machine")
    parser.add_argument("--seed", type=int, default=1, help="of the mutations")
    parser.add_argument("--report-every", type=int, default=10, help="draw report.png every n")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    lines = _survey(2)
    changes = [
        (rng.randrange(len(lines)), rng.randrange(10_000), rng.randrange(N_KINDS))
        for _ in range(args.runs)
    ]
    outcomes: Counter[str] = Counter()
    skipped: Counter[str] = Counter()
    bugs: list[dict[str, Any]] = []
    start = time.perf_counter()
    jobs = list(enumerate(changes))
    workers = min(args.workers, 2)
    with Pool(workers, initializer=_init, initargs=(2, args.report_every)) as pool:
        for k, got in enumerate(pool.imap_unordered(run_one, jobs, chunksize=8), start=1):
            outcomes[got["outcome"]] += 1
            skipped.update(got["skipped"])
            if got["outcome"] in ("uncaught", "no outputs"):
                bugs.append(got)
                print(f"  {got['outcome']}: mutate(lines, *{got['change']})", flush=True)
            if k % 250 == 0:  # a run cut short still says how far it got, and how
                tally = ", ".join(f"{o} {n}" for o, n in sorted(outcomes.items()))
                print(f"  {k} runs, {time.perf_counter() - start:.0f} s: {tally}", flush=True)
    wall = time.perf_counter() - start
    print(f"{args.runs} mutated 30-plant logs ({len(lines)} lines each) through the lenient")
    print(
        f"pipeline with every output (report.png drawn in every {args.report_every}th run), "
        f"{workers} workers, {wall:.0f} s:"
    )
    for outcome in ("outputs", "stopped at a bad meta", "uncaught", "no outputs"):
        print(f"  {outcome:<24} {outcomes[outcome]:>6}")
    print("lines skipped, by reason (over all runs):")
    for reason, n in skipped.most_common():
        print(f"  {reason:<24} {n:>6}")
    for bug in bugs[:10]:
        print(f"\n{bug['outcome']}: mutate(lines, *{bug['change']})\n{bug.get('error', '')}")
    return 1 if bugs else 0


if __name__ == "__main__":
    sys.exit(main())
