"""Hostile input in ROS bags: a truncated MCAP file is read up to the cut and says how much,
a message with a wild stamp costs that message, a frame of too many detections is refused
whole, a bad meta record stops the read, and values out of bounds never become records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_rosbag_inputs import bag, kinds, odom, read

from agrislam.io.ros.messages import DETECTION3D_ARRAY, ODOMETRY, STRING, MessageFactory
from agrislam.io.sinks.rosbag import write_survey_bag
from agrislam.io.sources import open_source
from agrislam.io.sources.jsonl import LogError
from agrislam.io.sources.rosbag import BagSource
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator


@pytest.fixture(scope="module")
def survey_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bag") / "survey.mcap"
    cfg = SimConfig.model_validate({"field": {"n_plants": 20, "n_rows": 2}, "seed": 2})
    write_survey_bag(list(Simulator(cfg).records()), path)
    return path


@pytest.mark.parametrize("kept", [0.3, 0.7, 0.999])
def test_a_truncated_mcap_bag_is_read_up_to_the_cut(survey_bag, tmp_path, kept):
    whole, _ = read(survey_bag)
    data = survey_bag.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(kept * len(data))])
    source = open_source(cut)  # opens: the damage is no reason to refuse the whole bag
    records = list(source.records())
    (damaged,) = [i for i in source.report.issues if i.kind == "damaged"]
    assert "truncated" in damaged.message and f"of {cut.stat().st_size:,} bytes" in damaged.message
    n_odom = sum(type(r).__name__ == "Odometry" for r in records)
    assert n_odom > 0 and len(records) <= len(whole)
    if kept > 0.99:  # cut in the summary, after every message
        assert len(records) == len(whole)


def test_a_stamp_spike_costs_one_message(tmp_path):
    make = MessageFactory()
    with bag(tmp_path / "b.mcap", make) as write:
        for k, t in enumerate((0.0, 0.1, 0.2, 1e6, 0.4, 0.5, 0.6)):
            write("/odom", ODOMETRY, odom(make, t, 0.1 * k, 0.0, 0.0), 0.1 * k)
    got, report = read(tmp_path / "b.mcap")
    assert [r.t for r in got] == [0.0, 0.1, 0.2, 0.4, 0.5, 0.6]  # type: ignore[union-attr]
    assert kinds(report)[-1] == ("time_jump", "/odom", 1e6)


def test_a_frame_of_too_many_detections_is_refused_before_it_is_read(tmp_path):
    make = MessageFactory()
    dets = [make.detection3d(0.25, "base_link", (1.0, 0.01 * k, 0.0), []) for k in range(1001)]
    with bag(tmp_path / "b.mcap", make) as write:
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write("/det", DETECTION3D_ARRAY, make.detection_array(0.25, "base_link", dets), 0.25)
        write("/odom", ODOMETRY, odom(make, 0.5, 0.1, 0.0, 0.0), 0.5)
    got, report = read(tmp_path / "b.mcap")
    assert [type(r).__name__ for r in got] == ["Odometry", "Odometry"]
    issue = next(i for i in report.issues if i.kind == "too_many_detections")
    assert "1001 detections" in issue.message


def test_out_of_bounds_odometry_is_skipped_and_the_motion_kept(tmp_path):
    make = MessageFactory()
    with bag(tmp_path / "b.mcap", make) as write:
        for k, x in enumerate((0.0, 0.1, 1e12, 0.3)):
            write("/odom", ODOMETRY, odom(make, 0.1 * k, x, 0.0, 0.0), 0.1 * k)
    got, report = read(tmp_path / "b.mcap", odometry_form="delta")
    assert kinds(report)[-1] == ("out_of_bounds", "/odom", 0.2)
    np.testing.assert_allclose(got[-1].delta, [0.2, 0.0, 0.0], atol=1e-12)  # type: ignore[union-attr]


def test_an_odometry_covariance_that_shrank_is_no_increment(tmp_path):
    make = MessageFactory()
    with bag(tmp_path / "b.mcap", make) as write:
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0, np.diag([0.2, 0.2, 0.02])), 0.0)
        write("/odom", ODOMETRY, odom(make, 1.0, 1.0, 0.0, 0.0, np.diag([0.3, 0.1, 0.03])), 1.0)
    got, report = read(tmp_path / "b.mcap", odom_covariance="absolute")
    assert got[1].cov is None  # type: ignore[union-attr]
    assert ("degenerate_covariance", "/odom", 1.0) in kinds(report)


def test_a_bad_meta_record_stops_the_bag(tmp_path):
    make = MessageFactory()
    meta = '{"type": "meta", "version": 1, "anchor": {"lat": 95.0, "lon": 5.0}}'
    with bag(tmp_path / "b.mcap", make) as write:
        write("/agrislam/meta", STRING, make.T[STRING](data=meta), 0.0)
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
    with pytest.raises(LogError, match=r"/agrislam/meta:1: out_of_bounds: anchor\.lat") as err:
        read(tmp_path / "b.mcap")
    assert err.value.fatal


def test_a_truncated_sqlite_bag_says_how_to_rescue_it(survey_bag, tmp_path):
    folder = tmp_path / "db"
    write_survey_bag(list(BagSource(survey_bag).records()), folder, "sqlite3")
    db = next(folder.glob("*.db3"))
    db.write_bytes(db.read_bytes()[: db.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"malformed.*\.recover"):
        open_source(folder)
