"""The fuzzing target for hostile input: at least 10,000 changed survey logs through the
whole lenient pipeline (read, map, write every output), with zero uncaught exceptions, zero
runs without outputs, none over 10x the clean run's time, and under 1 % of the runs mapping
less than 0.9 of what the clean log maps.

Each run takes a small simulated survey with truth (30 plants in 3 rows, about 230 lines:
one robot, seeds 2 and 3, or two robots with GNSS, seeds 2 and 3), makes one change to it
and runs `run_survey` on it in lenient mode into a fresh folder. A change is, by
`--operators` share, one plausible bad message (tests/log_mutations.py `OPERATORS`: a
re-sent odometry record, a jump of 2 m, 5 km or 1,000 rad, every covariance overconfident,
a robot renamed, no meta, a wrong row angle, GNSS fixes far off, a detection 9,000 km off;
the GNSS ones on the two-robot surveys), else an edit of one field or one line
(`mutate`: numbers to NaN, inf, huge, strings; covariances zero, indefinite; fields
deleted or of another type; lines cut, garbage, duplicated, swapped, not UTF-8...).
The outcome:

- outputs: the run ended with its outputs (objects.csv, trajectory.csv, map.sqlite,
  metrics.json at least); its mapped fraction (metrics.json `objects.mapped_fraction`) is
  compared with the clean run's of its survey, and its wall time too;
- stopped at a bad meta: a clear LogError at the meta line, which lenient mode does not
  skip (the meta line is the survey's contract), and nothing written;
- uncaught: any other exception (a bug), with the change to replay it;
- no outputs: a run that ended without raising and without its outputs (a bug);
- too slow: stopped past `--timeout` times the clean run's time (a bug).

Then it prints the skipped lines by reason over all runs, and per operator (edits by
class) the runs, their mean mapped fraction against the clean run's, the share below 0.9
of it, the worst, and the slowest run against the clean one. report.png, the dearest
output of a small run, is drawn in every `--report-every`-th run (default 10); the other
runs write a placeholder in its place.

    python benchmarks/fuzz_logs.py [--runs 10000] [--workers 2] [--seed 1] [--report-every 10]
                                   [--operators 0.5] [--timeout 10]
"""

from __future__ import annotations

import argparse
import io
import math
import random
import signal
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from multiprocessing import Pool
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the mutations the fuzz tests use

import agrislam.run.pipeline as pipeline  # noqa: E402
from agrislam.io.sources.jsonl import LogError, read_log  # noqa: E402
from agrislam.run.pipeline import RunError, RunResult, run_survey  # noqa: E402
from agrislam.world import WorldModel  # noqa: E402
from log_mutations import (  # noqa: E402
    N_KINDS,
    NEEDS_GNSS,
    OPERATORS,
    as_log,
    kind_name,
    mutate,
    operate,
    survey_lines,
)

REQUIRED = {"objects.csv", "trajectory.csv", "map.sqlite", "metrics.json"}
SMALL = {"field": {"n_plants": 30, "n_rows": 3}}
SURVEYS = {  # name -> simulator config; the GNSS operators take the "gnss" ones
    "one robot, seed 2": {**SMALL, "seed": 2},
    "one robot, seed 3": {**SMALL, "seed": 3},
    "two robots, gnss, seed 2": {**SMALL, "seed": 2, "path": {"n_robots": 2}, "gnss": {}},
    "two robots, gnss, seed 3": {**SMALL, "seed": 3, "path": {"n_robots": 2}, "gnss": {}},
}
FAIR = 0.9  # of the clean run's mapped fraction: below, the change wrecked the map
TARGET = 0.01  # the share of runs below FAIR the issue allows
SLOW = 10.0  # times the clean run's wall time
LINES: dict[str, list[str]] = {}
DRAW = {"every": 10, "report": pipeline.write_report, "timeout": {}}

Change = tuple[str, str, Any]  # survey, "edit" or an operator's name, (line, field, kind) or seed


class TooSlow(KeyboardInterrupt):
    """A run past its time: stops it as Ctrl-C would (the map so far is written)."""


def _stop(signum: int, frame: Any) -> None:
    raise TooSlow


def _init(report_every: int, timeout: dict[str, float]) -> None:
    LINES.update({name: survey_lines(config) for name, config in SURVEYS.items()})
    DRAW.update(every=report_every, timeout=timeout)
    signal.signal(signal.SIGALRM, _stop)


def _placeholder(snapshot: Any, path: Path, **kwargs: Any) -> Path:
    Path(path).write_bytes(b"report.png not drawn in this fuzzing run\n")
    return Path(path)


