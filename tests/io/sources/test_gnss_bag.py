"""sensor_msgs/NavSatFix in ROS bags: a simulated survey with GNSS written by the
survey bag sink reads back with the same fixes (type, covariance, antenna from tf_static);
a NavSatFix's status and covariance give the fix type; a bad fix is an issue, not a stop."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_rosbag_roundtrip import assert_same_records

from agrislam.io.ros.navsat import FIX, GBAS_FIX, NO_FIX, SBAS_FIX, fix_type
from agrislam.io.sinks.rosbag import write_survey_bag
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.io.sources.rosbag import BagSource
from agrislam.records import GnssFix, Record
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator


@pytest.fixture(scope="module")
def gnss_survey() -> list[Record]:
    cfg = SimConfig.model_validate(
        {
            "field": {"n_plants": 40, "n_rows": 4},
            "path": {"n_robots": 2},
            "odometry": {"kind": "pose"},
            "gnss": {"fraction": {"rtk_fixed": 0.4, "rtk_float": 0.3, "single": 0.3}, "run_s": 2.0},
        }
    )
    return list(Simulator(cfg).records())


def test_navsat_fixes_round_trip_through_a_bag(tmp_path: Path, gnss_survey: list[Record]) -> None:
    fixes = [r for r in gnss_survey if isinstance(r, GnssFix)]
    assert {f.fix for f in fixes} == {"rtk_fixed", "rtk_float", "single"}
    write_survey_bag(gnss_survey, tmp_path / "survey.mcap")
    source = BagSource(tmp_path / "survey.mcap", None, BagSourceConfig(split_labels=False))
    got = list(source.records())
    assert source.report.issues == []
    assert source.report.roles["gnss"] == ["/r1/gnss/fix", "/r2/gnss/fix"]
    assert_same_records(got, gnss_survey)


def test_a_bad_fix_in_a_bag_is_an_issue_and_the_rest_is_read(tmp_path: Path) -> None:
    good = GnssFix(1.0, "r1", 51.4, 5.4, 20.0, "rtk_fixed", np.eye(3) * 1e-4, None)
    bad = GnssFix(2.0, "r1", 95.0, 5.4, 20.0, "rtk_fixed", np.eye(3) * 1e-4, None)
    write_survey_bag(
        [good, bad, GnssFix(3.0, "r1", 51.4, 5.4, 20.0, "single")], tmp_path / "b.mcap"
    )
    source = BagSource(tmp_path / "b.mcap", None, None)
    got = [r for r in source.records() if isinstance(r, GnssFix)]
    assert [f.t for f in got] == [1.0, 3.0]
    assert got[1].cov is None and got[1].fix == "single"
    (issue,) = [i for i in source.report.issues if i.kind == "out_of_bounds"]
    assert "'lat'" in issue.message


@pytest.mark.parametrize(
    ("status", "sigma", "expected"),
    [
        (NO_FIX, 1.0, "none"),
        (FIX, 2.0, "single"),
        (SBAS_FIX, 0.5, "dgps"),
        (GBAS_FIX, 0.02, "rtk_fixed"),
        (GBAS_FIX, 0.3, "rtk_float"),
        (GBAS_FIX, None, "rtk_float"),
    ],
)
def test_status_and_covariance_give_the_fix_type(status, sigma, expected) -> None:
    cov = None if sigma is None else np.eye(3) * sigma**2
    assert fix_type(status, cov) == expected
