import gzip
import io
import json
import zlib

import numpy as np
import pytest

from agrislam.config import FieldSchema
from agrislam.io.sinks.jsonl import record_to_json, write_log
from agrislam.io.sources.jsonl import REASONS, LogError, read_log
from agrislam.records import (
    Anchor,
    ContinuousMeasurement,
    Detection,
    Detections,
    DiscreteMeasurement,
    FieldPrior,
    Meta,
    Odometry,
    RobotStart,
    TruthObject,
    TruthPose,
)

SCHEMA = {
    "attributes": {
        "type": {"kind": "discrete", "values": ["crop", "weed"]},
        "size": {"kind": "discrete", "values": ["small", "medium", "big"]},
        "length": {"kind": "continuous", "min": 0.0, "max": 0.6},
    }
}
META = {"type": "meta", "version": 1, "schema": SCHEMA}
ODOM = {
    "type": "odom",
    "t": 1.0,
    "robot": "r1",
    "delta": [0.1, 0.0, 0.0],
    "cov": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 4e-6]],
}
DET = {
    "type": "detections",
    "t": 1.0,
    "robot": "r1",
    "objects": [
        {
            "xy": [1.41, -0.22],
            "cov": [[0.04, 0.0], [0.0, 0.004]],
            "attributes": {
                "type": {"value": "crop", "p": 0.91},
                "length": {"value": 0.23, "var": 0.0009},
            },
            "truth_id": "p0117",
        }
    ],
}


def _read(lines, **kw):
    data = "".join(line if isinstance(line, str) else json.dumps(line) + "\n" for line in lines)
    reader = read_log(io.BytesIO(data.encode()), **kw)
    return list(reader), reader.report


def test_spec_example_reads():
    lines = [
        '{"type": "meta", "version": 1, "schema": {"attributes": {'
        '"type": {"kind": "discrete", "values": ["crop", "weed"]},'
        '"size": {"kind": "discrete", "values": ["small", "medium", "big"]},'
        '"health": {"kind": "discrete", "values": ["healthy", "diseased"]},'
        '"length": {"kind": "continuous", "min": 0.0, "max": 0.6}}},'
        '"robots": {"r1": {"start_pose": [0.0, 0.0, 0.0], "start_sigma": [0.01, 0.01, 0.005]}},'
        '"anchor": {"lat": 51.4488, "lon": 5.4905, "h": 20.0, "yaw_deg": 0.0},'
        '"field": {"row_spacing": 1.0, "min_plant_distance": 0.3, "row_angle_deg": null}}\n',
        "# a comment\n",
        "\n",
        '{"type": "odom", "t": 12.30, "robot": "r1", "pose": [3.02, 0.11, 0.015],'
        ' "cov": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 4e-6]]}\n',
        '{"type": "detections", "t": 12.31, "robot": "r1", "sensor": "front", "objects": ['
        '{"xy": [1.41, -0.22], "cov": [[0.04, 0.0], [0.0, 0.004]],'
        ' "attributes": {"type": {"value": "crop", "p": 0.91},'
        ' "size": {"value": "small", "p": 0.55},'
        ' "length": {"value": 0.23, "var": 0.0009}}, "truth_id": "p0117"},'
        '{"range": 3.78, "bearing": -0.257, "sigma_range": 0.15, "sigma_bearing": 0.03},'
        '{"xy": [0.5, 0.1], "label": "crop_small_healthy", "p": 0.8}]}\n',
        '{"type": "detections", "t": 12.5, "robot": "r1", "objects": []}\n',
        '{"type": "truth_pose", "t": 12.50, "robot": "r1", "pose": [3.0, 0.1, 0.01]}\n',
        '{"type": "truth_object", "id": "p0117", "xy": [4.4, -0.1],'
        ' "attributes": {"type": "crop", "size": "small", "health": "healthy", "length": 0.21}}',
    ]  # the last line without a newline is fine
    recs, report = _read(lines)
    assert report.records == 6 and report.lines == 8 and not report.skipped
    meta, odom, dets, empty, tp, to = recs
    assert meta.schema.discrete["size"].values == ["small", "medium", "big"]
    assert meta.anchor == Anchor(51.4488, 5.4905, 20.0, 0.0)
    assert meta.field == FieldPrior(1.0, 0.3, None)
    np.testing.assert_array_equal(meta.robots["r1"].sigma, [0.01, 0.01, 0.005])
    np.testing.assert_array_equal(odom.pose, [3.02, 0.11, 0.015]) and odom.delta is None
    a, b, c = dets.objects
    assert a.attributes["type"] == DiscreteMeasurement("crop", 0.91)
    assert a.attributes["length"] == ContinuousMeasurement(0.23, 0.0009)
    assert a.truth_id == "p0117" and dets.sensor == "front"
    assert (b.range, b.bearing, b.sigma_range, b.sigma_bearing) == (3.78, -0.257, 0.15, 0.03)
    assert b.xy is None and a.range is None
    assert (c.label, c.label_p, c.attributes) == ("crop_small_healthy", 0.8, {})
    assert empty.objects == ()
    np.testing.assert_array_equal(tp.pose, [3.0, 0.1, 0.01])
    assert to.attributes == {"type": "crop", "size": "small", "health": "healthy", "length": 0.21}


