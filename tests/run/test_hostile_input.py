"""Hostile input, record by record: each edit of one record of a small simulated survey log,
read in strict mode (a clear error naming the line and the field) and mapped in lenient mode
(one skipped and reported record, and otherwise the map of the clean log). Rows for the back
end (an odometry delta of 1e308 reaching GTSAM, 1,000 robots) are stopped here at the door.

"Otherwise the same map": a skipped detection, truth or meta-free record changes nothing of
the map's objects beyond that one detection; a skipped odometry record is bridged
(io/sources/odometry_gaps.py), so every object is still mapped within a few centimetres of
where the clean log puts it."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from agrislam.config import AgrislamConfig
from agrislam.estimation import noise_calibration
from agrislam.frontend import doubt, sensor_model
from agrislam.io.sinks.jsonl import record_to_json
from agrislam.io.sources.jsonl import LogError, read_log
from agrislam.run.pipeline import RunError, run_survey
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator
from agrislam.snapshot import MapSnapshot
from agrislam.world import WorldModel

BRIDGED = 0.05  # m: how far an object may move when one odometry record was bridged


@pytest.fixture(scope="module")
def lines() -> list[str]:
    """A 30-plant survey log (about 230 lines), one JSON text per line."""
    cfg = SimConfig.model_validate({"field": {"n_plants": 30, "n_rows": 3}, "seed": 2})
    return [json.dumps(record_to_json(r)) for r in Simulator(cfg).records()]


@pytest.fixture(scope="module")
def clean(lines: list[str]) -> MapSnapshot:
    return _lenient(_log(lines))[0]


def _log(lines: list[str]) -> bytes:
    return "".join(line + "\n" for line in lines).encode()


def _index(lines: list[str], kind: str, k: int, with_objects: bool = False) -> int:
    """The line number (0-based) of the k-th record of a type (with detections)."""
    hits = [
        i
        for i, text in enumerate(lines)
        if json.loads(text)["type"] == kind and (not with_objects or '"xy"' in text)
    ]
    return hits[k]


def _edit(lines: list[str], i: int, change: Callable[[dict[str, Any]], Any]) -> bytes:
    out = list(lines)
    record = json.loads(out[i])
    change(record)
    out[i] = json.dumps(record)
    return _log(out)


def _strict_error(data: bytes) -> LogError:
    with pytest.raises(LogError) as err:
        list(read_log(io.BytesIO(data), strict=True))
    return err.value


def _lenient(data: bytes) -> tuple[MapSnapshot, Any]:
    reader = read_log(io.BytesIO(data), strict=False)
    result = run_survey(reader, WorldModel(AgrislamConfig()))
    assert result.snapshot is not None
    return result.snapshot, reader.report


def _one_skipped(report: Any, line: int, reason: str) -> None:
    assert dict(report.skipped) == {reason: 1}
    (bad,) = report.bad_lines
    assert (bad.line, bad.reason) == (line, reason)
    table = report.skipped_table()
    assert table["line"] == [line] and table["reason"] == [reason]


def _same_map(got: MapSnapshot, clean: MapSnapshot, tolerance: float = 0.0) -> None:
    """The same objects (ids) at the same places, or within `tolerance` metres."""
    np.testing.assert_array_equal(got.objects.ids, clean.objects.ids)
    np.testing.assert_allclose(got.objects.xy, clean.objects.xy, rtol=0.0, atol=tolerance)


def _objects(xy: list[Any]) -> Callable[[dict[str, Any]], None]:
    def change(record: dict[str, Any]) -> None:
        record["objects"][0]["xy"] = xy

    return change


def _set(key: str, value: Any, index: int | None = None) -> Callable[[dict[str, Any]], None]:
    def change(record: dict[str, Any]) -> None:
        if index is None:
            record[key] = value
        else:
            record[key][index] = value

    return change


# (what is done, record type, which one, the edit, reason); the odometry rows are
# bridged (BRIDGED), the others leave the map as it was
ODOMETRY_ROWS = [
    ("one odometry record early with t = 1e9", 4, _set("t", 1e9), "time_jump", "t = 1000000000"),
    ("a string '0.2' in an odometry delta", 20, _set("delta", "0.2", 0), "bad_value", "'0.2'"),
    ("odometry covariance with a tiny negative entry", 40, None, "bad_covariance", "-1e-12"),
    ("odometry covariance all zeros", 41, None, "bad_covariance", "all zeros"),
    ("an integer of 400 digits", 30, _set("t", 10**399), "out_of_bounds", "400 digits"),
    ("t of 1e308", 31, _set("t", 1e308), "out_of_bounds", "'t' = 1e+308"),
    ("an odometry delta of 1e308", 32, _set("delta", 1e308, 0), "out_of_bounds", "'delta'[0]"),
]


def _cov(kind: str) -> Callable[[dict[str, Any]], None]:
    def change(record: dict[str, Any]) -> None:
        if kind == "negative":
            record["cov"][2][2] = -1e-12
        else:
            record["cov"] = [[0.0] * 3 for _ in range(3)]

    return change


@pytest.mark.parametrize(("row", "k", "change", "reason", "says"), ODOMETRY_ROWS)
def test_one_bad_odometry_record_costs_that_record(lines, clean, row, k, change, reason, says):
    change = change or _cov("negative" if "negative" in row else "zeros")
    i = _index(lines, "odom", k)
    data = _edit(lines, i, change)
    err = _strict_error(data)
    assert (err.line, err.reason) == (i + 1, reason) and says in err.message, row
    got, report = _lenient(data)
    _one_skipped(report, i + 1, reason)
    _same_map(got, clean, BRIDGED)


@pytest.mark.parametrize("strict", [True, False])
def test_a_re_sent_odometry_delta_is_dropped_and_counted(lines, clean, strict):
    """The same delta record twice (a re-sent message) would move the robot twice; it is
    dropped and counted, in strict mode too, and the map is the clean log's."""
    i = _index(lines, "odom", 20)
    reader = read_log(io.BytesIO(_log([*lines[: i + 1], *lines[i:]])), strict=strict)
    result = run_survey(reader, WorldModel(AgrislamConfig()))
    _one_skipped(reader.report, i + 2, "repeated")
    assert result.snapshot is not None
    _same_map(result.snapshot, clean)


