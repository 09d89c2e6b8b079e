"""A simulated survey written as a ROS 2 bag (MCAP file, MCAP and sqlite3 folders) reads
back into the same records."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agrislam.config import AgrislamConfig, FieldSchema
from agrislam.io.perception.label_map import LabelMap
from agrislam.io.sinks.jsonl import record_to_json
from agrislam.io.sinks.rosbag import write_survey_bag
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.io.sources.bag_report import BagReport
from agrislam.io.sources.rosbag import BagSource
from agrislam.records import (
    ContinuousMeasurement,
    Detection,
    Detections,
    DiscreteMeasurement,
    Meta,
    Odometry,
    Record,
    TruthObject,
    TruthPose,
)
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator


def open_bag(
    path: Path, config: AgrislamConfig | None = None, bag: BagSourceConfig | None = None
) -> tuple[Iterator[Record], BagReport]:
    """The records of a bag and the report that fills as they are read."""
    source = BagSource(path, config, bag)
    return source.records(), source.report


def simulated(**detector: Any) -> list[Record]:
    odometry = detector.pop("odometry", "pose")
    schema = detector.pop("schema", "colour_size")
    cfg = SimConfig.model_validate(
        {
            "schema": schema,
            "field": {"n_plants": 60, "n_rows": 4},
            "path": {"n_robots": 2},
            "odometry": {"kind": odometry},
            "detector": detector,
        }
    )
    return list(Simulator(cfg).records())


def same(a: Any, b: Any, where: str = "") -> None:
    """Recursive equality of JSON-like values, floats within 1e-9."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (
            f"{where}: keys {a.keys()} != {b.keys()}"
        )
        for k in a:
            same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), f"{where}: lengths differ"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and not isinstance(b, str):
        assert math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-9), f"{where}: {a} != {b}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def assert_same_records(got: list[Record], want: list[Record]) -> None:
    assert [type(r).__name__ for r in got] == [type(r).__name__ for r in want]
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        same(record_to_json(g), record_to_json(w), f"record {i}")


@pytest.fixture(scope="module")
def pose_survey() -> list[Record]:
    """Two robots, odometry poses, range/bearing detections with combined labels."""
    return simulated(geometry="range_bearing", emit_label=True)


@pytest.mark.parametrize(
    ("name", "storage"), [("survey.mcap", "mcap"), ("mcap_bag", "mcap"), ("sqlite_bag", "sqlite3")]
)
def test_simulated_survey_round_trip(
    tmp_path: Path, pose_survey: list[Record], name: str, storage: str
) -> None:
    path = tmp_path / name
    n = write_survey_bag(pose_survey, path, storage)  # type: ignore[arg-type]
    assert n == len(pose_survey)
    assert path.is_file() if name.endswith(".mcap") else (path / "metadata.yaml").is_file()
    records, report = open_bag(
        path, bag=BagSourceConfig(split_labels=False, detection_geometry="range_bearing")
    )
    got = list(records)
    assert report.issues == []
    assert report.roles["odometry"] == ["/r1/odom", "/r2/odom"]
    assert report.roles["detections"] == ["/r1/front/detections", "/r2/front/detections"]
    assert_same_records(got, pose_survey)


def test_delta_odometry_and_continuous_attributes_round_trip(tmp_path: Path) -> None:
    want = simulated(odometry="delta", geometry="xy", emit_label=False, schema="colour_length")
    assert any(
        isinstance(m, ContinuousMeasurement)
        for r in want
        if isinstance(r, Detections)
        for d in r.objects
        for m in d.attributes.values()
    )
    write_survey_bag(want, tmp_path / "delta.mcap")
    records, report = open_bag(tmp_path / "delta.mcap", bag=BagSourceConfig(odometry_form="delta"))
    assert_same_records(list(records), want)
    assert report.issues == []


def test_edge_cases_round_trip(tmp_path: Path) -> None:
    schema = FieldSchema.preset("crops_weeds")
    want: list[Record] = [
        Meta(schema=schema),
        TruthObject("a", np.array([1.0, 2.0]), {"type": "crop", "size": "small"}),
        TruthPose(0.0, "r1", np.zeros(3)),  # at one instant: truth, odometry, detections
        Odometry(0.0, "r1", pose=np.zeros(3)),  # unknown covariance
        Detections(0.0, "r1", ()),  # looked, saw nothing
        Odometry(0.5, "r1", pose=np.array([0.2, 0.01, 0.05]), cov=np.diag([1e-4, 2e-4, 3e-6])),
        Detections(
            0.5,
            "r1",
            (
                Detection(xy=np.array([1.0, -0.5])),  # no covariance, no semantics
                Detection(xy=np.array([2.0, 0.5]), label="weed_big", truth_id="a"),  # no score
                Detection(
                    xy=np.array([1.5, 0.0]),
                    cov=np.array([[0.01, 0.002], [0.002, 0.003]]),
                    attributes={"type": DiscreteMeasurement("weed", 0.6)},
                    label="crop_small_healthy",
                    label_p=0.4,
                ),
            ),
        ),
        TruthObject("b", np.array([3.0, 2.0]), {"type": "weed"}),  # logged mid-survey
        Odometry(1.25, "r1", pose=np.array([0.4, 0.02, 0.1]), cov=np.diag([1e-4, 2e-4, 3e-6])),
    ]
    write_survey_bag(want, tmp_path / "edge", "sqlite3")
    records, _ = open_bag(tmp_path / "edge", bag=BagSourceConfig(split_labels=False))
    assert_same_records(list(records), want)


def test_labels_are_split_by_the_schema_the_bag_carries(
    tmp_path: Path, pose_survey: list[Record]
) -> None:
    write_survey_bag(pose_survey, tmp_path / "labels.mcap")
    records, report = open_bag(
        tmp_path / "labels.mcap", bag=BagSourceConfig(detection_geometry="range_bearing")
    )
    got = list(records)
    schema = pose_survey[0].schema  # type: ignore[union-attr]
    label_map = LabelMap(schema=schema)
    want = [
        Detections(r.t, r.robot, tuple(label_map.apply(d) for d in r.objects), r.sensor)
        if isinstance(r, Detections)
        else r
        for r in pose_survey
    ]
    assert_same_records(got, want)
    first = next(d for r in got if isinstance(r, Detections) for d in r.objects)
    assert first.label is None and set(first.attributes) == {"colour", "size"}
    assert report.issues == []


def test_writer_refuses_what_a_bag_cannot_hold(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="negative"):
        write_survey_bag([Odometry(-1.0, "r1", pose=np.zeros(3))], tmp_path / "neg.mcap")
    bad = Detections(
        0.0, "r1", (Detection(xy=np.zeros(2), attributes={"a=b": DiscreteMeasurement("x", 0.5)}),)
    )
    with pytest.raises(ValueError, match="'a=b'"):
        write_survey_bag([bad], tmp_path / "name.mcap")
    (tmp_path / "exists.mcap").write_bytes(b"")
    with pytest.raises(FileExistsError):
        write_survey_bag([], tmp_path / "exists.mcap")