def _bad_line_reason(line, prefix=(META,)):
    recs, report = _read([*prefix, line, ODOM], strict=False)
    assert len(recs) == len(prefix) + 1, "the good lines around a bad one are kept"
    assert report.n_skipped == 1
    (reason,) = report.skipped
    with pytest.raises(LogError) as err:
        _read([*prefix, line, ODOM])
    assert err.value.line == len(prefix) + 1 and err.value.reason == reason
    assert f"line {len(prefix) + 1}: {reason}" in str(err.value)
    return reason, err.value.message


def _with(base, **changes):
    out = json.loads(json.dumps(base))
    for key, value in changes.items():
        if value is ...:
            del out[key]
        else:
            out[key] = value
    return out


def _obj(**changes):
    return _with(DET, objects=[_with(DET["objects"][0], **changes)])


@pytest.mark.parametrize(
    ("line", "reason", "says"),
    [
        ('{"type": "odom", "t": 1.0\n', "not_json", "column"),
        ("[1, 2]\n", "not_json", "JSON object"),
        (_with(ODOM, type="imu"), "unknown_type", "'imu'"),
        (_with(ODOM, t=...), "missing_field", "'t'"),
        (_with(ODOM, delta=...), "missing_field", "'pose' and 'delta'"),
        (_with(ODOM, pose=[0, 0, 0]), "bad_value", "exactly one"),
        (_with(DET, objects=...), "missing_field", "'objects'"),
        (_obj(xy=...), "missing_field", "objects[0]"),
        (_with(ODOM, robot=3), "bad_value", "'robot'"),
        (_with(ODOM, t="soon"), "bad_value", "'t'"),
        (_with(ODOM, delta=[0.1, 0.0]), "bad_value", "shape (3,)"),
        ('{"type": "odom", "t": NaN, "robot": "r1", "delta": [0, 0, 0]}\n', "non_finite", "'t'"),
        (
            '{"type": "odom", "t": 1, "robot": "r1", "delta": [0, Infinity, 0]}\n',
            "non_finite",
            "'delta'",
        ),
        (
            _with(ODOM, cov=[[1e-4, 1e-5, 0], [0, 1e-4, 0], [0, 0, 1e-6]]),
            "bad_covariance",
            "symmetric",
        ),
        (
            _with(ODOM, cov=[[1e-4, 0, 0], [0, -1e-4, 0], [0, 0, 1e-6]]),
            "bad_covariance",
            "variance -0.0001 below",
        ),
        (_obj(cov=[[0.01, 0.02], [0.02, 0.01]]), "bad_covariance", "objects[0]"),
        (_obj(attributes={"type": {"value": "crop", "p": 1.2}}), "p_out_of_range", "1.2"),
        (_obj(label="crop_small", p=-0.1), "p_out_of_range", "label"),
        (_obj(attributes={"colour": {"value": "red", "p": 0.9}}), "not_in_schema", "'colour'"),
        (_obj(attributes={"size": {"value": "huge", "p": 0.9}}), "not_in_schema", "'huge'"),
        (_obj(attributes={"size": {"value": "big"}}), "missing_field", "'p'"),
        (_obj(attributes={"length": {"value": 0.2}}), "missing_field", "'var'"),
        (_obj(attributes={"length": {"value": 0.2, "var": -1.0}}), "bad_value", "var"),
        (_obj(attributes={"size": {"value": 2, "p": 0.9}}), "bad_value", "not a string"),
        (_with(ODOM, t=0.5), "time_backwards", "t = 0.5"),
        (
            {"type": "truth_object", "id": "p1", "xy": [0, 0], "attributes": {"size": "tiny"}},
            "not_in_schema",
            "'tiny'",
        ),
        ({"type": "truth_object", "xy": [0, 0]}, "missing_field", "'id'"),
        ({"type": "truth_pose", "t": 2.0, "robot": "r1"}, "missing_field", "'pose'"),
        (b"\xff\xfe not utf-8\n", "bad_encoding", "utf-8"),
    ],
)
def test_every_bad_input_reason(line, reason, says):
    if isinstance(line, bytes):
        data = (json.dumps(META) + "\n" + json.dumps(ODOM) + "\n").encode() + line
        reader = read_log(
            io.BytesIO(data + (json.dumps(_with(ODOM, t=2.0)) + "\n").encode()), strict=False
        )
        assert len(list(reader)) == 3 and dict(reader.report.skipped) == {reason: 1}
        assert says in reader.report.examples[0].message
        return
    prefix = (META, _with(ODOM, t=1.0)) if reason == "time_backwards" else (META,)
    if reason == "time_backwards":
        line = _with(ODOM, t=0.5)
        recs, report = _read([*prefix, line, _with(ODOM, t=2.0)], strict=False)
        assert len(recs) == 3 and dict(report.skipped) == {reason: 1}
        with pytest.raises(LogError, match=f"line 3: {reason}: .*{says}"):
            _read([*prefix, line])
        return
    got, message = _bad_line_reason(line, prefix)
    assert got == reason
    assert says in message


