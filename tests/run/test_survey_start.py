"""How a survey starts, when its log says it wrongly or not at all: a robot the meta gives no
start pose is placed where its first detections fit the map being built (season/newcomers.py),
and until then none of its detections starts an object; a log without a meta has its first
robot's first pose for origin, the map scored aligned to the truth; a row angle the plants
contradict gives way to theirs; detections read before their robot's first odometry do not
make its odometry go back in time."""

from __future__ import annotations

import dataclasses
import io
import json
from typing import Any

import numpy as np
import pytest

from agrislam.config import AgrislamConfig
from agrislam.io.sinks.jsonl import record_to_json
from agrislam.io.sources.jsonl import read_log
from agrislam.io.sources.sync import synchronise
from agrislam.records import (
    Detections,
    FieldPrior,
    GnssFix,
    Meta,
    Odometry,
    Record,
    TruthObject,
    TruthPose,
)
from agrislam.run.checkpoint import RunState, dump_state, load_state
from agrislam.run.pipeline import RunResult, run_survey
from agrislam.season.field_learning import NO_META
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator
from agrislam.world import WorldModel

ROBOTS = {"path": {"n_robots": 2}, "seed": 3}


def _survey(field: dict[str, Any]) -> list[Record]:
    cfg = SimConfig.model_validate({**ROBOTS, "field": field})
    return list(Simulator(cfg).records())


@pytest.fixture(scope="module")
def records() -> list[Record]:
    """Two robots on a 40-plant field of 4 rows: r1 on the lanes of rows 0-2, r2 on rows
    2-3; r1 maps the rows r2 starts beside, late in its survey."""
    return _survey({"n_plants": 40, "n_rows": 4})


def _map(records: list[Record], config: AgrislamConfig | None = None) -> RunResult:
    return run_survey(records, WorldModel(config))


@pytest.fixture(scope="module")
def clean(records: list[Record]) -> RunResult:
    return _map(records)


def _renamed(records: list[Record], old: str, new: str) -> list[Record]:
    """The records with robot `old` named `new` (its truth too, for scoring)."""
    kinds = (Odometry, Detections, GnssFix, TruthPose)
    return [
        dataclasses.replace(r, robot=new) if isinstance(r, kinds) and r.robot == old else r
        for r in records
    ]


def _mapped(result: RunResult) -> float:
    assert result.metrics is not None
    return result.metrics["objects"]["mapped_fraction"]


def test_a_robot_not_in_the_meta_starts_where_its_first_detections_fit(records, clean):
    result = _map(_renamed(records, "r2", "r9"))
    assert _mapped(result) >= 0.95 * _mapped(clean)
    assert (
        result.issues["robot 'r9' has no start pose: placed where its detections fit the map"] == 1
    )
    assert not any("weak prior" in issue for issue in result.issues)
    assert result.n_frames == clean.n_frames  # every frame of r9 mapped once it was placed
    r9 = result.snapshot.trajectories["r9"]
    truth = next(r.pose for r in records if isinstance(r, TruthPose) and r.robot == "r2")
    assert np.linalg.norm(r9.poses[0, :2] - truth[:2]) < 0.1


def test_a_robot_whose_detections_fit_nowhere_is_reported_and_maps_nothing(records):
    """r9 sees a field of its own (its detections mirrored): never placed, none of its
    detections starts an object, at the origin or anywhere; its frames are counted."""

    def mirrored(r: Record) -> Record:
        if not (isinstance(r, Detections) and r.robot == "r9"):
            return r
        flipped = [dataclasses.replace(d, xy=d.xy * np.array([1.0, -1.0])) for d in r.objects]
        return dataclasses.replace(r, objects=tuple(flipped))

    renamed = _renamed(records, "r2", "r9")
    result = _map([mirrored(r) for r in renamed])
    alone = _map([r for r in renamed if getattr(r, "robot", None) != "r9"])
    np.testing.assert_allclose(result.snapshot.objects.xy, alone.snapshot.objects.xy)
    (issue,) = [i for i in result.issues if i.startswith("robot 'r9' has no start pose")]
    assert "fit nowhere on the map" in issue
    frames = sum(isinstance(r, Detections) and r.robot == "r9" for r in renamed)
    assert result.issues[issue] == frames
    assert "r9" not in result.snapshot.trajectories


