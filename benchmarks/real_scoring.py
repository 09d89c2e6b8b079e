"""What the real-log benchmarks share (bench_real.py, real_reference.py): a survey log read
into records up to a time, a map scored by agrislam's own evaluation
(`agrislam.evaluation.metrics.evaluate`) into one row of the real-log table, the table with
the gap between two rows, and the targets a row is judged against.

A row's columns: objects (and the landmarks there are), landmarks with an object within
0.3 m and 0.15 m (one to one), the landmark RMS of those within 0.3 m, the trajectory's RMS
(dead reckoning's beside it), the heading's RMS (the same), the trajectory's RMS over the
first and the second half of the survey, the association's purity and completeness, and
the wall time of the mapping (reading and scoring left out)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from agrislam.evaluation.ground_truth import TruthObjects
from agrislam.evaluation.metrics import evaluate
from agrislam.geometry.se2 import compose
from agrislam.io.sources import open_source
from agrislam.records import (
    Detections,
    Meta,
    Odometry,
    Record,
    RobotStart,
    TruthObject,
    TruthPose,
)
from agrislam.snapshot import MapSnapshot, ObjectMap, Trajectory

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MRCLAM6 = SHARED_DATA / "mrclam6" / "mrclam6.jsonl"
VICTORIA_PARK = SHARED_DATA / "victoria_park" / "victoria_park.jsonl"


# ------------------------------------------------------------------------------ the log


@dataclass(frozen=True)
class Survey:
    """A survey log's records up to `t_max` (None: all); records without a time (meta,
    landmarks' truth) are all kept."""

    name: str
    records: list[Record]
    t_max: float | None = None

    @property
    def span(self) -> str:
        return "whole" if self.t_max is None else f"first {self.t_max:g} s"

    @property
    def starts(self) -> dict[str, RobotStart]:
        """Each robot's start pose and sigma, as the metas give them."""
        out: dict[str, RobotStart] = {}
        for record in self.records:
            if isinstance(record, Meta):
                out.update(record.robots)
        return out

    @property
    def frames(self) -> list[Detections]:
        return [r for r in self.records if isinstance(r, Detections)]

    def odometry(self) -> dict[str, list[Odometry]]:
        """Each robot's odometry records, in the order of the log."""
        out: dict[str, list[Odometry]] = {}
        for record in self.records:
            if isinstance(record, Odometry):
                out.setdefault(record.robot, []).append(record)
        return out

    def odometry_tracks(self) -> dict[str, np.ndarray]:
        """Each robot's (n, 4) odometry-frame track: t, x, y and the heading unwrapped; a
        `delta` record composed onto the pose before it (the first from the origin)."""
        tracks = {}
        for robot, records in self.odometry().items():
            pose, rows = np.zeros(3), []
            for record in records:
                if record.pose is not None:
                    pose = np.asarray(record.pose, float)
                elif record.delta is not None:
                    pose = compose(pose, np.asarray(record.delta, float))
                rows.append((record.t, *pose))
            track = np.array(rows)
            track[:, 3] = np.unwrap(track[:, 3])
            tracks[robot] = track
        return tracks

    def landmarks_seen(self) -> list[str]:
        """The truth ids the detections name, in the order first seen."""
        seen = (d.truth_id for f in self.frames for d in f.objects if d.truth_id is not None)
        return list(dict.fromkeys(seen))

    def truth_objects(self) -> list[TruthObject]:
        return [r for r in self.records if isinstance(r, TruthObject)]

    def truth_poses(self) -> list[TruthPose]:
        return [r for r in self.records if isinstance(r, TruthPose)]


def read_survey(log: str | Path, t_max: float | None = None) -> Survey:
    """The log's records (through agrislam's own source), those after `t_max` left out."""
    records = [
        r
        for r in open_source(str(log)).records()
        if t_max is None or getattr(r, "t", None) is None or r.t <= t_max
    ]
    return Survey(Path(log).stem, records, t_max)


# ------------------------------------------------------------------------------ a row


@dataclass(frozen=True)
class Row:
    """One run's figures (None: not known for this run or log)."""

    objects: int
    landmarks: int
    within_30: int | None
    within_15: int | None
    landmark_rms: float | None
    trajectory_rms: float | None
    trajectory_dr: float | None
    heading_deg: float | None
    heading_dr_deg: float | None
    first_half: float | None
    second_half: float | None
    purity: float | None
    completeness: float | None
    wall_s: float

    @classmethod
    def of(cls, metrics: Mapping[str, Any], landmarks: int, wall_s: float) -> Row:
        """The row of `evaluate`'s metrics (with the association's, if the run has them)."""
        objects = metrics["objects"]
        within = {w["radius"]: w for w in objects.get("within", [])}
        trajectory = metrics.get("trajectory", {})
        optimised = trajectory.get("optimised", {})
        dead = trajectory.get("dead_reckoning", {})
        association = metrics.get("association", {})
        has_truth = objects["n_truth"] > 0
        return cls(
            objects=objects["n_estimated"],
            landmarks=landmarks,
            within_30=within[0.3]["matched"] if has_truth else None,
            within_15=within[0.15]["matched"] if has_truth else None,
            landmark_rms=within[0.3]["position_rms"] if has_truth else None,
            trajectory_rms=optimised.get("rms_position"),
            trajectory_dr=dead.get("rms_position"),
            heading_deg=_degrees(optimised.get("rms_heading")),
            heading_dr_deg=_degrees(dead.get("rms_heading")),
            first_half=optimised.get("rms_position_first_half"),
            second_half=optimised.get("rms_position_second_half"),
            purity=association.get("purity"),
            completeness=association.get("completeness"),
            wall_s=wall_s,
        )

    def gap(self, reference: Row) -> dict[str, float | None]:
        """This row minus `reference`, column by column."""
        out: dict[str, float | None] = {}
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(reference, f.name)
            out[f.name] = None if a is None or b is None else a - b
        return out