def _stops_in_either_mode(lines):
    """A bad meta line is the survey's contract broken: lenient mode stops at it too."""
    for strict in (True, False):
        with pytest.raises(LogError) as err:
            _read(lines, strict=strict)
        assert err.value.fatal
    return err.value


@pytest.mark.parametrize(
    ("meta", "reason", "says"),
    [
        ({"type": "meta", "version": 2}, "unsupported_version", "version 2"),
        ({"type": "meta", "version": True}, "unsupported_version", "True"),
        (
            {
                "type": "meta",
                "schema": {"attributes": {"size": {"kind": "discrete", "values": ["a"]}}},
            },
            "bad_schema",
            "size",
        ),
        ({"type": "meta", "anchor": {"lat": 95.0, "lon": 5.0}}, "out_of_bounds", "anchor.lat"),
        (  # found by benchmarks/fuzz_logs.py: a TypeError escaped
            {"type": "meta", "schema": {"attributes": {"size": {"kind": ["discrete"]}}}},
            "bad_schema",
            "unknown kind ['discrete']",
        ),
        ({"type": "meta", "field": {"row_spacing": -1}}, "out_of_bounds", "row_spacing"),
        ({"type": "meta", "field": {"row_spacing": 0}}, "out_of_bounds", "row_spacing"),
        ({"type": "meta", "field": {"min_plant_distance": 0}}, "out_of_bounds", "min_plant"),
        ({"type": "meta", "field": {"row_spacing": "1.0"}}, "bad_value", "field: 'row_spacing'"),
        (
            {"type": "meta", "robots": {"r1": {"start_pose": [0, 0, 0], "start_sigma": [0, 1, 1]}}},
            "bad_value",
            "robots.r1.start_sigma[0] is 0",
        ),
        (
            {"type": "meta", "robots": {"r1": {"start_pose": [1e308, 0, 0]}}},
            "out_of_bounds",
            "robots.r1.start_pose[0]",
        ),
    ],
)
def test_a_bad_meta_stops_the_read_in_either_mode(meta, reason, says):
    err = _stops_in_either_mode([meta, ODOM])
    assert (err.line, err.reason) == (1, reason) and says in err.message


def test_a_meta_after_other_records_stops_the_read():
    err = _stops_in_either_mode([META, ODOM, {"type": "meta", "version": 1}])
    assert (err.line, err.reason) == (3, "meta_not_first")