def _changed(change: Change) -> bytes:
    survey, what, how = change
    lines = LINES[survey]
    return as_log(mutate(lines, *how) if what == "edit" else operate(lines, what, how))


def _run(data: bytes) -> tuple[RunResult, dict[str, int]]:
    reader = read_log(io.BytesIO(data), strict=False)
    with tempfile.TemporaryDirectory(prefix="agrislam-fuzz-") as folder:
        return run_survey(reader, WorldModel(), Path(folder) / "run"), dict(reader.report.skipped)


def run_one(job: tuple[int, Change]) -> dict[str, Any]:
    """One changed log through the lenient pipeline: its outcome, skips by reason, mapped
    fraction and wall time."""
    k, change = job
    drawn = k % DRAW["every"] == 0
    pipeline.write_report = DRAW["report"] if drawn else _placeholder
    got: dict[str, Any] = {"change": change, "skipped": {}, "drawn": drawn}
    start, error = time.perf_counter(), None
    signal.setitimer(signal.ITIMER_REAL, DRAW["timeout"][change[0]])
    try:
        result, got["skipped"] = _run(_changed(change))
    except BaseException as err:
        error = err
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
    got["seconds"] = time.perf_counter() - start
    if error is not None:
        return {**got, **_failure(error)}
    written = {p.name for p in result.outputs}
    complete = written >= REQUIRED and not result.output_errors
    got["outcome"] = "outputs" if complete else "no outputs"
    got["mapped"] = ((result.metrics or {}).get("objects") or {}).get("mapped_fraction")
    return got


def _failure(err: BaseException) -> dict[str, Any]:
    """The outcome of a run that raised `err`."""
    if isinstance(err, RunError) and err.__cause__ is not None:
        err = err.__cause__
    if isinstance(err, LogError) and err.fatal:
        return {"outcome": "stopped at a bad meta"}
    if isinstance(err, TooSlow):
        return {"outcome": "too slow"}
    return {"outcome": "uncaught", "error": "".join(traceback.format_exception(err)[-3:])}


def clean_runs() -> dict[str, dict[str, float]]:
    """Each survey's clean run: its mapped fraction and wall time (report.png not drawn)."""
    pipeline.write_report = _placeholder
    clean = {}
    for name, config in SURVEYS.items():
        start = time.perf_counter()
        result, _ = _run(as_log([line.encode() for line in survey_lines(config)]))
        clean[name] = {
            "mapped": result.metrics["objects"]["mapped_fraction"],
            "seconds": time.perf_counter() - start,
        }
    pipeline.write_report = DRAW["report"]
    return clean


def changes(n: int, share: float, seed: int) -> list[Change]:
    """`n` changes: an operator by `share` (each as likely; the GNSS ones on surveys with
    GNSS), else an edit of one field or line."""
    rng = random.Random(seed)
    gnss = [name for name, config in SURVEYS.items() if "gnss" in config]
    lengths = {name: len(survey_lines(config)) for name, config in SURVEYS.items()}
    out: list[Change] = []
    for _ in range(n):
        if rng.random() < share:
            operator = rng.choice(sorted(OPERATORS))
            survey = rng.choice(gnss if operator in NEEDS_GNSS else sorted(SURVEYS))
            out.append((survey, operator, rng.randrange(10_000)))
        else:
            survey = rng.choice(sorted(SURVEYS))
            edit = (rng.randrange(lengths[survey]), rng.randrange(10_000), rng.randrange(N_KINDS))
            out.append((survey, "edit", edit))
    return out


def operator_of(change: Change) -> str:
    _, what, how = change
    return kind_name(how[2]) if what == "edit" else what


def replay(change: Change) -> str:
    survey, what, how = change
    if what == "edit":
        return f"mutate(survey_lines(SURVEYS[{survey!r}]), *{how})"
    return f"operate(survey_lines(SURVEYS[{survey!r}]), {what!r}, {how})"


