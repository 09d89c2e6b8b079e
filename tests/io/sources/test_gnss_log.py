"""The `gnss` record of the survey log (docs/log-format.md, reader version 1.2): written and
read back, and every bad fix stopped (strict) or skipped and counted (lenient)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from agrislam.io.sinks.jsonl import record_to_json, write_log
from agrislam.io.sources.jsonl import LogError, read_log
from agrislam.records import GnssFix, Odometry

META = {"type": "meta", "version": 1}
ODOM = {"type": "odom", "t": 0.5, "robot": "r1", "delta": [0.1, 0.0, 0.0]}
FIX = {
    "type": "gnss",
    "t": 1.0,
    "robot": "r1",
    "lat": 51.4488,
    "lon": 5.4905,
    "alt": 20.1,
    "fix": "rtk_fixed",
    "cov": [[4e-4, 0, 0], [0, 4e-4, 0], [0, 0, 1e-3]],
    "antenna": [0.3, 0.0, 1.2],
}


def read(lines: list[dict | str], strict: bool):
    text = "\n".join(x if isinstance(x, str) else json.dumps(x) for x in lines) + "\n"
    reader = read_log(io.BytesIO(text.encode()), strict=strict)
    return list(reader), reader.report


def test_a_fix_is_written_and_read_back(tmp_path) -> None:
    fix = GnssFix(1.0, "r1", 51.4488, 5.4905, 20.1, "rtk_float", np.eye(3) * 0.09, None)
    write_log([Odometry(0.5, "r1", delta=np.zeros(3)), fix], tmp_path / "log.jsonl")
    back = list(read_log(tmp_path / "log.jsonl"))[1]
    assert isinstance(back, GnssFix)
    assert (back.lat, back.lon, back.alt, back.fix, back.antenna) == (
        51.4488,
        5.4905,
        20.1,
        "rtk_float",
        None,
    )
    np.testing.assert_array_equal(back.cov, fix.cov)
    assert record_to_json(back)["type"] == "gnss"


def test_the_spec_layout_reads() -> None:
    records, _ = read([META, ODOM, FIX], strict=True)
    fix = records[-1]
    assert isinstance(fix, GnssFix)
    np.testing.assert_array_equal(fix.antenna, [0.3, 0.0, 1.2])


BAD = [
    ({"lat": float("nan")}, "non_finite", "'lat'"),  # Python's JSON reads NaN
    ({"lat": 91.0}, "out_of_bounds", "'lat'"),
    ({"lon": -180.5}, "out_of_bounds", "'lon'"),
    ({"cov": [[-1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]]}, "bad_covariance", "'cov'"),
    ({"fix": "rtk_maybe"}, "bad_value", "'fix'"),
    ({"fix": None}, "missing_field", "'fix'"),
    ({"lat": "51.4"}, "bad_value", "'lat'"),
    ({"antenna": [0.1, 0.2]}, "bad_value", "'antenna'"),
]


@pytest.mark.parametrize(("change", "reason", "says"), BAD)
def test_a_bad_fix_is_a_bad_line(change: dict, reason: str, says: str) -> None:
    bad = json.dumps({**FIX, **change})
    with pytest.raises(LogError) as err:
        read([META, ODOM, bad], strict=True)
    assert err.value.reason == reason and err.value.line == 3
    assert says in str(err.value)
    records, report = read([META, ODOM, bad, {**FIX, "t": 2.0}], strict=False)
    assert report.skipped == {reason: 1}
    assert [type(r).__name__ for r in records] == ["Meta", "Odometry", "GnssFix"]
