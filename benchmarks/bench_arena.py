"""The arena scenario with the DEFAULT configuration, against its targets.

Five robots drive random paths for 15 minutes among 17 point landmarks (a triple and two
pairs 0.15-0.2 m apart) in a 15 m x 8 m arena, with 50 Hz drifting odometry whose heading
covariance is reported 4x too small and a range-bearing camera with 2 % gross range
outliers (`agrislam.sim.arena`). For each seed it prints one row per variant: agrislam's
default configuration and the paper's association (the K_n gate, sec. 2.4) pinned as the
baseline. The default config is the point: the real data this stands for will be mapped
without tuning.

    python benchmarks/bench_arena.py [--seeds 1 2 3] [--minutes 15] [--attribute] [--stages]
                                     [--set '{"slam": {"window": 0}}'] [--profile realistic]
                                     [--record LOG.jsonl]

`--profile realistic` simulates the arena as the real multi-robot log measured
(`ArenaConfig.realistic()`: its layout, drives, odometry and camera effects) instead of the
scenario's defaults; the targets stay the same. `--record` writes the first seed's
simulated log and stops (for `real_statistics.py --compare`).

Each seed's line also gives the association's ceiling: the purity and completeness of a
mapper that knew the true poses and landmarks and gave each frame's detections their
likeliest landmarks, one to one, by their geometry alone (`association_ceiling`). The
clusters' landmarks stand about a range sigma apart, so even it confuses some; a run is
judged against that too. With `--attribute` the barcodes tell more than the ceiling uses.

`--stages` prints each run's steps' p95 minute by minute with its dearest stages: where a
step-time drift comes from.

`--set` changes every variant the same way (to see past a failure of the default; such a
run is not the default configuration, and the title says so). A run that crashes is a row
too: where it stopped and why. With several seeds each variant gets a row of their means:
one seed's association swings by a few points with any small change, so judge on those.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.optimize import linear_sum_assignment

from agrislam.config import AgrislamConfig
from agrislam.config.loading import merged
from agrislam.evaluation.metrics import association_counts, evaluate
from agrislam.geometry.se2 import wrap_angle
from agrislam.io.sinks.jsonl import write_log
from agrislam.records import Detections, Record, TruthObject, TruthPose
from agrislam.run.pipeline import RunResult, run_survey
from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.config import ArenaConfig
from agrislam.sim.range_bearing import true_range_bearing
from agrislam.world import StepReport, WorldModel

VARIANTS: dict[str, dict[str, Any]] = {
    "agrislam": {},
    # the paper's association and noise as logged, pinned: the baseline when defaults change
    "paper's gate": {
        "advanced": {
            "association": {
                "innovation_gate": False,
                "gate_chi2": 1.0,
                "landmark_defaults": False,
            },
            "sensor": {"calibration": {"enabled": False}},
        }
    },
}
# a landmark counts as mapped if an object lies within this of it (one to one: the most
# pairs, then the least total distance): twice the RMS target; an object between the two
# landmarks of a pair maps only one of them. Unmatched objects within it of a landmark are
# duplicates, the others spurious
MATCH_RADIUS = 0.3
WINDOW_S = 60.0  # the first and the last minute, for the step-time drift
TARGETS = {
    "mapped": "all",
    "spurious": "<= 2",
    "duplicates": "-",
    "purity": ">= 0.95",
    "completeness": ">= 0.95",
    "landmark RMS": "<= 0.15 m",
    "trajectory": "opt <= DR / 3",
    "steps first minute": "-",
    "steps last minute": "p95 <= 1.5 x first",
    "wall": "-",
    "real time": ">= 10 x",
}
console = Console(width=240)


class ClockedWorld(WorldModel):
    """The world model noting each step's frame time (the step times come in step order)."""

    def __init__(self, config: AgrislamConfig) -> None:
        super().__init__(config)
        self.step_t: list[float] = []

    def step(self, frame: Detections) -> StepReport:
        self.step_t.append(frame.t)
        return super().step(frame)


