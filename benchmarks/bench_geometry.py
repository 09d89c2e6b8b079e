"""Geometry back end benchmark: per-step latency and final map accuracy of the
incremental back end (iSAM2 with keyframes), plain iSAM2 and the paper's batch baseline
(whole-graph LM every step) on simulated lawnmower surveys of 400, 2,000 and 10,000
plants with known association (the detector's truth ids).

Fields come from agrislam.sim (rows 1 m apart, plants 0.4-0.5 m apart, lawnmower lanes
between the rows, a front camera seeing 2.5 m, noisy odometry); clutter and double
detections are off, so association is exact. A step is one camera frame: its odometry,
its objects and observations, `update()` and the row tracker, all timed together.

    python benchmarks/bench_geometry.py                      # 400, 2000, 10000
    python benchmarks/bench_geometry.py --sizes 400 --modes incremental batch

A mode that would exceed its time budget stops there; its row says how many steps it ran
and the accuracy columns then compare it with the incremental back end at that step.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agrislam.backend import GraphBackend, RelativePosition, make_backend
from agrislam.config import RowsConfig, SlamConfig
from agrislam.estimation.rows import RowTracker
from agrislam.geometry.se2 import compose
from agrislam.records import Detections, Meta, Odometry
from agrislam.sim.config import DetectorConfig, FieldLayout, SimConfig
from agrislam.sim.simulator import Simulator

# rows per field: the default 400-plant field has 10 rows of 40; larger fields grow in
# both directions (about square), so their lanes get longer as well as more numerous
ROWS = {400: 10, 2000: 22, 10000: 50}


@dataclass
class Step:
    t: float
    robot: str
    odometry: tuple[np.ndarray, np.ndarray] | None
    detections: list[tuple[str, np.ndarray, np.ndarray]]  # truth id, xy, cov (robot frame)


@dataclass
class Survey:
    n_plants: int
    starts: dict[str, tuple[np.ndarray, np.ndarray]]
    steps: list[Step]
    truth: dict[str, np.ndarray]
    weeds: set[str]  # ids of the plants off the rows
    row_normal: np.ndarray  # n of the true rows: row k is n . p = n . origin + k spacing
    row_origin: np.ndarray


def make_survey(
    n_plants: int, seed: int = 1, n_rows: int | None = None, weed_fraction: float = 0.0
) -> Survey:
    """A simulated survey of the field with `n_plants` plants, records flattened to steps."""
    layout = FieldLayout(
        n_plants=n_plants, n_rows=n_rows or ROWS.get(n_plants, 10), weed_fraction=weed_fraction
    )
    cfg = SimConfig(
        seed=seed,
        field=layout,
        detector=DetectorConfig(clutter_rate=0.0, double_detection_p=0.0),
    )
    sim = Simulator(cfg)
    starts, steps, pending = {}, [], None
    for record in sim.records():
        if isinstance(record, Meta):
            starts = {n: (s.pose, s.sigma) for n, s in record.robots.items()}
        elif isinstance(record, Odometry) and record.cov is not None and np.any(record.cov):
            pending = (np.asarray(record.delta), np.asarray(record.cov))
        elif isinstance(record, Detections):
            dets = [(d.truth_id, np.asarray(d.xy), np.asarray(d.cov)) for d in record.objects]
            steps.append(Step(record.t, record.robot, pending, dets))
            pending = None
    field = sim.field
    truth = {str(i): xy for i, xy in zip(field.ids, field.xy, strict=True)}
    weeds = {str(i) for i in field.ids[field.is_weed]}
    return Survey(n_plants, starts, steps, truth, weeds, field.row_normal, field.origin)


@dataclass
class Run:
    mode: str
    latency: np.ndarray  # s per step
    steps: int
    complete: bool
    rms: float  # object RMS error against truth at the last step run
    refined_rms: float | None = None
    refine_s: float | None = None
    rms_at: dict[int, float] = field(default_factory=dict)  # step -> RMS then


def drive(
    backend: GraphBackend,
    survey: Survey,
    rows: RowTracker | None,
    budget_s: float,
    snapshot_at: Callable[[int], bool] = lambda step: False,
) -> tuple[np.ndarray, dict[str, int], bool, dict[int, dict[str, np.ndarray]]]:
    """Feed the survey step by step; stop when the budget is spent."""
    for name, (pose, sigma) in survey.starts.items():
        backend.add_robot(name, pose, sigma, t=0.0)
    ids: dict[str, int] = {}
    frames_seen = np.zeros(len({d[0] for s in survey.steps for d in s.detections}), np.int64)
    latency, snapshots = [], {}
    start = time.perf_counter()
    for n, step in enumerate(survey.steps):
        t0 = time.perf_counter()
        if step.odometry is not None:
            backend.add_odometry(step.robot, step.t, *step.odometry)
        pose = backend.current_pose(step.robot)
        touched = []
        for truth_id, xy, cov in step.detections:
            if truth_id not in ids:
                ids[truth_id] = len(ids)
                backend.add_object(ids[truth_id], compose(pose, np.r_[xy, 0.0])[:2])
            backend.add_observation(step.robot, ids[truth_id], RelativePosition(xy, cov))
            touched.append(ids[truth_id])
        backend.update()
        touched_ids = np.unique(np.array(touched, np.int64))
        frames_seen[touched_ids] += 1
        if rows is not None:
            rows.after_step(backend, touched_ids, len(touched), frames_seen)
        latency.append(time.perf_counter() - t0)
        if snapshot_at(n + 1):
            snapshots[n + 1] = positions(backend, ids)
        if time.perf_counter() - start > budget_s:
            return np.array(latency), ids, False, snapshots
    return np.array(latency), ids, True, snapshots


def positions(backend: GraphBackend, ids: dict[str, int]) -> dict[str, np.ndarray]:
    xy = backend.object_positions(np.array(list(ids.values()), dtype=np.int64))
    return dict(zip(ids, xy, strict=True))


def rms_error(estimates: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> float:
    err = np.array([estimates[k] - truth[k] for k in estimates])
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


MODES = {
    "incremental": SlamConfig(backend="incremental"),
    # as measured before issue 3: relinearise threshold 0.1, every 10th step
    "plain-isam2": SlamConfig(window=0, relinearize_threshold=0.1, relinearize_skip=10),
    "batch": SlamConfig(backend="batch"),
}


def run_mode(
    mode: str, survey: Survey, rows: bool, budget_s: float, snapshot_steps: set[int]
) -> Run:
    backend = make_backend(MODES[mode], RowsConfig())
    tracker = RowTracker(RowsConfig()) if rows else None
    latency, ids, complete, snaps = drive(
        backend, survey, tracker, budget_s, lambda n: n in snapshot_steps
    )
    run = Run(
        mode, latency, len(latency), complete, rms_error(positions(backend, ids), survey.truth)
    )
    run.rms_at = {step: rms_error(xy, survey.truth) for step, xy in snaps.items()}
    if complete and mode != "batch":
        t0 = time.perf_counter()
        backend.refine()
        run.refine_s = time.perf_counter() - t0
        run.refined_rms = rms_error(positions(backend, ids), survey.truth)
    return run


def table(results: list[tuple[int, Run, Run | None]]) -> str:
    lines = [
        "| plants | mode | steps | median ms | p95 ms | max ms | RMS m | vs incremental | "
        "after refine() m | refine s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n, run, reference in results:
        ms = run.latency * 1e3
        steps = f"{run.steps}" + ("" if run.complete else " (budget)")
        ratio = "" if reference is None else f"{run.rms / reference_rms(run, reference):.3f}x"
        refined = "" if run.refined_rms is None else f"{run.refined_rms:.4f}"
        refine_s = "" if run.refine_s is None else f"{run.refine_s:.1f}"
        lines.append(
            f"| {n} | {run.mode} | {steps} | {np.median(ms):.2f} | {np.percentile(ms, 95):.2f} "
            f"| {ms.max():.1f} | {run.rms:.4f} | {ratio} | {refined} | {refine_s} |"
        )
    return "\n".join(lines)


def reference_rms(run: Run, reference: Run) -> float:
    """The incremental back end's RMS at the step `run` stopped (the same objects)."""
    return reference.rms if run.complete else reference.rms_at[run.steps]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[400, 2000, 10000])
    parser.add_argument("--modes", nargs="+", default=["incremental", "plain-isam2", "batch"])
    parser.add_argument("--budget-s", type=float, default=300.0, help="per mode and size")
    parser.add_argument("--no-rows", action="store_true")
    parser.add_argument("--json", help="write the figures here too")
    args = parser.parse_args()
    results: list[tuple[int, Run, Run | None]] = []
    summary = {}
    for n in args.sizes:
        survey = make_survey(n)
        print(
            f"{n} plants: {len(survey.steps)} steps, "
            f"{sum(len(s.detections) for s in survey.steps)} detections",
            flush=True,
        )
        others = [
            run_mode(mode, survey, not args.no_rows, args.budget_s, set())
            for mode in args.modes
            if mode != "incremental"
        ]
        # the incremental back end, with its map kept where a budgeted run stopped
        stops = {run.steps for run in others if not run.complete}
        incremental = run_mode("incremental", survey, not args.no_rows, float("inf"), stops)
        results.append((n, incremental, None))
        results.extend((n, run, incremental) for run in others)
        print(table([r for r in results if r[0] == n]), flush=True)
        summary[n] = {
            run.mode: {
                "steps": run.steps,
                "complete": run.complete,
                "median_ms": float(np.median(run.latency) * 1e3),
                "p95_ms": float(np.percentile(run.latency, 95) * 1e3),
                "max_ms": float(run.latency.max() * 1e3),
                "rms_m": run.rms,
                "refined_rms_m": run.refined_rms,
            }
            for size, run, _ in results
            if size == n
        }
    print()
    print(table(results))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=2)


if __name__ == "__main__":
    main()