def test_an_undecodable_first_line_meant_as_meta_stops_the_read():
    err = _stops_in_either_mode(['{"type": "meta", "version": 1, \n', ODOM])
    assert (err.line, err.reason) == (1, "not_json")


def test_a_byte_order_mark_before_the_meta_line_is_accepted():
    data = "\ufeff" + json.dumps(META) + "\n" + json.dumps(ODOM) + "\n"
    for strict in (True, False):
        reader = read_log(io.BytesIO(data.encode("utf-8")), strict=strict)
        meta, _ = list(reader)
        assert meta.schema is not None and not reader.report.skipped


def test_every_reason_is_documented():
    assert set(REASONS) >= {
        "not_json",
        "truncated",
        "unknown_type",
        "missing_field",
        "bad_value",
        "non_finite",
        "bad_covariance",
        "p_out_of_range",
        "not_in_schema",
        "time_backwards",
    }


def test_file_cut_off_in_the_middle_of_a_line(tmp_path):
    path = tmp_path / "cut.jsonl"
    full = json.dumps(META) + "\n" + json.dumps(ODOM) + "\n" + json.dumps(DET) + "\n"
    path.write_text(full[: len(full) - 40])  # the last record loses its end and its newline
    with pytest.raises(LogError) as err:
        list(read_log(path))
    assert (err.value.line, err.value.reason) == (3, "truncated")
    assert str(path) in str(err.value)
    reader = read_log(path, strict=False)
    assert len(list(reader)) == 2
    assert dict(reader.report.skipped) == {"truncated": 1}
    assert "1 truncated" in reader.report.summary()


def test_lenient_mode_counts_by_reason_and_keeps_the_rest():
    lines = [
        META,
        "garbage\n",
        ODOM,
        _with(ODOM, t=0.2),
        _with(ODOM, type="x"),
        "garbage\n",
        _with(DET, t=3.0),
    ]
    recs, report = _read(lines, strict=False)
    assert [type(r).__name__ for r in recs] == ["Meta", "Odometry", "Detections"]
    assert dict(report.skipped) == {"not_json": 2, "time_backwards": 1, "unknown_type": 1}
    assert [e.line for e in report.examples] == [2, 4, 5, 6]
    d = report.as_dict()
    assert d["skipped"]["not_json"] == 2 and d["records"] == 3 and d["lines"] == 7


def test_without_a_schema_attributes_are_typed_by_their_value():
    recs, _ = _read(
        [
            _obj(
                attributes={
                    "colour": {"value": "red", "p": 0.9},
                    "height": {"value": 0.3, "var": 0.01},
                }
            )
        ]
    )
    attrs = recs[0].objects[0].attributes
    assert attrs["colour"] == DiscreteMeasurement("red", 0.9)
    assert attrs["height"] == ContinuousMeasurement(0.3, 0.01)


def test_configured_schema_validates_when_meta_has_none():
    line = _obj(attributes={"colour": {"value": "red", "p": 0.9}})
    with pytest.raises(LogError, match="not_in_schema"):
        _read([line], schema=FieldSchema.model_validate(SCHEMA))


def test_time_is_per_robot():
    second = _with(ODOM, t=5.0, delta=[0.2, 0.0, 0.0])  # at the same t: the spec allows it
    recs, _ = _read([_with(ODOM, t=5.0), _with(ODOM, t=1.0, robot="r2"), second])
    assert len(recs) == 3


def test_detections_read_before_the_first_odometry_wait_for_it():
    """A robot's time line starts at its first odometry: detections read before it and
    stamped at or before it go ahead of it (the pose sync places or reports them); one
    stamped after it (a frame copied ahead of the log) is its own bad line, and the odometry
    after it is not taken for time going backwards."""
    ahead = [_with(DET, t=0.5), _with(DET, t=3.0), _with(DET, t=1.0)]
    rest = [ODOM, _with(ODOM, t=2.0), _with(DET, t=3.0), _with(ODOM, t=3.0)]
    recs, report = _read([META, *ahead, *rest], strict=False)
    assert dict(report.skipped) == {"before_odometry": 1}
    (bad,) = report.bad_lines
    assert bad.line == 3 and "read before the robot's first odometry, at t = 1.0" in bad.message
    kinds = [(type(r).__name__[0], r.t) for r in recs[1:]]
    assert kinds == [("D", 0.5), ("D", 1.0), ("O", 1.0), ("O", 2.0), ("D", 3.0), ("O", 3.0)]
    with pytest.raises(LogError) as err:
        _read([META, *ahead, *rest])
    assert (err.value.line, err.value.reason) == (3, "before_odometry")