@dataclass
class Score:
    """One run's figures against the arena's targets."""

    mapped: int
    n_truth: int
    spurious: int
    duplicates: int
    purity: float
    completeness: float
    landmark_rms: float
    traj_opt: float
    traj_dr: float
    first_ms: tuple[float, float]  # median, p95 of the steps in the first minute
    last_ms: tuple[float, float]  # the same in the last minute
    wall_s: float
    survey_s: float
    attribute: float | None  # accuracy of the mapped landmarks' attribute, if there is one
    noise: dict[str, float] | None = None  # the sigma factors the run estimated

    @property
    def real_time(self) -> float:
        return self.survey_s / self.wall_s

    def failures(self) -> list[str]:
        checks = {
            "mapped": self.mapped == self.n_truth,
            "spurious": self.spurious <= 2,
            "purity": self.purity >= 0.95,
            "completeness": self.completeness >= 0.95,
            "landmark RMS": self.landmark_rms <= 0.15,
            "trajectory": self.traj_opt <= self.traj_dr / 3,
            "step drift": self.last_ms[1] <= 1.5 * self.first_ms[1],
            "real time": self.real_time >= 10.0,
        }
        return [name for name, ok in checks.items() if not ok]


def _nan(x: float | None) -> float:
    return float("nan") if x is None else float(x)


def step_windows(world: ClockedWorld, steps_s: np.ndarray) -> tuple[tuple[float, float], ...]:
    """(median, p95) in ms of the steps whose frames fall in the first and the last minute."""
    t = np.asarray(world.step_t)
    ms = steps_s * 1e3
    out = []
    for inside in (t <= t.min() + WINDOW_S, t >= t.max() - WINDOW_S):
        x = ms[inside]
        out.append((float(np.median(x)), float(np.percentile(x, 95))) if len(x) else (np.nan,) * 2)
    return tuple(out)


