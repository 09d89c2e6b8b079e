"""objects.csv and trajectory.csv: columns, values read back with the csv module, errors."""

from __future__ import annotations

import csv
import dataclasses
import sys
import tracemalloc

import numpy as np
import pytest

from agrislam.config import COLOURS, SIZES, FieldSchema
from agrislam.io.sinks import csv as sinks_csv
from agrislam.io.sinks.csv import write_objects_csv, write_trajectory_csv
from agrislam.snapshot import MapSnapshot, ObjectMap


def read_csv(path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


def two_plants(schema: FieldSchema | None, size_values: int = 3) -> MapSnapshot:
    """Two plants with hand-picked beliefs."""
    size = np.array([[0.2, 0.7, 0.1], [0.05, 0.15, 0.8]])[:, :size_values]
    return MapSnapshot(
        schema=schema,
        objects=ObjectMap(
            ids=np.array([7, 3]),
            xy=np.array([[1.25, -2.5], [10.0, 0.125]]),
            cov=np.array([[[0.04, 0.01], [0.01, 0.09]], [[1e-4, 0.0], [0.0, 4e-4]]]),
            n_meas=np.array([4, 1]),
            interest=np.array([0.3, 0.95]),
            row=np.array([0, -1]),
            discrete={"size": size},
            continuous={"length": (np.array([0.31, 0.12]), np.array([0.0025, 0.01]))},
        ),
        trajectories={},
        dead_reckoning={},
    )


SIZE_SCHEMA = FieldSchema.model_validate(
    {
        "attributes": {
            "size": {"kind": "discrete", "values": SIZES},
            "length": {"kind": "continuous", "min": 0.0, "max": 0.6},
        }
    }
)


def test_objects_csv_header_follows_the_design(sample_snapshot, tmp_path):
    header, rows = read_csv(write_objects_csv(sample_snapshot, tmp_path / "objects.csv"))
    expected = ["id", "x", "y", "cov_xx", "cov_xy", "cov_yy", "n_meas", "interest", "status"]
    expected += ["colour", "colour_p"] + [f"colour_{c}" for c in COLOURS]
    expected += ["size", "size_p"] + [f"size_{s}" for s in SIZES]
    expected += ["length", "length_var"]
    assert header == expected
    assert len(rows) == len(sample_snapshot.objects) == 30


def test_objects_csv_values_match_the_snapshot(sample_snapshot, tmp_path):
    _, rows = read_csv(write_objects_csv(sample_snapshot, tmp_path / "objects.csv"))
    obj = sample_snapshot.objects

    def col(name: str) -> np.ndarray:
        return np.array([float(r[name]) for r in rows])

    assert [int(r["id"]) for r in rows] == obj.ids.tolist()
    np.testing.assert_allclose(col("x"), obj.xy[:, 0], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(col("y"), obj.xy[:, 1], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(col("cov_xy"), obj.cov[:, 0, 1], rtol=1e-8)
    np.testing.assert_allclose(col("cov_yy"), obj.cov[:, 1, 1], rtol=1e-8)
    np.testing.assert_allclose(col("interest"), obj.interest, rtol=1e-8)
    assert [int(r["n_meas"]) for r in rows] == obj.n_meas.tolist()
    assert {r["status"] for r in rows} == {"active"}
    colour = obj.discrete["colour"]
    assert [r["colour"] for r in rows] == [COLOURS[i] for i in colour.argmax(axis=1)]
    np.testing.assert_allclose(col("colour_p"), colour.max(axis=1), rtol=1e-8)
    for j, c in enumerate(COLOURS):
        np.testing.assert_allclose(col(f"colour_{c}"), colour[:, j], rtol=1e-8)
    np.testing.assert_allclose(col("length"), obj.continuous["length"][0], rtol=1e-8)
    np.testing.assert_allclose(col("length_var"), obj.continuous["length"][1], rtol=1e-8)


def test_objects_csv_hand_built_rows(tmp_path):
    _, rows = read_csv(write_objects_csv(two_plants(SIZE_SCHEMA), tmp_path / "o.csv"))
    assert rows[0] == {
        "id": "7",
        "x": "1.25",
        "y": "-2.5",
        "cov_xx": "0.04",
        "cov_xy": "0.01",
        "cov_yy": "0.09",
        "n_meas": "4",
        "interest": "0.3",
        "status": "active",
        "size": "medium",
        "size_p": "0.7",
        "size_small": "0.2",
        "size_medium": "0.7",
        "size_big": "0.1",
        "length": "0.31",
        "length_var": "0.0025",
    }
    assert (rows[1]["id"], rows[1]["size"], rows[1]["size_p"]) == ("3", "big", "0.8")
    assert rows[1]["cov_xx"] == "0.0001"


def test_value_names_with_commas_and_quotes_survive(tmp_path):
    schema = FieldSchema.model_validate(
        {"attributes": {"size": {"kind": "discrete", "values": ['tiny, "x"', "mid", "big"]}}}
    )
    snap = two_plants(schema)
    snap = dataclasses.replace(snap, objects=dataclasses.replace(snap.objects, continuous={}))
    snap.objects.discrete["size"][:] = [[0.8, 0.1, 0.1], [0.1, 0.1, 0.8]]
    header, rows = read_csv(write_objects_csv(snap, tmp_path / "o.csv"))
    assert 'size_tiny, "x"' in header
    assert [r["size"] for r in rows] == ['tiny, "x"', "big"]
    assert rows[0]['size_tiny, "x"'] == "0.8"


AWKWARD = ["with, comma", 'say "hi"', "two\nlines", "carriage\rreturn", "crlf\r\nend", " padded "]


def test_awkward_value_and_robot_names_read_back_with_the_csv_reader(sample_snapshot, tmp_path):
    """Commas, quotes and every kind of line break in names come back as written."""
    n = len(AWKWARD)
    schema = FieldSchema.model_validate(
        {"attributes": {"kind": {"kind": "discrete", "values": AWKWARD}}}
    )
    objects = dataclasses.replace(
        two_plants(None).objects,
        ids=np.arange(n),
        xy=np.zeros((n, 2)),
        cov=np.tile(np.eye(2), (n, 1, 1)),
        n_meas=np.ones(n, dtype=int),
        interest=np.full(n, 0.5),
        row=np.full(n, -1),
        discrete={"kind": 0.9 * np.eye(n) + 0.1 / n},
        continuous={},
    )
    path = write_objects_csv(MapSnapshot(schema, objects, {}, {}), tmp_path / "o.csv")
    with open(path, newline="", encoding="utf-8") as f:
        header, *rows = list(csv.reader(f))
    assert header[9:11] == ["kind", "kind_p"] and header[11:] == [f"kind_{v}" for v in AWKWARD]
    assert [r[9] for r in rows] == AWKWARD
    assert all(len(r) == len(header) for r in rows)

    robot = sample_snapshot.trajectories["spot"]
    odd = {v: dataclasses.replace(robot, robot=v) for v in AWKWARD}
    snap = dataclasses.replace(sample_snapshot, trajectories=odd, dead_reckoning={})
    _, rows = read_csv(write_trajectory_csv(snap, tmp_path / "t.csv"))
    assert [r["robot"] for r in rows[:: len(robot.t)]] == AWKWARD


def test_plain_rows_are_written_unquoted_with_nine_significant_digits(tmp_path):
    path = write_objects_csv(two_plants(SIZE_SCHEMA), tmp_path / "o.csv")
    lines = path.read_bytes().split(b"\n")
    assert lines[1] == b"7,1.25,-2.5,0.04,0.01,0.09,4,0.3,active,medium,0.7,0.2,0.7,0.1,0.31,0.0025"
    assert lines[-1] == b"" and b"\r" not in path.read_bytes()


def test_without_schema_values_are_numbered(tmp_path):
    header, rows = read_csv(write_objects_csv(two_plants(None), tmp_path / "o.csv"))
    assert header[9:14] == ["size", "size_p", "size_0", "size_1", "size_2"]
    assert [r["size"] for r in rows] == ["1", "2"]


def test_schema_and_map_disagreeing_names_the_attribute(tmp_path):
    with pytest.raises(ValueError, match=r"attribute 'size': the schema has 3 values"):
        write_objects_csv(two_plants(SIZE_SCHEMA, size_values=2), tmp_path / "o.csv")


def test_bad_array_shape_is_named(sample_snapshot, tmp_path):
    objects = dataclasses.replace(sample_snapshot.objects, interest=np.zeros(3))
    with pytest.raises(ValueError, match=r"objects.interest has shape \(3,\)"):
        write_objects_csv(dataclasses.replace(sample_snapshot, objects=objects), tmp_path / "o")


def test_empty_map_writes_the_header_only(sample_snapshot, tmp_path):
    empty = ObjectMap(
        ids=np.zeros(0, dtype=int),
        xy=np.zeros((0, 2)),
        cov=np.zeros((0, 2, 2)),
        n_meas=np.zeros(0, dtype=int),
        interest=np.zeros(0),
        row=np.zeros(0, dtype=int),
        discrete={"colour": np.zeros((0, 7)), "size": np.zeros((0, 3))},
        continuous={"length": (np.zeros(0), np.zeros(0))},
    )
    path = write_objects_csv(dataclasses.replace(sample_snapshot, objects=empty), tmp_path / "o")
    header, rows = read_csv(path)
    assert rows == [] and header[:3] == ["id", "x", "y"] and "size_big" in header


def test_trajectory_csv_has_optimised_and_dead_reckoning(sample_snapshot, tmp_path):
    header, rows = read_csv(write_trajectory_csv(sample_snapshot, tmp_path / "trajectory.csv"))
    assert header == ["robot", "t", "x", "y", "theta", "source"]
    n = len(sample_snapshot.trajectories["spot"].t)
    assert len(rows) == 4 * n
    assert [(r["robot"], r["source"]) for r in rows[::n]] == [
        ("spot", "optimised"),
        ("husky", "optimised"),
        ("spot", "dead_reckoning"),
        ("husky", "dead_reckoning"),
    ]
    dr = sample_snapshot.dead_reckoning["husky"]
    got = np.array([[float(r[k]) for k in ("t", "x", "y", "theta")] for r in rows[3 * n :]])
    np.testing.assert_allclose(got, np.column_stack([dr.t, dr.poses]), rtol=1e-8, atol=1e-12)


@pytest.mark.slow
def test_objects_csv_of_100k_objects_has_every_row(snapshot_factory, tmp_path):
    big = snapshot_factory(n_rows=100, per_row=1000, surface=False)
    write_objects_csv(big, tmp_path / "objects.csv")
    with open(tmp_path / "objects.csv", encoding="utf-8") as f:
        assert sum(1 for _ in f) == 100_001


def test_rows_are_formatted_a_chunk_at_a_time(tmp_path, monkeypatch):
    """No column is formatted longer than CHUNK rows, and the Python objects the writer
    holds at its peak are a small share of one string per cell of the whole table: what
    keeps a whole field's table fast and small (the timing is benchmarks/bench_outputs.py)."""
    monkeypatch.setattr(sinks_csv, "CHUNK", 256)
    n = 64 * 256
    rng = np.random.default_rng(0)
    columns = {name: rng.normal(size=n) for name in ("x", "y", "a", "b")}
    columns["id"] = np.arange(n)
    formatted = []
    format_column = sinks_csv._format_column

    def counted(column):
        formatted.append(len(column))
        return format_column(column)

    monkeypatch.setattr(sinks_csv, "_format_column", counted)
    tracemalloc.start()
    try:
        sinks_csv.write_table(columns, tmp_path / "t.csv")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert max(formatted) == 256 and sum(formatted) == n * len(columns)
    one_string_per_cell = sum(sys.getsizeof(v) for c in columns.values() for v in format_column(c))
    assert peak < one_string_per_cell / 4
    with open(tmp_path / "t.csv", encoding="utf-8") as f:
        assert sum(1 for _ in f) == n + 1


def test_rows_formatted_a_chunk_at_a_time_are_the_same_text(sample_snapshot, tmp_path, monkeypatch):
    """Rows are formatted CHUNK at a time (no list of strings per column of 100,000
    plants): the same text wherever the chunk boundaries fall, also for rows quoted whole
    because a name holds a lone carriage return."""
    robot = sample_snapshot.trajectories["spot"]
    odd = {v: dataclasses.replace(robot, robot=v) for v in AWKWARD}
    awkward = dataclasses.replace(sample_snapshot, trajectories=odd)
    whole = [
        write(snap, tmp_path / f"{n}.csv").read_bytes()
        for n, (write, snap) in enumerate(
            [(write_objects_csv, sample_snapshot), (write_trajectory_csv, awkward)]
        )
    ]
    assert b'"carriage\rreturn"' in whole[1]  # quoted: a lone \r would split the row
    monkeypatch.setattr(sinks_csv, "CHUNK", 7)
    chunked = [
        write(snap, tmp_path / f"c{n}.csv").read_bytes()
        for n, (write, snap) in enumerate(
            [(write_objects_csv, sample_snapshot), (write_trajectory_csv, awkward)]
        )
    ]
    assert chunked == whole