POSE = _with(ODOM, delta=..., pose=[3.0, 0.1, 0.01])


@pytest.mark.parametrize("strict", [True, False])
@pytest.mark.parametrize("odometry", [ODOM, POSE], ids=["delta", "pose"])
def test_a_re_sent_record_is_dropped_and_counted_in_either_mode(strict, odometry):
    """The same record again (same robot, type, t and content) is a re-sent message: a
    repeated delta would move the robot twice. Dropping it loses nothing, so strict mode
    drops it too; another robot's record in between changes nothing."""
    moved = _with(odometry, t=2.0)
    lines = [META, odometry, DET, _with(odometry, robot="r2"), odometry, DET, moved, moved]
    recs, report = _read(lines, strict=strict)
    assert [(type(r).__name__, r.robot, r.t) for r in recs[1:]] == [
        ("Odometry", "r1", 1.0),
        ("Detections", "r1", 1.0),
        ("Odometry", "r2", 1.0),
        ("Odometry", "r1", 2.0),
    ]
    assert dict(report.skipped) == {"repeated": 3}
    assert report.skipped_table()["line"] == [5, 6, 8]
    assert "robot 'r1': the odom record of line 2 again (t = 1.0)" in str(report.examples[0])


def test_the_same_t_with_another_content_is_no_repeat():
    """Two deltas at one t are two motions (stamps rounded); a repeat is the whole record."""
    lines = [META, ODOM, _with(ODOM, delta=[0.3, 0.0, 0.0]), ODOM, _with(ODOM, cov=...)]
    recs, report = _read(lines)
    assert len(recs) == 5 and not report.skipped


def _records():
    schema = FieldSchema.model_validate(SCHEMA)
    return [
        Meta(
            schema=schema,
            robots={"r1": RobotStart(np.array([1.0, 2.0, 0.1]), np.array([0.1, 0.1, 0.01]))},
            anchor=Anchor(51.4488, 5.4905, 20.0, 12.5),
            field=FieldPrior(1.0, 0.4, None),
        ),
        TruthObject("p1", np.array([0.1, 1 / 3]), {"type": "weed", "size": "big", "length": 0.31}),
        Odometry(0.0, "r1", delta=np.zeros(3), cov=np.eye(3) * 1e-8),
        Odometry(0.5, "r2", pose=np.array([0.1, 0.2, 0.3])),  # r1 keeps to deltas
        TruthPose(0.5, "r1", np.array([0.1, 0.2, np.pi])),
        Detections(
            0.5,
            "r1",
            sensor="front",
            objects=(
                Detection(
                    xy=np.array([1.0, 0.1]),
                    cov=np.array([[0.01, 0.001], [0.001, 0.002]]),
                    attributes={
                        "type": DiscreteMeasurement("crop", 0.9),
                        "length": ContinuousMeasurement(0.2, 1e-3),
                    },
                    truth_id="p1",
                ),
                Detection(range=2.0, bearing=-0.3, sigma_range=0.2, sigma_bearing=0.01),
                Detection(xy=np.array([0.5, 0.0]), label="crop_small", label_p=0.7),
            ),
        ),
        Detections(0.6, "r1"),
    ]


def _same(a, b):
    assert type(a) is type(b)
    for name in a.__slots__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
        elif isinstance(x, tuple) and x and hasattr(x[0], "__slots__"):
            for u, v in zip(x, y, strict=True):
                _same(u, v)
        elif isinstance(x, dict) and x and hasattr(next(iter(x.values())), "pose"):
            assert x.keys() == y.keys()
            for k in x:
                _same(x[k], y[k])
        else:
            assert x == y, name


@pytest.mark.parametrize("name", ["log.jsonl", "log.jsonl.gz"])
def test_write_then_read_gives_the_same_records(tmp_path, name):
    path = tmp_path / name
    assert write_log(_records(), path) == 7
    back = list(read_log(path))
    for a, b in zip(_records(), back, strict=True):
        _same(a, b)
    if name.endswith(".gz"):
        with gzip.open(path) as f:
            assert f.readline().startswith(b'{"type":"meta"')


