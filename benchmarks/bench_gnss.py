"""Georeferenced maps against their targets: simulated surveys scored WITHOUT alignment.

For each seed and scenario, the same field and odometry: RTK fixed most of the time with
some float; the same with 30 % of the survey in outages of minutes; the same with 2 %
multipath outliers of metres; and without GNSS (the baseline, also scored after a rigid
alignment, as maps without GNSS are scored). Prints plants within 0.1 m of the truth,
plant and trajectory RMS, the fixes used and rejected, and the median step time against the
run without GNSS and the GNSS stage's own share of it. Targets (10,000 plants): RTK >= 98 %
within 0.1 m, plant RMS <= 0.03 m, trajectory RMS <= 0.03 m; outages >= 95 % within
0.1 m; multipath no more than 10 % worse than RTK; step time with GNSS <= 1.1 x without.

    nice python benchmarks/bench_gnss.py [--plants 10000] [--seeds 1 2 3]"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from agrislam.config import AgrislamConfig
from agrislam.evaluation.metrics import evaluate
from agrislam.records import GnssFix, TruthObject, TruthPose
from agrislam.run.pipeline import run_survey
from agrislam.sim.config import SimConfig
from agrislam.sim.gnss_config import GnssSimConfig
from agrislam.sim.simulator import Simulator
from agrislam.world import WorldModel

SCENARIOS: dict[str, dict[str, Any] | None] = {
    "RTK fixed + float": {},
    "30 % outage": {"outage_fraction": 0.3},
    "2 % multipath": {"multipath_fraction": 0.02},
    "no GNSS": None,
}
WITHIN = 0.1  # m
console = Console(width=180)


def simulate(seed: int, plants: int, gnss: dict[str, Any] | None) -> list:
    cfg = SimConfig(seed=seed)
    cfg.field.n_plants = plants
    cfg.gnss = None if gnss is None else GnssSimConfig(**gnss)
    return list(Simulator(cfg).records())


def score(records: list, result: Any, align: bool) -> dict[str, float]:
    truth_objects = [r for r in records if isinstance(r, TruthObject)]
    truth_poses = [r for r in records if isinstance(r, TruthPose)]
    full = evaluate(result.snapshot, truth_objects, truth_poses, align=align)
    near = evaluate(result.snapshot, truth_objects, truth_poses, radius=WITHIN, align=align)
    return {
        "within": near["objects"]["mapped_fraction"],
        "plant_rms": full["objects"]["position_rms"],
        "traj_rms": full["trajectory"]["optimised"]["rms_position"],
        "dr_rms": full["trajectory"]["dead_reckoning"]["rms_position"],
        "mapped": full["objects"]["mapped_fraction"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=10_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument(
        "--scenarios", nargs="+", choices=["rtk", "outage", "multipath"], default=None,
        help="only these GNSS scenarios (the run without GNSS is always made)",
    )  # fmt: skip
    parser.add_argument("--no-baseline", action="store_true", help="leave out the run without GNSS")
    args = parser.parse_args()
    keys = dict(zip(("rtk", "outage", "multipath"), SCENARIOS, strict=False))
    chosen = {keys[k] for k in args.scenarios} if args.scenarios else set(SCENARIOS)
    scenarios = {
        k: v for k, v in SCENARIOS.items() if k in chosen or (v is None and not args.no_baseline)
    }
    table = Table(title=f"{args.plants}-plant surveys, scored without alignment")
    for column in (
        "scenario",
        "seed",
        f"within {WITHIN} m",
        "plant RMS (m)",
        "traj RMS (m)",
        "DR RMS (m)",
        "mapped",
        "fixes used / rejected",
        "step ms p50 / max",
        "vs no GNSS",
        "GNSS stage",
        "wall s",
    ):
        table.add_column(column)
    summary: dict[str, list[dict[str, float]]] = {name: [] for name in SCENARIOS}
    for seed in args.seeds:
        rows, base_ms = [], 0.0
        for name, gnss in reversed(scenarios.items()):  # no GNSS first: the step baseline
            records = simulate(seed, args.plants, gnss)
            result = run_survey(records, WorldModel(AgrislamConfig()))
            s = score(records, result, align=False)
            steps = result.snapshot.step_seconds()
            ms = float(np.median(steps) * 1e3)
            share = float(np.sum(result.snapshot.step_times["gnss"]) / np.sum(steps))
            base_ms = ms if gnss is None else base_ms
            s["step_ratio"] = ms / base_ms if base_ms else float("nan")
            s["gnss_share"] = share
            counts = result.gnss
            rejected = sum(v for k, v in counts.items() if k.startswith("rejected"))
            fixes = sum(isinstance(r, GnssFix) for r in records)
            used = f"{counts.get('used', 0)} / {rejected} of {fixes}" if fixes else "-"
            label = name
            if gnss is None:
                aligned = score(records, result, align=True)
                s |= {f"aligned_{k}": v for k, v in aligned.items()}
                label += (
                    f" (aligned: {aligned['within']:.1%} within, plants "
                    f"{aligned['plant_rms']:.3f} m, traj {aligned['traj_rms']:.3f} m)"
                )
            summary[name].append(s)
            rows.append(
                row := [
                    label,
                    str(seed),
                    f"{s['within']:.1%}",
                    f"{s['plant_rms']:.3f}",
                    f"{s['traj_rms']:.3f}",
                    f"{s['dr_rms']:.2f}",
                    f"{s['mapped']:.1%}",
                    used,
                    f"{ms:.1f} / {np.max(steps) * 1e3:.0f}",
                    f"{s['step_ratio']:.2f}",
                    f"{share:.1%}",
                    f"{result.wall_seconds:.0f}",
                ]
            )
            console.print("  ".join(row), soft_wrap=True)  # as each run ends
            if result.issues:  # what the run isolated, refused or could not do
                console.print(f"    issues: {result.issues}", soft_wrap=True)
        for row in reversed(rows):
            table.add_row(*row)
    console.print(table)
    verdicts(summary)


def verdicts(summary: dict[str, list[dict[str, float]]]) -> None:
    """Each target against the worst seed (targets of scenarios not run are left out)."""
    rtk, outage, multipath = (
        summary["RTK fixed + float"],
        summary["30 % outage"],
        summary["2 % multipath"],
    )
    gnss_runs = rtk + outage + multipath

    def ratio(key: str) -> list[float]:
        return [m[key] / r[key] for m, r in zip(multipath, rtk, strict=True)]

    def worst(rows: list[dict[str, float]], key: str) -> float:
        """The worst seed's value: the least fraction within, the largest RMS."""
        values = [r[key] for r in rows]
        return min(values) if key == "within" else max(values)

    checks: list[tuple[str, Callable[[], float], Callable[[float], bool]]] = [
        ("RTK: >= 98 % within 0.1 m", lambda: worst(rtk, "within"), lambda v: v >= 0.98),
        ("RTK: plant RMS <= 0.03 m", lambda: worst(rtk, "plant_rms"), lambda v: v <= 0.03),
        ("RTK: trajectory RMS <= 0.03 m", lambda: worst(rtk, "traj_rms"), lambda v: v <= 0.03),
        ("outage: >= 95 % within 0.1 m", lambda: worst(outage, "within"), lambda v: v >= 0.95),
        ("multipath: within >= 0.9 x RTK's", lambda: min(ratio("within")), lambda v: v >= 0.9),
        ("multipath: plant RMS <= 1.1 x RTK", lambda: max(ratio("plant_rms")), lambda v: v <= 1.1),
        (
            "step time with GNSS <= 1.1 x without (median step, mean over runs; noisy on a "
            "shared machine)",
            lambda: float(np.mean([r["step_ratio"] for r in gnss_runs])),
            lambda v: v <= 1.1,
        ),
        (
            "the GNSS stage's share of the step time (largest run)",
            lambda: max(r["gnss_share"] for r in gnss_runs),
            lambda v: v <= 0.1,
        ),
    ]  # fmt: skip
    for text, value, ok in checks:
        try:
            v = value()
        except ValueError:  # a scenario that was not run
            continue
        console.print(f"{'PASS' if ok(v) else 'FAIL'}  {text}: {v:.3f}")


if __name__ == "__main__":
    main()