def minute_stages(
    step_t: list[float], step_times: dict[str, np.ndarray], steps_s: np.ndarray, top: int = 4
) -> list[str]:
    """Per minute of the survey: the steps' p95 (ms; `steps_s`, each step's whole time) and
    the `top` stages' own p95 (where a drift comes from: `--stages`)."""
    t = np.asarray(step_t) - step_t[0]
    total = np.asarray(steps_s)
    lines = []
    for minute in range(int(t.max() // WINDOW_S) + 1):
        inside = (t >= minute * WINDOW_S) & (t < (minute + 1) * WINDOW_S)
        if not inside.any():
            continue
        p95 = {stage: 1e3 * np.percentile(s[inside], 95) for stage, s in step_times.items()}
        dearest = sorted(p95, key=p95.__getitem__, reverse=True)[:top]
        parts = ", ".join(f"{stage} {p95[stage]:.1f}" for stage in dearest)
        lines.append(
            f"minute {minute}: p95 {1e3 * np.percentile(total[inside], 95):.1f} ms ({parts})"
        )
    return lines


def association_ceiling(records: list[Record]) -> tuple[float, float]:
    """Purity and completeness of the association a mapper knowing the true poses and
    landmarks would make: each frame's range-bearing detections to the landmarks of least
    summed squared normalised error, one to one: the most likely joint choice, which a
    mapper deciding frame by frame on estimated poses and landmarks can hardly beat
    (landmarks a range sigma apart are confused by it too). Geometry alone: a landmark
    attribute (a barcode) is not used."""
    landmarks = {r.id: r.xy for r in records if isinstance(r, TruthObject)}
    number = {name: n for n, name in enumerate(landmarks)}
    xy = np.array(list(landmarks.values())).reshape(-1, 2)
    pose: dict[str, np.ndarray] = {}
    truths: list[int] = []
    chosen: list[int] = []
    for r in records:
        if isinstance(r, TruthPose):
            pose[r.robot] = r.pose
        elif isinstance(r, Detections) and r.objects:
            seen = [(d.range, d.bearing, d.sigma_range, d.sigma_bearing) for d in r.objects]
            rng, bearing, s_rng, s_bearing = np.array(seen, dtype=float).T[:, :, None]
            true_rng, true_bearing = true_range_bearing(pose[r.robot][None], xy)
            error = ((rng - true_rng) / s_rng) ** 2
            error += (wrap_angle(bearing - true_bearing) / s_bearing) ** 2
            rows, cols = linear_sum_assignment(error)
            best = np.argmin(error, axis=1)  # the likeliest, where landmarks run short
            best[rows] = cols
            chosen.extend(best.tolist())
            truths.extend(number.get(d.truth_id, -1) for d in r.objects)
    counts = association_counts(np.array(truths), np.array(chosen))
    return counts["purity"], counts["completeness"]


def score(result: RunResult, world: ClockedWorld, records: list[Record], survey_s: float) -> Score:
    truths = [r for r in records if isinstance(r, TruthObject)]
    poses = [r for r in records if isinstance(r, TruthPose)]
    m = evaluate(result.snapshot, truths, poses, radius=MATCH_RADIUS)
    o, tr = m["objects"], m["trajectory"]
    assoc = (result.metrics or {}).get("association", {})
    first, last = step_windows(world, result.snapshot.step_seconds())
    attribute = next((a.get("accuracy") for a in m["attributes"].values()), None)
    return Score(
        mapped=o["mapped"],
        n_truth=o["n_truth"],
        spurious=o["false_objects"],
        duplicates=o["duplicates"],
        purity=_nan(assoc.get("purity")),
        completeness=_nan(assoc.get("completeness")),
        landmark_rms=_nan(o["position_rms"]),
        traj_opt=_nan(tr["optimised"]["rms_position"]),
        traj_dr=_nan(tr["dead_reckoning"]["rms_position"]),
        first_ms=first,
        last_ms=last,
        wall_s=result.wall_seconds,
        survey_s=survey_s,
        attribute=attribute,
        noise=(result.noise or {}).get("sigma_factors"),
    )


def mean_score(scores: list[Score]) -> Score:
    """The seeds' mean of each figure (counts to 0.1): a change is judged on it, as one
    seed's association swings by a few points with any small change."""
    fields = {}
    for name in Score.__dataclass_fields__:
        values = [getattr(s, name) for s in scores]
        if name in ("first_ms", "last_ms"):
            fields[name] = tuple(np.mean(values, axis=0).tolist())
        elif name == "noise" or any(v is None for v in values):
            fields[name] = None
        else:
            fields[name] = round(float(np.mean(values)), 1 if isinstance(values[0], int) else 6)
    return Score(**fields)


def cells(name: str, seed: int | str, s: Score) -> list[str]:
    fails = s.failures()
    return [
        name,
        str(seed),
        f"{s.mapped:g} / {s.n_truth:g}",
        f"{s.spurious:g}",
        f"{s.duplicates:g}",
        f"{s.purity:.3f}",
        f"{s.completeness:.3f}",
        f"{s.landmark_rms:.3f}",
        f"{s.traj_opt:.3f} / {s.traj_dr:.3f}",
        f"{s.first_ms[0]:.1f} / {s.first_ms[1]:.1f}",
        f"{s.last_ms[0]:.1f} / {s.last_ms[1]:.1f}",
        f"{s.wall_s:.0f}",
        f"{s.real_time:.1f} x",
        "-" if s.attribute is None else f"{s.attribute:.1%}",
        ", ".join(fails) if fails else "none",
    ]


def crashed_cells(name: str, seed: int, t: float, steps: int, wall: float, why: str) -> list[str]:
    """A run that stopped: where (frame time, steps done) and why, in place of its figures."""
    row = [name, str(seed)] + ["-"] * (len(COLUMNS) - 2)
    row[COLUMNS.index(("wall s", TARGETS["wall"]))] = f"{wall:.0f}"
    row[-1] = f"CRASHED at t = {t:.1f} s (step {steps}): {why}"
    return row


COLUMNS = (
    ("variant", "-"),
    ("seed", "-"),
    ("mapped", TARGETS["mapped"]),
    ("spurious", TARGETS["spurious"]),
    ("dup.", TARGETS["duplicates"]),
    ("purity", TARGETS["purity"]),
    ("compl.", TARGETS["completeness"]),
    ("landmark RMS (m)", TARGETS["landmark RMS"]),
    ("traj RMS opt / DR (m)", TARGETS["trajectory"]),
    ("step ms 1st min p50/p95", TARGETS["steps first minute"]),
    ("step ms last min p50/p95", TARGETS["steps last minute"]),
    ("wall s", TARGETS["wall"]),
    ("real time", TARGETS["real time"]),
    ("attribute acc.", "-"),
    ("targets missed", "-"),
)


def run_variant(
    name: str, seed: int, cfg: AgrislamConfig, records: list[Record], survey_s: float
) -> tuple[Score | list[str], dict[str, int], list[str]]:
    """One run scored, or, if it crashed, the row saying where it stopped and why; its
    issues, and its steps' p95 minute by minute (`minute_stages`)."""
    world = ClockedWorld(cfg)
    start = time.perf_counter()
    try:
        result = run_survey(records, world)
    except Exception as err:  # a crash is a result too: say where, go on
        at = world.step_t[-1] if world.step_t else float("nan")
        reason = f"{type(err).__name__}: {str(err).strip().splitlines()[0]}"
        wall = time.perf_counter() - start
        return crashed_cells(name, seed, at, len(world.step_t), wall, reason), {}, []
    snapshot = result.snapshot
    minutes = minute_stages(world.step_t, snapshot.step_times, snapshot.step_seconds())
    return score(result, world, records, survey_s), result.issues, minutes


def simulate(
    seed: int, minutes: float, attribute: bool, profile: str = "default"
) -> tuple[list[Record], float]:
    changes = {
        "seed": seed,
        "driving": {"duration_s": 60.0 * minutes},
        "attribute": {"enabled": attribute},
    }
    if profile == "realistic":
        cfg = ArenaConfig.realistic(changes)
    else:
        cfg = ArenaConfig.model_validate(changes)
    start = time.perf_counter()
    records = list(ArenaSimulator(cfg).records())
    return records, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--minutes", type=float, default=15.0, help="survey length")
    parser.add_argument(
        "--profile",
        choices=["default", "realistic"],
        default="default",
        help="the arena's defaults, or as the real multi-robot log measured",
    )
    parser.add_argument(
        "--record", type=Path, metavar="LOG", help="write the first seed's log and stop"
    )
    parser.add_argument(
        "--attribute", action="store_true", help="landmarks carry a noisy barcode id"
    )
    parser.add_argument(
        "--stages", action="store_true", help="each run's step p95 minute by minute, by stage"
    )
    parser.add_argument(
        "--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS), metavar="NAME"
    )
    parser.add_argument(
        "--set",
        type=json.loads,
        default={},
        metavar="JSON",
        help="config changes applied to every variant (then not the default config)",
    )
    args = parser.parse_args()
    if args.record is not None:
        records, _ = simulate(args.seeds[0], args.minutes, args.attribute, args.profile)
        console.print(f"{write_log(records, args.record)} records written to {args.record}")
        return
    config = f"NOT the default config: {json.dumps(args.set)}" if args.set else "default config"
    table = Table(
        title=f"Arena ({args.profile} profile), {args.minutes:g} min, 5 robots, {config}"
        + (", noisy landmark attribute" if args.attribute else "")
        + f" (landmarks matched within {MATCH_RADIUS} m)"
    )
    for column, _ in COLUMNS:
        table.add_column(column)
    table.add_row(*(target for _, target in COLUMNS), style="dim")
    scores: dict[str, list[Score]] = {name: [] for name in args.variants}
    for seed in args.seeds:
        records, gen_s = simulate(seed, args.minutes, args.attribute, args.profile)
        frames = sum(isinstance(r, Detections) for r in records)
        purity, completeness = association_ceiling(records)
        console.print(
            f"seed {seed}: {len(records)} records, {frames} frames, generated in {gen_s:.1f} s;"
            f" association ceiling (geometry alone) purity {purity:.3f},"
            f" completeness {completeness:.3f}"
        )
        done: dict[str, tuple[str, Score | list[str]]] = {}
        for name in args.variants:
            cfg = AgrislamConfig.model_validate(merged(VARIANTS[name], args.set))
            key = cfg.model_dump_json()
            if key in done:  # the same configuration today: not run twice
                same, res = done[key]
                label = f"{name} (= {same})"
                row = cells(label, seed, res) if isinstance(res, Score) else [label, *res[1:]]
            else:
                res, issues, minutes = run_variant(name, seed, cfg, records, 60.0 * args.minutes)
                done[key] = (name, res)
                if issues:
                    console.print(f"  {name}: issues {issues}")
                for line in minutes if args.stages else []:
                    console.print(f"  {name}: {line}")
                if isinstance(res, Score) and res.noise:
                    console.print(f"  {name}: noise scales {res.noise}")
                row = cells(name, seed, res) if isinstance(res, Score) else res
            if isinstance(res, Score):
                scores[name].append(res)
            console.print("  " + " | ".join(row))  # as it comes, in case the run is cut short
            table.add_row(*row)
    for name, done_seeds in scores.items():
        if len(done_seeds) > 1:
            table.add_row(*cells(name, f"mean of {len(done_seeds)}", mean_score(done_seeds)))
    console.print(table)


if __name__ == "__main__":
    main()