def mapped_table(results: list[dict[str, Any]], clean: dict[str, dict[str, float]]) -> bool:
    """Per change (operators by name, edits by class): runs, runs that did not end with
    their outputs, the mean mapped fraction against the clean run's, the share below FAIR,
    the worst, and the slowest run (report.png not drawn) against the clean run; then the
    share below FAIR over all scored runs, against TARGET. Returns whether it is within."""
    runs: Counter[str] = Counter()
    failed: Counter[str] = Counter()
    ratios: dict[str, list[float]] = defaultdict(list)
    slowest: dict[str, float] = {}
    for got in results:
        survey, change = got["change"][0], operator_of(got["change"])
        runs[change] += 1
        if not got["drawn"]:
            ratio = got["seconds"] / clean[survey]["seconds"]
            slowest[change] = max(slowest.get(change, 0.0), ratio)
        if got["outcome"] != "outputs":
            failed[change] += got["outcome"] != "stopped at a bad meta"
        elif got.get("mapped") is not None:
            ratios[change].append(got["mapped"] / clean[survey]["mapped"])
    below = {c: sum(r < FAIR for r in ratios[c]) / max(len(ratios[c]), 1) for c in runs}
    print(f"mapped fraction against the clean run's, by change (below {FAIR}: wrecked):")
    head = f"{'runs':>5} {'failed':>6} {'mean':>5} {'below':>6} {'worst':>5} {'slowest':>7}"
    print(f"  {'change':<38} {head}")
    for change in sorted(runs, key=lambda c: (-below[c], -failed[c], c)):
        got = ratios[change]
        mean, worst = (sum(got) / len(got), min(got)) if got else (math.nan, math.nan)
        slow = f"{slowest[change]:.1f}x" if change in slowest else "-"  # all drawn
        print(
            f"  {change:<38} {runs[change]:>5} {failed[change]:>6} {mean:>5.2f} "
            f"{below[change]:>6.0%} {worst:>5.2f} {slow:>7}"
        )
    scored = sum(len(got) for got in ratios.values())
    wrecked = sum(r < FAIR for got in ratios.values() for r in got)
    print(
        f"runs below {FAIR} of the clean run's mapped fraction: {wrecked} of {scored} "
        f"({wrecked / max(scored, 1):.1%}; target under {TARGET:.0%})"
    )
    worst = [f"{c} ({below[c]:.0%})" for c in sorted(runs, key=lambda c: -below[c]) if below[c]]
    print(f"worst changes: {', '.join(worst[:5]) or 'none'}")
    return wrecked <= TARGET * scored


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10_000)
    parser.add_argument("--workers", type=int, default=2, help="at most 2 on a shared machine")
    parser.add_argument("--seed", type=int, default=1, help="of the changes")
    parser.add_argument("--report-every", type=int, default=10, help="draw report.png every n")
    parser.add_argument("--operators", type=float, default=0.5, help="share of runs with one")
    parser.add_argument(
        "--timeout", type=float, default=SLOW, help="stop a run past this x the clean run's time"
    )
    args = parser.parse_args()
    clean = clean_runs()
    for name, run in clean.items():
        print(f"clean {name}: mapped {run['mapped']:.2f}, {run['seconds']:.1f} s")
    # two workers share the machine the clean runs had alone: a floor of 30 s
    timeout = {name: max(args.timeout * run["seconds"], 30.0) for name, run in clean.items()}
    jobs = list(enumerate(changes(args.runs, args.operators, args.seed)))
    outcomes: Counter[str] = Counter()
    skipped: Counter[str] = Counter()
    results, bugs = [], []
    start = time.perf_counter()
    workers = min(args.workers, 2)
    with Pool(workers, initializer=_init, initargs=(args.report_every, timeout)) as pool:
        for k, got in enumerate(pool.imap_unordered(run_one, jobs, chunksize=8), start=1):
            outcomes[got["outcome"]] += 1
            skipped.update(got["skipped"])
            results.append(got)
            if got["outcome"] in ("uncaught", "no outputs", "too slow"):
                bugs.append(got)
                print(f"  {got['outcome']}: {replay(got['change'])}", flush=True)
            if k % 250 == 0:  # a run cut short still says how far it got, and how
                tally = ", ".join(f"{o} {n}" for o, n in sorted(outcomes.items()))
                print(f"  {k} runs, {time.perf_counter() - start:.0f} s: {tally}", flush=True)
    wall = time.perf_counter() - start
    print(f"{args.runs} changed 30-plant logs through the lenient pipeline with every output")
    every = f"report.png drawn in every {args.report_every}th run"
    print(f"({every}), {workers} workers, {wall:.0f} s:")
    for outcome in ("outputs", "stopped at a bad meta", "uncaught", "no outputs", "too slow"):
        print(f"  {outcome:<24} {outcomes[outcome]:>6}")
    print("lines skipped, by reason (over all runs):")
    for reason, n in skipped.most_common():
        print(f"  {reason:<24} {n:>6}")
    within_target = mapped_table(results, clean)
    for bug in bugs[:10]:
        print(f"\n{bug['outcome']}: {replay(bug['change'])}\n{bug.get('error', '')}")
    return 0 if within_target and not bugs else 1


if __name__ == "__main__":
    sys.exit(main())