def _degrees(x: float | None) -> float | None:
    return None if x is None else math.degrees(x)


def solution_snapshot(
    landmarks: Mapping[str, np.ndarray],
    trajectories: Mapping[str, Trajectory],
    dead_reckoning: Mapping[str, Trajectory],
) -> MapSnapshot:
    """A solve's landmarks and trajectories as a map snapshot, for agrislam's evaluation."""
    n = len(landmarks)
    xy = np.array(list(landmarks.values()), float).reshape(n, 2)
    objects = ObjectMap(
        ids=np.arange(n),
        xy=xy,
        cov=np.zeros((n, 2, 2)),
        n_meas=np.ones(n, dtype=np.int64),
        interest=np.zeros(n),
        row=np.full(n, -1),
    )
    return MapSnapshot(None, objects, dict(trajectories), dict(dead_reckoning))


def score_against(
    snapshot: MapSnapshot,
    landmarks: Mapping[str, np.ndarray],
    trajectories: Mapping[str, Trajectory],
) -> dict[str, Any]:
    """`evaluate` of a map against landmarks and trajectories taken as the truth (a log's
    own truth, or a reference solve where the log has none)."""
    truth = TruthObjects.of(TruthObject(name, np.asarray(xy)) for name, xy in landmarks.items())
    return evaluate(snapshot, truth, dict(trajectories))


# ---------------------------------------------------------------------------- targets

Check = tuple[str, Callable[[Row], bool]]


def _at_most(value: float | None, limit: float) -> bool:
    return value is not None and value <= limit


# the targets of a whole multi-robot range-bearing log (MRCLAM-style) and of Victoria Park
LANDMARK_LOG_TARGETS: list[Check] = [
    ("all landmarks within 0.3 m", lambda r: r.within_30 == r.landmarks),
    (">= 12 within 0.15 m", lambda r: r.within_15 is not None and r.within_15 >= 12),
    ("<= 3 objects beyond the landmarks", lambda r: r.objects <= r.landmarks + 3),
    ("landmark RMS <= 0.10 m", lambda r: _at_most(r.landmark_rms, 0.10)),
    ("trajectory RMS <= 0.25 m", lambda r: _at_most(r.trajectory_rms, 0.25)),
    (
        "second half no worse than first",
        lambda r: r.first_half is not None and _at_most(r.second_half, r.first_half),
    ),
    ("wall <= 60 s", lambda r: r.wall_s <= 60.0),
]
VICTORIA_PARK_TARGETS: list[Check] = [
    ("purity >= 0.95", lambda r: r.purity is not None and r.purity >= 0.95),
    ("completeness >= 0.95", lambda r: r.completeness is not None and r.completeness >= 0.95),
    ("wall < 60 s", lambda r: r.wall_s < 60.0),
]


def judged(row: Row, targets: Iterable[Check]) -> tuple[list[str], list[str]]:
    """The targets the row meets and those it misses."""
    met, missed = [], []
    for name, check in targets:
        (met if check(row) else missed).append(name)
    return met, missed


# ------------------------------------------------------------------------------ the table

COLUMNS = (
    "log, span",
    "run",
    "objects",
    "<=0.3 m",
    "<=0.15 m",
    "lm RMS",
    "traj RMS (DR)",
    "heading (DR)",
    "1st / 2nd half",
    "purity",
    "complete",
    "wall",
)


def _num(x: float | None, digits: int = 3, unit: str = "", sign: bool = False) -> str:
    if x is None:
        return "-"
    return f"{x:+.{digits}f}{unit}" if sign else f"{x:.{digits}f}{unit}"


def row_cells(label: str, run: str, row: Row) -> list[str]:
    """A row's cells in COLUMNS."""
    return [
        label,
        run,
        f"{row.objects} / {row.landmarks}",
        _num(row.within_30, 0),
        _num(row.within_15, 0),
        _num(row.landmark_rms, unit=" m"),
        f"{_num(row.trajectory_rms, unit=' m')} ({_num(row.trajectory_dr, 2)})",
        f"{_num(row.heading_deg, 1, ' deg')} ({_num(row.heading_dr_deg, 1)})",
        f"{_num(row.first_half, 3)} / {_num(row.second_half, 3)}",
        _num(row.purity),
        _num(row.completeness),
        _num(row.wall_s, 1, " s"),
    ]


def gap_cells(gap: Mapping[str, float | None]) -> list[str]:
    """The gap's cells in COLUMNS (default minus reference)."""
    return [
        "",
        "gap",
        _num(gap["objects"], 0, sign=True),
        _num(gap["within_30"], 0, sign=True),
        _num(gap["within_15"], 0, sign=True),
        _num(gap["landmark_rms"], unit=" m", sign=True),
        _num(gap["trajectory_rms"], unit=" m", sign=True),
        _num(gap["heading_deg"], 1, " deg", sign=True),
        f"{_num(gap['first_half'], sign=True)} / {_num(gap['second_half'], sign=True)}",
        _num(gap["purity"], sign=True),
        _num(gap["completeness"], sign=True),
        _num(gap["wall_s"], 1, " s", sign=True),
    ]


def table(title: str, caption: str | None = None) -> Table:
    """An empty table of COLUMNS."""
    out = Table(title=title, caption=caption)
    for name in COLUMNS:
        out.add_column(name, justify="left" if name in ("log, span", "run") else "right")
    return out


console = Console(width=200)