def test_writer_output_is_the_spec_layout():
    odom = record_to_json(Odometry(1.5, "r1", delta=np.array([0.1, 0, 0]), cov=np.eye(3)))
    assert odom == {
        "type": "odom",
        "t": 1.5,
        "robot": "r1",
        "delta": [0.1, 0.0, 0.0],
        "cov": np.eye(3).tolist(),
    }
    det = record_to_json(_records()[5])
    assert det["objects"][0]["attributes"]["type"] == {"value": "crop", "p": 0.9}
    assert det["objects"][1] == {
        "range": 2.0,
        "bearing": -0.3,
        "sigma_range": 0.2,
        "sigma_bearing": 0.01,
    }
    assert det["objects"][2] == {"xy": [0.5, 0.0], "label": "crop_small", "p": 0.7}


def test_writer_refuses_nan(tmp_path):
    with pytest.raises(ValueError):
        write_log([TruthPose(0.0, "r1", np.array([np.nan, 0, 0]))], tmp_path / "x.jsonl")


def test_reader_streams_without_loading_the_file(tmp_path):
    path = tmp_path / "big.jsonl"
    write_log((Odometry(float(t), "r1", delta=np.zeros(3)) for t in range(5000)), path)
    reader = iter(read_log(path))
    first = next(reader)
    assert first.t == 0.0
    # only the first lines were parsed so far
    assert next(reader).t == 1.0


def _gzip_log(n: int = 400) -> tuple[bytes, bytes]:
    """A log of a meta and `n` odometry lines: its text and the text gzip-compressed."""
    odom = [json.dumps({**ODOM, "t": 1.0 + 0.1 * k}) + "\n" for k in range(n)]
    text = "".join([json.dumps(META) + "\n", *odom]).encode()
    return text, gzip.compress(text, mtime=0)


@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_a_gzip_log_cut_short_gives_every_line_before_the_cut(tmp_path, keep):
    """A .jsonl.gz cut short raised EOFError: now each whole line before the cut is read,
    and the cut is one bad line (where the text stops) saying how much was read."""
    _, packed = _gzip_log()
    cut = packed[: int(len(packed) * keep)]
    path = tmp_path / "cut.jsonl.gz"
    path.write_bytes(cut)
    available = zlib.decompressobj(wbits=31).decompress(cut)  # all a reader could recover
    whole = available.count(b"\n")
    reader = read_log(path, strict=False)
    records = list(reader)
    assert len(records) == whole  # the meta and every whole odometry line
    assert reader.report.skipped == {"truncated": 1}
    (bad,) = reader.report.bad_lines
    assert bad.line == whole + 1
    assert f"breaks off after {len(available):,} bytes of text" in bad.message
    with pytest.raises(LogError, match=rf"cut.jsonl.gz:{whole + 1}: truncated: the file was cut"):
        list(read_log(path, strict=True))


def test_a_gzip_log_without_its_end_or_with_a_wrong_checksum_keeps_every_line(tmp_path):
    text, packed = _gzip_log(n=50)
    lines = text.count(b"\n")
    path = tmp_path / "log.jsonl.gz"
    path.write_bytes(packed[:-8])  # the stream's end: its checksum and length are missing
    reader = read_log(path, strict=False)
    assert len(list(reader)) == lines and reader.report.skipped == {"truncated": 1}
    assert reader.report.bad_lines[0].line == lines + 1
    path.write_bytes(packed[:-8] + b"\0\0\0\0" + packed[-4:])  # a checksum that fails
    reader = read_log(path, strict=False)
    assert len(list(reader)) == lines and reader.report.skipped == {"bad_compression": 1}
    assert "CRC check failed" in reader.report.bad_lines[0].message


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b'{"type": "meta", "version": 1}\n', r"not gzip-compressed: it reads as a plain-text log"),
        (b"BZh91AY&SY" + bytes(100), r"begins with bytes 42 5a 68 39\): .*another compression"),
    ],
)
def test_a_file_named_gz_that_is_no_gzip_is_refused_when_opened(tmp_path, content, says):
    from agrislam.io.sources import open_source

    path = tmp_path / "survey.jsonl.gz"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=says):
        open_source(path)