def test_a_row_angle_the_plants_contradict_is_replaced_by_the_fitted_one(records, clean):
    """The meta says the rows run at 90 deg; they run at 0: the plants' angle is fitted,
    reported, and the map is as without the wrong angle."""
    wrong = FieldPrior(row_spacing=1.0, min_plant_distance=0.4, row_angle_deg=90.0)
    result = _map(
        [dataclasses.replace(r, field=wrong) if isinstance(r, Meta) else r for r in records]
    )
    assert _mapped(result) >= 0.95 * _mapped(clean)
    (issue,) = [i for i in result.issues if i.startswith("row angle 90 deg given")]
    assert "the fitted angle used" in issue
    assert abs(np.degrees(result.snapshot.rows.angle)) < 1.0


def test_detections_copied_before_the_first_odometry_cost_only_themselves(records, clean):
    """Each robot's frames of its first 10 s copied to the top of the log: the copies are
    skipped lines (`before_odometry`), the odometry after them is read, the map as clean."""
    lines = [json.dumps(record_to_json(r)) for r in records]
    first = next(i for i, r in enumerate(records) if isinstance(r, Odometry))
    copies = [lines[i] for i, r in enumerate(records) if isinstance(r, Detections) and r.t <= 10.0]
    data = "\n".join([*lines[:first], *copies, *lines[first:]]) + "\n"
    reader = read_log(io.BytesIO(data.encode()), strict=False)
    result = run_survey(reader, WorldModel())
    late = sum(json.loads(c)["t"] > 0.0 for c in copies)  # stamped after the first odometry
    assert dict(reader.report.skipped) == {"before_odometry": late}
    assert _mapped(result) >= 0.95 * _mapped(clean)
    assert result.records["Odometry"] == clean.records["Odometry"]


def test_a_log_without_a_meta_is_mapped_in_its_first_robots_frame(records, clean):
    """No meta: no schema, start poses or field prior. The first robot's first pose is the
    map origin (the map is scored aligned), the first plants say the field is in rows, and
    a later robot is placed where its detections fit, or reported."""
    result = _map([r for r in records if not isinstance(r, Meta)])
    assert _mapped(result) >= 0.95 * _mapped(clean)
    assert result.metrics["alignment"]["applied"]
    assert result.issues[NO_META] == 1
    (rows,) = [i for i in result.issues if i.startswith("no field prior: the first plants stand")]
    assert "rows 0.98 m apart" in rows
    r2 = [i for i in result.issues if i.startswith("robot 'r2' has no start pose")]
    assert len(r2) == 1 and not any("weak prior" in i for i in result.issues)


def test_a_world_saved_while_a_robot_waits_carries_on_to_the_same_map(records):
    """A checkpoint taken while a robot waits to be placed holds its records: read back, the
    world maps as one never saved."""
    renamed = _renamed(records, "r2", "r9")
    synced = [r for r in synchronise(renamed) if not isinstance(r, (TruthObject, TruthPose))]
    cut = len(synced) // 2
    whole, saved = WorldModel(), WorldModel()
    for record in synced[:cut]:
        whole.process(record)
        saved.process(record)
    assert saved.newcomers.waiting["r9"].held
    saved = load_state(dump_state(RunState(saved, None))).world
    for world in (whole, saved):
        for record in synced[cut:]:
            world.process(record)
        world.finish()
    a, b = whole.snapshot(), saved.snapshot()
    assert "r9" in a.trajectories
    np.testing.assert_array_equal(a.objects.ids, b.objects.ids)
    np.testing.assert_allclose(a.objects.xy, b.objects.xy, atol=1e-9)