@pytest.mark.parametrize(
    ("row", "change"),
    [
        ("a jump of 2 m", [2.0, 0.0, 0.0]),
        ("a jump of 5 km", [5000.0, 0.0, 0.0]),
        ("a spin of 1,000 rad", [0.0, 0.0, 1000.0]),
    ],
)
def test_one_odometry_delta_far_beyond_the_robots_motion_is_doubted(lines, clean, row, change):
    """A delta within sensor.limits but far beyond anything the robot did (a corrupted
    message) is doubted, the next frame's detections deciding; the map is the clean
    log's within what a guessed motion costs, and the doubt is counted."""
    i = _index(lines, "odom", 45)  # in the second row: its next frame sees mapped plants

    def jumped(record: dict[str, Any]) -> None:
        record["delta"] = [a + b for a, b in zip(record["delta"], change, strict=True)]

    reader = read_log(io.BytesIO(_edit(lines, i, jumped)), strict=True)
    result = run_survey(reader, WorldModel(AgrislamConfig()))
    assert result.issues == {doubt.DOUBTED: 1}, row
    assert result.snapshot is not None
    _same_map(result.snapshot, clean, BRIDGED)


def _near_clean(got: MapSnapshot, clean: MapSnapshot, tolerance: float) -> None:
    """As many objects as the clean map, each clean one with one within `tolerance` m."""
    assert len(got.objects) == len(clean.objects)
    apart = np.linalg.norm(clean.objects.xy[:, None] - got.objects.xy[None], axis=2)
    assert apart.min(axis=1).max() < tolerance


@pytest.mark.parametrize(
    ("kind", "variance", "raised"),
    [
        ("detections", 1e-6, {noise_calibration.FLOORED}),
        ("detections", 1e-12, {noise_calibration.FLOORED}),
        ("detections", 1e-16, {noise_calibration.FLOORED}),
        ("odom", 1e-16, {sensor_model.RAISED, doubt.FLOORED}),
    ],
)
def test_covariances_far_too_sure_of_themselves_are_raised(lines, clean, kind, variance, raised):
    """Every covariance of a kind a diagonal of 1e-6 to 1e-16 (1e-16: the least the reader
    takes): raised to what the data show (the spread of a plant's re-sightings, the
    robot's own jitter), never below the solver's least; counted, and the map is the
    clean log's within a few centimetres (it was 0.2-0.5 m off, or 'indeterminate')."""

    def sure(text: str) -> str:
        record = json.loads(text)
        if record["type"] == "odom" == kind:
            record["cov"] = (np.eye(3) * variance).tolist()
        elif record["type"] == "detections" == kind:
            for obj in record["objects"]:
                obj["cov"] = (np.eye(2) * variance).tolist()
        return json.dumps(record)

    reader = read_log(io.BytesIO(_log([sure(text) for text in lines])), strict=True)
    result = run_survey(reader, WorldModel(AgrislamConfig()))
    assert set(result.issues) == raised
    assert result.snapshot is not None
    _near_clean(result.snapshot, clean, BRIDGED)


DETECTION_ROWS = [
    ("a string in xy", _objects(["0.2", 1.0]), "bad_value", "objects[0]: 'xy' entry"),
    ("xy of 1e150", _objects([1e150, 0.0]), "out_of_bounds", "objects[0]: 'xy'[0]"),
    ("a coordinate of 1e308", _objects([0.5, 1e308]), "out_of_bounds", "'xy'[1] = 1e+308"),
    ("a detection with an all-zero covariance", None, "bad_covariance", "all zeros"),
]


