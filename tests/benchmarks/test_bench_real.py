"""benchmarks/real_scoring.py and real_reference.py: a row is read from agrislam's own
evaluation, the gap is column by column, the targets judge what the issue says, and the
reference solves by true association recover a simulated survey's landmarks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agrislam.evaluation.metrics import evaluate
from agrislam.geometry.se2 import compose
from agrislam.io.sinks.jsonl import write_log
from agrislam.records import (
    Detection,
    Detections,
    Meta,
    Odometry,
    RobotStart,
    TruthObject,
    TruthPose,
)
from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.config import ArenaConfig
from benchmark_module import load_benchmark

scoring = load_benchmark("real_scoring")  # before the reference, which imports it
reference = load_benchmark("real_reference")


def row(**changes) -> object:
    """A row meeting every target of a whole MRCLAM-style log, with `changes`."""
    good = scoring.Row(
        objects=16,
        landmarks=15,
        within_30=15,
        within_15=13,
        landmark_rms=0.08,
        trajectory_rms=0.2,
        trajectory_dr=3.0,
        heading_deg=5.0,
        heading_dr_deg=80.0,
        first_half=0.2,
        second_half=0.19,
        purity=0.99,
        completeness=0.98,
        wall_s=40.0,
    )
    return dataclasses.replace(good, **changes)


def test_a_row_reads_agrislams_evaluation():
    truth = [TruthObject(f"l{i}", np.array([float(i), 0.0])) for i in range(4)]
    est = np.array([[0.1, 0.0], [1.2, 0.0], [2.0, 0.4], [3.0, 0.05], [3.0, 2.0]])
    snapshot = scoring.solution_snapshot(dict(enumerate(est)), {}, {})
    metrics = evaluate(snapshot, truth)
    got = scoring.Row.of(metrics, 4, 12.5)
    assert (got.objects, got.landmarks, got.within_30, got.within_15) == (5, 4, 3, 2)
    assert got.landmark_rms == pytest.approx(math.sqrt((0.01 + 0.04 + 0.0025) / 3))
    assert got.trajectory_rms is None and got.purity is None and got.wall_s == 12.5


def test_the_gap_is_default_minus_reference_column_by_column():
    gap = row(objects=30, landmark_rms=0.2, purity=None).gap(row())
    assert gap["objects"] == 14 and gap["landmark_rms"] == pytest.approx(0.12)
    assert gap["purity"] is None and gap["within_30"] == 0
    cells = scoring.gap_cells(gap)
    assert len(cells) == len(scoring.COLUMNS) and cells[2] == "+14"


@pytest.mark.parametrize(
    "changes, missed",
    [
        ({}, []),
        ({"within_30": 14}, ["all landmarks within 0.3 m"]),
        ({"within_15": 11}, [">= 12 within 0.15 m"]),
        ({"objects": 19}, ["<= 3 objects beyond the landmarks"]),
        ({"landmark_rms": 0.11}, ["landmark RMS <= 0.10 m"]),
        (
            {"trajectory_rms": 0.26, "second_half": 0.21},
            ["trajectory RMS <= 0.25 m", "second half no worse than first"],
        ),
        ({"wall_s": 61.0}, ["wall <= 60 s"]),
    ],
)
def test_the_whole_logs_targets(changes, missed):
    assert scoring.judged(row(**changes), scoring.LANDMARK_LOG_TARGETS)[1] == missed


def test_victoria_parks_targets():
    _, missed = scoring.judged(row(purity=0.94, wall_s=60.0), scoring.VICTORIA_PARK_TARGETS)
    assert missed == ["purity >= 0.95", "wall < 60 s"]


def test_a_survey_read_up_to_a_time_keeps_the_truth_of_its_landmarks(tmp_path):
    records = list(arena_survey(60.0).records)
    log = tmp_path / "arena.jsonl"
    write_log(records, log)
    survey = scoring.read_survey(log, t_max=30.0)
    assert survey.span == "first 30 s" and survey.name == "arena"
    assert (
        max(f.t for f in survey.frames) <= 30.0 < max(f.t for f in scoring.read_survey(log).frames)
    )
    assert len(survey.truth_objects()) == 17 and set(survey.starts) == {"r1", "r2"}
    track = survey.odometry_tracks()["r1"]
    assert track[-1, 0] <= 30.0 and np.all(np.diff(track[:, 0]) > 0)


def arena_survey(seconds: float) -> object:
    """The arena's landmarks seen by two robots for `seconds`: the odometry's white noise as
    reported (its biases not), 2 % of the ranges gross errors."""
    cfg = ArenaConfig(
        seed=2,
        driving={"duration_s": seconds, "n_robots": 2},
        odometry={"report_sigma_factor": (1.0, 1.0, 1.0)},
    )
    return scoring.Survey("arena", list(ArenaSimulator(cfg).records()))


def test_the_range_bearing_reference_maps_a_simulated_survey_by_its_true_association():
    survey = arena_survey(120.0)
    solved = reference.solve_reference(survey, passes=2, log=lambda _: None)
    assert sorted(solved.landmarks) == sorted(survey.landmarks_seen())
    got = solved.row(survey)
    assert got.within_15 == len(solved.landmarks)
    assert got.trajectory_rms < 0.5 * got.trajectory_dr  # the map corrects the odometry
    assert (got.purity, got.completeness) == (1.0, 1.0)


def points_survey(n_steps: int = 150, seed: int = 0) -> object:
    """A car circling ten landmarks, a frame of robot-frame xy detections at each odometry
    record (as Victoria Park's log has them), its odometry as noisy as it reports, its true
    poses beside."""
    rng = np.random.default_rng(seed)
    landmarks = {f"t{i}": rng.uniform(-12.0, 12.0, 2) for i in range(10)}
    start = np.zeros(3)
    records: list = [Meta(robots={"car": RobotStart(start, np.full(3, 1e-3))})]
    step, sigma = np.array([0.5, 0.0, 2 * np.pi / n_steps]), np.array([0.02, 0.02, 0.02])
    pose = start
    for k in range(n_steps + 1):
        if k == 0:
            records.append(Odometry(0.0, "car", pose=start))
        else:
            pose = compose(pose, step + rng.normal(0.0, sigma))
            records.append(Odometry(float(k), "car", delta=step, cov=np.diag(sigma**2)))
        records.append(TruthPose(float(k), "car", pose))
        c, s = np.cos(pose[2]), np.sin(pose[2])
        seen = []
        for name, xy in landmarks.items():
            d = xy - pose[:2]
            local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
            if np.hypot(*local) < 15.0:
                noisy = local + rng.normal(0.0, 0.05, 2)
                seen.append(Detection(xy=noisy, cov=np.eye(2) * 0.0025, truth_id=name))
        records.append(Detections(float(k), "car", tuple(seen)))
    truth = [TruthObject(name, xy) for name, xy in landmarks.items()]
    return scoring.Survey("points", records + truth)


def test_the_point_reference_corrects_the_odometrys_drift():
    survey = points_survey()
    got = reference.solve_reference(survey).row(survey)
    assert got.objects == got.landmarks == 10 and got.landmark_rms < 0.05
    assert got.trajectory_rms < 0.3 * got.trajectory_dr
