"""Real logs against their reference: agrislam with its DEFAULT configuration and, in the same
run, the batch solve of the same records by their true association (real_reference.py), on
a multi-robot range-bearing log (MRCLAM dataset 6: whole, and its first 300 s) and on
Victoria Park. Per log and span it prints a row for each, the gap (default minus
reference) column by column, and the targets the default row meets and misses.

    python benchmarks/bench_real.py [--mrclam LOG] [--victoria-park LOG] [--spans whole 300]
                                    [--no-reference] [--skip-victoria-park]

Both are scored by agrislam's own evaluation (real_scoring.py). Victoria Park's log has no
truth but its association: its landmark and trajectory columns are against the reference's
solve (which then scores itself perfectly: only its size and wall time say anything).
The targets: the whole multi-robot log's (a held-back log of the same kind is judged by
them too) and Victoria Park's; a part of a log has none."""

from __future__ import annotations

import argparse
from pathlib import Path

from agrislam.run.pipeline import run_survey
from agrislam.world import WorldModel
from real_reference import Reference, solve_reference
from real_scoring import (
    LANDMARK_LOG_TARGETS,
    MRCLAM6,
    VICTORIA_PARK,
    VICTORIA_PARK_TARGETS,
    Check,
    Row,
    Survey,
    console,
    gap_cells,
    judged,
    read_survey,
    row_cells,
    score_against,
    table,
)


def default_row(survey: Survey, reference: Reference | None) -> Row:
    """agrislam's default configuration on the survey's records, scored against the log's
    truth, or against the reference's solve where the log has none."""
    result = run_survey(survey.records, WorldModel())
    metrics = result.metrics or {"objects": {"n_estimated": len(result.snapshot.objects)}}
    truth = survey.truth_objects()
    if not truth:
        association = metrics.get("association", {})
        if reference is not None:
            metrics = score_against(result.snapshot, reference.landmarks, reference.trajectories)
        else:
            metrics = {"objects": {**metrics["objects"], "n_truth": 0}}
        metrics["association"] = association
    landmarks = len(truth) or len(survey.landmarks_seen())
    return Row.of(metrics, landmarks, result.wall_seconds)


def compare(log: Path, t_max: float | None, with_reference: bool) -> tuple[str, Row, Row | None]:
    """One log and span: its label, agrislam's row and the reference's."""
    survey = read_survey(log, t_max)
    reference = solve_reference(survey, log=lambda _: None) if with_reference else None
    default = default_row(survey, reference)
    label = f"{survey.name}, {survey.span}"
    return label, default, reference.row(survey) if reference is not None else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mrclam", type=Path, default=MRCLAM6, help="a MRCLAM-style log")
    parser.add_argument("--victoria-park", type=Path, default=VICTORIA_PARK)
    parser.add_argument(
        "--spans", nargs="+", default=["whole", "300"], help="'whole' or seconds from the start"
    )
    parser.add_argument("--no-reference", action="store_true", help="agrislam's rows only")
    parser.add_argument("--skip-victoria-park", action="store_true")
    args = parser.parse_args()
    cases: list[tuple[Path, float | None, list[Check]]] = []
    for span in args.spans:
        t_max = None if span == "whole" else float(span)
        targets = LANDMARK_LOG_TARGETS if t_max is None else []
        cases.append((args.mrclam, t_max, targets))
    if not args.skip_victoria_park:
        cases.append((args.victoria_park, None, VICTORIA_PARK_TARGETS))
    out = table(
        "Real logs: agrislam's default configuration against the reference by true association",
        caption="gap = default - reference; Victoria Park's landmarks and trajectory against "
        "the reference's solve (its log has no truth)",
    )
    verdicts = []
    for log, t_max, targets in cases:
        label, default, reference = compare(log, t_max, not args.no_reference)
        out.add_row(*row_cells(label, "agrislam", default))
        if reference is not None:
            out.add_row(*row_cells("", "reference", reference))
            out.add_row(*gap_cells(default.gap(reference)), end_section=True)
        if targets:
            verdicts.append((label, "agrislam", *judged(default, targets)))
            if reference is not None:
                verdicts.append((label, "reference", *judged(reference, targets)))
    console.print(out)
    for label, run, met, missed in verdicts:
        summary = "all met" if not missed else f"missed: {'; '.join(missed)}"
        console.print(f"{label}, {run}: {len(met)} of {len(met) + len(missed)} targets, {summary}")


if __name__ == "__main__":
    main()