@pytest.mark.parametrize(("row", "change", "reason", "says"), DETECTION_ROWS)
def test_one_bad_detection_record_costs_that_record(lines, clean, row, change, reason, says):
    def zero_cov(record: dict[str, Any]) -> None:
        record["objects"][0]["cov"] = [[0.0, 0.0], [0.0, 0.0]]

    i = _index(lines, "detections", 25, with_objects=True)
    data = _edit(lines, i, change or zero_cov)
    err = _strict_error(data)
    assert (err.line, err.reason) == (i + 1, reason) and says in err.message, row
    got, report = _lenient(data)
    _one_skipped(report, i + 1, reason)
    # one frame fewer: the objects it saw were seen in their other frames
    assert len(got.objects) == len(clean.objects)
    np.testing.assert_allclose(
        np.sort(got.objects.xy, axis=0), np.sort(clean.objects.xy, axis=0), atol=BRIDGED
    )


@pytest.mark.parametrize(
    ("row", "bad_line", "reason"),
    [
        ("a line of 100,000 nested brackets", "[" * 100_000 + "]" * 100_000, "not_json"),
        ("a 5,000-digit number", '{"type": "odom", "t": 1' + "0" * 5000 + "}", "not_json"),
        ("a line longer than max_line_bytes", "x" * (17 * 2**20), "line_too_long"),
    ],
)
def test_a_line_json_cannot_take_is_a_bad_line(lines, clean, row, bad_line, reason):
    i = _index(lines, "truth_pose", 10)  # inserted before it: nothing of the map is lost
    data = _log([*lines[:i], bad_line, *lines[i:]])
    err = _strict_error(data)
    assert (err.line, err.reason) == (i + 1, reason), row
    got, report = _lenient(data)
    _one_skipped(report, i + 1, reason)
    _same_map(got, clean)


def test_a_frame_of_too_many_detections_is_refused_whole_and_fast(lines, clean):
    """One frame of 100,000 detections is refused whole, before any work is spent on it."""
    rng = np.random.default_rng(0)
    many = [{"xy": [float(x), float(y)]} for x, y in rng.uniform(0.5, 2.0, (100_000, 2))]
    i = _index(lines, "detections", 12, with_objects=True)
    data = _edit(lines, i, _set("objects", many))
    err = _strict_error(data)
    assert (err.line, err.reason) == (i + 1, "too_many_detections")
    assert "100000 detections" in err.message and "at most 1000" in err.message
    got, report = _lenient(data)
    _one_skipped(report, i + 1, "too_many_detections")
    assert len(got.objects) == len(clean.objects)


def test_a_byte_order_mark_before_the_meta_line_changes_nothing(lines, clean):
    data = b"\xef\xbb\xbf" + _log(lines)
    assert len(list(read_log(io.BytesIO(data), strict=True))) == len(lines)
    got, report = _lenient(data)
    assert not report.skipped
    _same_map(got, clean)


@pytest.mark.parametrize(
    ("row", "change", "reason", "says"),
    [
        ("latitude 95", lambda m: m["anchor"].update(lat=95.0), "out_of_bounds", "anchor.lat"),
        ("version 2", lambda m: m.update(version=2), "unsupported_version", "version 2"),
        ("row_spacing -1", lambda m: m["field"].update(row_spacing=-1), "out_of_bounds", "row_sp"),
        ("row_spacing 0", lambda m: m["field"].update(row_spacing=0), "out_of_bounds", "row_sp"),
        ("a bad schema", lambda m: m.update(schema={"attributes": 1}), "bad_schema", "attributes"),
    ],
)
def test_a_bad_meta_stops_the_run_in_either_mode(lines, row, change, reason, says):
    data = _edit(lines, 0, change)
    err = _strict_error(data)
    assert (err.line, err.reason, err.fatal) == (1, reason, True) and says in err.message, row
    with pytest.raises(RunError) as stopped:
        run_survey(read_log(io.BytesIO(data), strict=False), WorldModel())
    assert isinstance(stopped.value.__cause__, LogError) and not stopped.value.result.records


def test_a_log_of_only_its_meta_line_has_no_usable_data(lines):
    """An empty map that says so (it was a KeyError "robot 'r1' was never added")."""
    for strict in (True, False):
        result = run_survey(read_log(io.BytesIO(_log(lines[:1])), strict=strict), WorldModel())
        assert not result.usable and len(result.snapshot.objects) == 0
        assert result.issues == {"robot 'r1' is in the meta but has no records": 1}


def test_records_of_a_robot_not_in_meta_and_a_meta_robot_that_never_drives(lines, clean):
    """A robot without a start pose starts at the origin (spec); the meta's robot that never
    drove is reported (both were a KeyError after the whole survey)."""
    moved = [text.replace('"robot": "r1"', '"robot": "r9"') for text in lines]
    got, _ = _lenient(_log(moved))
    assert len(got.objects) == len(clean.objects) and set(got.trajectories) == {"r9"}


def test_a_growth_model_on_a_discrete_attribute_maps_the_survey(lines, clean):
    """The first empty frame maps (it was 'need at least one array to stack')."""

    def growth(meta: dict[str, Any]) -> None:
        meta["schema"]["attributes"]["size"]["time_model"] = {"kind": "growth", "l_max": 0.6}

    got, report = _lenient(_edit(lines, 0, growth))
    assert not report.skipped
    _same_map(got, clean)  # a survey of minutes: growth of 0.04 per day moves no plant
