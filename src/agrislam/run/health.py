"""A run's health, minute by minute of survey time: what the map did (objects created,
merged, pruned; frames on which a lost robot rejoined it; loops closed) and how well the
accepted associations fit (their normalised innovation squared, NIS), so that a user
without ground truth sees when and how a map degrades. The NIS is taken with the
innovation covariance the association gated with (association/gnn.py, `accepted_nis`), an
upper bound of the true one: a consistent map's NIS stays at or below chi2 with 2 degrees
of freedom (mean 2, median 1.39, 1 % beyond 9.21). A map bent by wrong associations, or by
drift its covariances do not cover, shows its NIS rising past that, and objects started
again for landmarks it had.

The run keeps it from each step's report (`world.StepReport`): a few appends a step, read
out once at the end. `metrics.json`'s `health` is a list of one dict per minute, from the
first frame's minute to the last one's (a minute without frames has a row of zeros):

    minute         survey minute: the row counts the frames with 60 minute <= t < 60 (minute + 1)
    frames         frames of detections mapped
    detections     detections in them (range errors of mapped landmarks included)
    created        objects started
    merged         objects merged into others (a closed loop's merges included)
    pruned         objects pruned (young ones dropped unconfirmed included)
    rejoins        frames on which a lost robot rejoined the map (association/rejoin.py)
    loops          loops closed (association/loop_closure.py)
    associated     detections the association put on existing objects (the GNN's; not
                   those the rejoin placed): the NIS below are theirs
    nis_median     their NIS's median (null without any)
    nis_mean       their NIS's mean
    nis_beyond_99  the share of them beyond the 99 % point of chi2 with 2 dof

The survey's end (`WorldModel.finish`: the last merges and prunes) counts in the last row.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agrislam.growing import GrowingRows
from agrislam.maintenance.maintainer import MaintenanceResult
from agrislam.world import StepReport

MINUTE_S = 60.0
NIS_99 = -2.0 * math.log(0.01)  # the 99 % point of chi2 with 2 dof (9.21)
COUNTED = ("frames", "detections", "created", "merged", "pruned", "rejoins", "loops")
KEYS = ("minute", *COUNTED, "associated", "nis_median", "nis_mean", "nis_beyond_99")
PRINTED_ROWS = 20  # a longer survey is printed with several minutes a row


class Health:
    """What each step of a run did, by survey minute (module doc)."""

    def __init__(self) -> None:
        self._minutes = GrowingRows(dtype=np.int64)  # each step's minute
        self._counts = GrowingRows((len(COUNTED),), dtype=np.int64)  # and its COUNTED
        self._nis = GrowingRows(dtype=np.float64)  # each accepted association's NIS
        self._nis_minutes = GrowingRows(dtype=np.int64)  # and its minute

    def step(self, report: StepReport) -> None:
        """One frame's step."""
        minute = int(report.t // MINUTE_S)
        done = report.maintenance
        counts = (1, len(report.object_ids), len(report.new_ids), len(done.merged))
        self._add(minute, (*counts, len(done.pruned), int(report.rejoined), done.loops))
        nis = report.nis[np.isfinite(report.nis)]
        if len(nis):
            self._nis.extend(nis)
            self._nis_minutes.extend(np.full(len(nis), minute))

    def finish(self, result: MaintenanceResult) -> None:
        """The survey's end (`WorldModel.finish`), counted in its last minute."""
        minute = int(self._minutes.array[-1]) if len(self._minutes) else 0
        self._add(minute, (0, 0, 0, len(result.merged), len(result.pruned), 0, result.loops))

    def _add(self, minute: int, counts: tuple[int, ...]) -> None:
        self._minutes.append(minute)
        self._counts.append(counts)

    def totals(self) -> dict[str, int]:
        """Each of COUNTED over the whole run."""
        return dict(zip(COUNTED, self._counts.array.sum(axis=0).tolist(), strict=True))

    @property
    def n_minutes(self) -> int:
        """Minutes from the first step's to the last one's."""
        minutes = self._minutes.array
        return int(minutes.max() - minutes.min()) + 1 if len(minutes) else 0

    def rows(self, span: int = 1) -> list[dict[str, Any]]:
        """One dict of KEYS per `span` minutes from the first step's minute on (module doc);
        `minute` is a row's first."""
        if not len(self._minutes):
            return []
        minutes = self._minutes.array
        first = int(minutes.min())
        group = (minutes - first) // span
        counts = np.zeros((int(group.max()) + 1, len(COUNTED)), dtype=np.int64)
        np.add.at(counts, group, self._counts.array)
        nis_group = (self._nis_minutes.array - first) // span
        order = np.argsort(nis_group, kind="stable")
        values = self._nis.array[order]
        bounds = np.searchsorted(nis_group[order], np.arange(len(counts) + 1))
        return [
            {
                "minute": first + g * span,
                **dict(zip(COUNTED, counts[g].tolist(), strict=True)),
                **nis_summary(values[bounds[g] : bounds[g + 1]]),
            }
            for g in range(len(counts))
        ]


def nis_summary(nis: np.ndarray) -> dict[str, Any]:
    """How many NIS values, their median and mean, and the share beyond chi2's 99 % (2 dof)."""
    if len(nis) == 0:
        return {"associated": 0, "nis_median": None, "nis_mean": None, "nis_beyond_99": None}
    return {
        "associated": len(nis),
        "nis_median": float(np.median(nis)),
        "nis_mean": float(nis.mean()),
        "nis_beyond_99": float((nis > NIS_99).mean()),
    }


def print_health(health: Health, console: Any = None, max_rows: int = PRINTED_ROWS) -> None:
    """The health as a table on the terminal: a row a minute, or several minutes a row so
    that a long survey fits in `max_rows`."""
    from rich.console import Console
    from rich.table import Table

    if health.n_minutes == 0:
        return
    console = console or Console()
    span = math.ceil(health.n_minutes / max_rows)
    title = "Map health by survey minute" + (f" ({span} minutes a row)" if span > 1 else "")
    table = Table(
        title=title,
        caption="NIS of the accepted associations: a consistent map stays at or below chi2 "
        f"with 2 dof (median 1.39, 1 % beyond {NIS_99:.2f})",
    )
    columns = ("minute", "created", "merged", "pruned", "NIS med", "NIS>99%", "rejoins", "loops")
    for name in columns:
        table.add_column(name, justify="right")
    rows = health.rows(span)
    last = rows[0]["minute"] + health.n_minutes - 1
    for row in rows:
        first = row["minute"]
        minute = f"{first}-{min(first + span - 1, last)}" if span > 1 else str(first)
        median, beyond = row["nis_median"], row["nis_beyond_99"]
        table.add_row(
            minute,
            *(str(row[k]) for k in ("created", "merged", "pruned")),
            "-" if median is None else f"{median:.2f}",
            "-" if beyond is None else f"{100 * beyond:.1f} %",
            str(row["rejoins"]),
            str(row["loops"]),
        )
    console.print(table)
