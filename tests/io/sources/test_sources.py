"""`open_source`: one entry point for every input, the reader chosen by suffix or scheme,
every source the same shape (records(), report, name)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer

from agrislam.config import AgrislamConfig
from agrislam.io.ros.messages import ODOMETRY, MessageFactory
from agrislam.io.sinks.jsonl import record_to_json, write_log
from agrislam.io.sinks.rosbag import write_survey_bag
from agrislam.io.sources import SUPPORTED, Source, SourceError, open_source
from agrislam.io.sources.jsonl import LogError, LogReader
from agrislam.io.sources.rosbag import BagSource
from agrislam.io.sources.simulated import SimulatedSource, simulation_config, simulation_uri
from agrislam.records import Detections, Meta, Odometry, Record
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator

SMALL = {"field": {"n_plants": 30, "n_rows": 3}}


def small_survey(seed: int = 2) -> list[Record]:
    return list(Simulator(SimConfig.model_validate({**SMALL, "seed": seed})).records())


def as_json(records: list[Record]) -> list[dict]:
    return [record_to_json(r) for r in records]


def read(source: Source) -> list[Record]:
    assert isinstance(source, Source)
    records = list(source.records())
    assert isinstance(source.report.summary(), str)
    json.dumps(source.report.as_dict())  # plain values
    return records


@pytest.fixture(scope="module")
def survey() -> list[Record]:
    return small_survey()


@pytest.mark.parametrize("name", ["survey.jsonl", "survey.jsonl.gz", "SURVEY.JSONL"])
def test_a_survey_log_opens_as_a_log_reader(tmp_path: Path, survey: list[Record], name: str):
    write_log(survey, tmp_path / name)
    source = open_source(tmp_path / name)
    assert isinstance(source, LogReader) and source.name == str(tmp_path / name)
    assert as_json(read(source)) == as_json(survey)
    assert source.report.as_dict()["records"] == len(survey)


def test_a_log_is_lenient_unless_strict(tmp_path: Path, survey: list[Record]):
    path = tmp_path / "broken.jsonl"
    write_log(survey, path)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:3], "{not json", *lines[3:]]) + "\n")
    lenient = open_source(str(path))
    assert len(read(lenient)) == len(survey) and lenient.report.as_dict()["skipped"] == {
        "not_json": 1
    }
    with pytest.raises(SourceError, match=r"broken\.jsonl:4: not_json") as err:
        list(open_source(path, strict=True).records())
    assert isinstance(err.value, LogError)


def test_the_report_is_that_of_the_latest_pass(tmp_path: Path, survey: list[Record]):
    write_log(survey, tmp_path / "s.jsonl")
    source = open_source(tmp_path / "s.jsonl")
    read(source)
    read(source)
    assert source.report.records == len(survey)


@pytest.mark.parametrize("layout", ["file.mcap", "mcap_folder", "sqlite_folder", "file.db3"])
def test_a_ros2_bag_opens_as_a_bag_source(tmp_path: Path, survey: list[Record], layout: str):
    if layout == "file.mcap":
        path = tmp_path / "survey.mcap"
        write_survey_bag(survey, path)
    else:
        path = tmp_path / "survey"
        storage = "mcap" if layout == "mcap_folder" else "sqlite3"
        write_survey_bag(survey, path, storage)
        path = next(path.glob("*.db3")) if layout == "file.db3" else path
    source = open_source(path, AgrislamConfig(), bag={"split_labels": False})
    assert isinstance(source, BagSource) and source.name == str(path)
    got = read(source)
    assert not source.report.issues and source.report.as_dict()["issues"] == []
    assert [type(r) for r in got] == [type(r) for r in survey]
    assert [r.t for r in got if isinstance(r, Odometry)] == [
        r.t for r in survey if isinstance(r, Odometry)
    ]


def test_a_ros1_bag_opens_as_a_bag_source(tmp_path: Path):
    make = MessageFactory("noetic")
    path = tmp_path / "old.bag"
    cov6 = np.zeros((6, 6))
    cov6[np.ix_([0, 1, 5], [0, 1, 5])] = np.diag([1e-4, 1e-4, 1e-5])
    with Ros1Writer(path) as w:
        conn = w.add_connection("/odom", ODOMETRY, typestore=make.store)
        for k in range(3):
            msg = make.odometry(k * 0.5, "odom", "base_link", (0.1 * k, 0, 0), (0, 0, 0, 1), cov6)
            w.write(conn, round(k * 0.5e9), make.serialize(msg, ODOMETRY))
    source = open_source(path)
    assert isinstance(source, BagSource)
    got = read(source)
    assert [r.t for r in got if isinstance(r, Odometry)] == [0.0, 0.5, 1.0]
    assert source.report.as_dict()["roles"]["odometry"] == ["/odom"]


def test_the_bag_section_configures_a_bag_source(tmp_path: Path, survey: list[Record]):
    write_survey_bag(survey, tmp_path / "s.mcap")
    source = open_source(tmp_path / "s.mcap", bag={"odometry_form": "delta"})
    assert isinstance(source, BagSource) and source.bag.odometry_form == "delta"
    assert all(r.delta is not None for r in read(source) if isinstance(r, Odometry))
    with pytest.raises(ValueError, match="odometry_form"):
        open_source(tmp_path / "s.mcap", bag={"odometry_form": "sideways"})


def test_the_simulated_source_is_the_simulator():
    cfg = SimConfig.model_validate({**SMALL, "seed": 7})
    source = open_source("sim:", sim=cfg)
    assert isinstance(source, SimulatedSource)
    got = read(source)
    assert as_json(got) == as_json(list(Simulator(cfg).records()))
    assert source.name == "sim:?plants=30&seed=7&preset=colour_size"
    counts = source.report.as_dict()["records"]
    assert counts["Meta"] == 1 and sum(counts.values()) == len(got)
    assert source.report.summary().startswith("sim:?plants=30&seed=7&preset=colour_size: ")


def test_uri_parameters_go_on_top_of_the_sim_section():
    uri = "sim:?plants=24&seed=3&preset=crops_weeds&robots=2"
    source = open_source(uri, sim={"field": {"n_rows": 4}, "seed": 99})
    cfg = source.config  # type: ignore[attr-defined]
    assert (cfg.field.n_plants, cfg.field.n_rows, cfg.seed, cfg.path.n_robots) == (24, 4, 3, 2)
    assert cfg.schema_ == "crops_weeds"
    want = SimConfig.model_validate(
        {
            "schema": "crops_weeds",
            "seed": 3,
            "field": {"n_plants": 24, "n_rows": 4},
            "path": {"n_robots": 2},
        }
    )
    assert as_json(read(source)) == as_json(list(Simulator(want).records()))
    assert simulation_config("sim:").model_dump() == SimConfig().model_dump()
    assert simulation_uri(plants=5, seed=1) == "sim:?plants=5&seed=1"
    meta = next(iter(open_source("sim:?plants=5").records()))
    assert isinstance(meta, Meta) and meta.robots.keys() == {"r1"}


@pytest.mark.parametrize(
    ("uri", "says"),
    [
        ("sim:?plants=many", "plants='many' is not int"),
        ("sim:?trees=4", "unknown parameter 'trees'; known: plants, seed, preset, robots"),
        ("sim:?seed=1&seed=2", "'seed' given twice"),
        ("sim:field?seed=1", "is not a simulation URI"),
        ("sim:?plants=0", "n_plants"),
    ],
)
def test_a_bad_simulation_uri_says_what_is_wrong(uri: str, says: str):
    with pytest.raises(ValueError, match=says.replace("?", r"\?")):
        open_source(uri)


def test_an_unknown_kind_of_input_names_what_is_supported(tmp_path: Path):
    (tmp_path / "survey.csv").write_text("t,x\n")
    with pytest.raises(ValueError, match="not a kind of input agrislam reads") as err:
        open_source(tmp_path / "survey.csv")
    assert SUPPORTED in str(err.value) and ".jsonl" in SUPPORTED and "sim:" in SUPPORTED
    with pytest.raises(ValueError, match="unknown source scheme 'http'; supported: a survey"):
        open_source("http://example.org/survey.jsonl")
    with pytest.raises(FileNotFoundError, match=r"nothere\.jsonl: no such file"):
        open_source(tmp_path / "nothere.jsonl")
    with pytest.raises(FileNotFoundError, match=r"nothere\.mcap"):
        open_source(str(tmp_path / "nothere.mcap"))


def test_every_source_yields_detections_the_same_way(tmp_path: Path, survey: list[Record]):
    """The same survey through the log, a bag and the simulator: the same frames."""
    write_log(survey, tmp_path / "s.jsonl")
    write_survey_bag(survey, tmp_path / "s.mcap")
    sources = [
        open_source(tmp_path / "s.jsonl"),
        open_source(tmp_path / "s.mcap", bag={"split_labels": False}),
        open_source("sim:?plants=30&seed=2", sim={"field": {"n_rows": 3}}),
    ]
    frames = [[r.t for r in read(s) if isinstance(r, Detections)] for s in sources]
    want = [r.t for r in survey if isinstance(r, Detections)]
    assert frames[0] == frames[1] == frames[2] == want
