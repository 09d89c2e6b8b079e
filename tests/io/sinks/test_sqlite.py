"""map.sqlite: exact round trip, atomic overwrite, queryable tables, clear errors."""

from __future__ import annotations

import dataclasses
import sqlite3
from contextlib import closing

import numpy as np
import pytest

from agrislam.io.sinks import sqlite as sqlite_sink
from agrislam.io.sinks.sqlite import FORMAT_VERSION, load_map, save_map
from agrislam.snapshot import MapSnapshot, ObjectMap


def assert_same_snapshot(a: MapSnapshot, b: MapSnapshot) -> None:
    """Every field equal, bit for bit, in the same order."""
    assert a.schema == b.schema
    assert a.anchor == b.anchor
    oa, ob = a.objects, b.objects
    for name in ("ids", "xy", "cov", "n_meas", "interest", "row"):
        x, y = getattr(oa, name), getattr(ob, name)
        assert x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name, strict=True)
    assert list(oa.discrete) == list(ob.discrete)
    for name in oa.discrete:
        np.testing.assert_array_equal(oa.discrete[name], ob.discrete[name], strict=True)
    assert list(oa.continuous) == list(ob.continuous)
    for name, (mean, var) in oa.continuous.items():
        np.testing.assert_array_equal(mean, ob.continuous[name][0], strict=True)
        np.testing.assert_array_equal(var, ob.continuous[name][1], strict=True)
    for trajs_a, trajs_b in (
        (a.trajectories, b.trajectories),
        (a.dead_reckoning, b.dead_reckoning),
    ):
        assert list(trajs_a) == list(trajs_b)
        for robot, ta in trajs_a.items():
            tb = trajs_b[robot]
            assert ta.robot == tb.robot
            np.testing.assert_array_equal(ta.t, tb.t, strict=True)
            np.testing.assert_array_equal(ta.poses, tb.poses, strict=True)
    assert (a.rows is None) == (b.rows is None)
    if a.rows is not None:
        assert a.rows.angle == b.rows.angle
        np.testing.assert_array_equal(a.rows.offsets, b.rows.offsets, strict=True)
    assert (a.interest_surface is None) == (b.interest_surface is None)
    if a.interest_surface is not None:
        sa, sb = a.interest_surface, b.interest_surface
        assert (sa.x0, sa.y0, sa.resolution) == (sb.x0, sb.y0, sb.resolution)
        np.testing.assert_array_equal(sa.values, sb.values, strict=True)
    assert list(a.step_times) == list(b.step_times)
    for stage, t in a.step_times.items():
        np.testing.assert_array_equal(t, b.step_times[stage], strict=True)


def test_round_trip_is_exact(sample_snapshot, tmp_path):
    path = save_map(sample_snapshot, tmp_path / "map.sqlite")
    loaded = load_map(path)
    assert_same_snapshot(sample_snapshot, loaded)
    assert loaded.schema is not None and list(loaded.schema.attributes) == [
        "colour",
        "size",
        "length",
    ]


def test_round_trip_without_optional_parts(snapshot_factory, tmp_path):
    bare = snapshot_factory(schema=False, anchor=False, rows=False, surface=False)
    bare = dataclasses.replace(bare, step_times={}, dead_reckoning={})
    assert_same_snapshot(bare, load_map(save_map(bare, tmp_path / "map.sqlite")))


def test_round_trip_of_an_empty_map_and_nan(sample_snapshot, tmp_path):
    empty = ObjectMap(
        ids=np.zeros(0, dtype=np.int64),
        xy=np.zeros((0, 2)),
        cov=np.zeros((0, 2, 2)),
        n_meas=np.zeros(0, dtype=np.int64),
        interest=np.zeros(0),
        row=np.zeros(0, dtype=np.int64),
        discrete={"colour": np.zeros((0, 7)), "size": np.zeros((0, 3))},
        continuous={"length": (np.zeros(0), np.zeros(0))},
    )
    snap = dataclasses.replace(sample_snapshot, objects=empty)
    assert_same_snapshot(snap, load_map(save_map(snap, tmp_path / "empty.sqlite")))

    interest = sample_snapshot.objects.interest.copy()
    interest[3] = np.nan  # SQLite keeps NaN as NULL; it must come back as NaN
    snap = dataclasses.replace(
        sample_snapshot, objects=dataclasses.replace(sample_snapshot.objects, interest=interest)
    )
    assert_same_snapshot(snap, load_map(save_map(snap, tmp_path / "nan.sqlite")))


def test_tables_answer_a_farmers_question(sample_snapshot, tmp_path):
    path = save_map(sample_snapshot, tmp_path / "map.sqlite")
    size = sample_snapshot.objects.discrete["size"]
    ids = sample_snapshot.objects.ids
    with sqlite3.connect(path) as db:
        (version,) = db.execute("SELECT version FROM format_version").fetchone()
        likely_big = db.execute(
            "SELECT object_id FROM discrete_beliefs WHERE attribute = 'size' AND value = 'big' "
            "AND probability > 0.5 ORDER BY object_id"
        ).fetchall()
        (x,) = db.execute("SELECT x FROM objects WHERE id = ?", (int(ids[4]),)).fetchone()
        n_poses = db.execute(
            "SELECT count(*) FROM poses JOIN trajectories ON poses.trajectory = "
            "trajectories.position WHERE robot = 'husky' AND kind = 'dead_reckoning'"
        ).fetchone()[0]
    assert version == FORMAT_VERSION
    assert [i for (i,) in likely_big] == sorted(ids[size[:, 2] > 0.5].tolist())
    assert x == sample_snapshot.objects.xy[4, 0]
    assert n_poses == len(sample_snapshot.dead_reckoning["husky"].t)


def test_save_overwrites_atomically_and_leaves_no_temp_files(
    sample_snapshot, snapshot_factory, tmp_path
):
    path = tmp_path / "map.sqlite"
    save_map(snapshot_factory(n_rows=5), path)
    save_map(sample_snapshot, path)
    assert len(load_map(path).objects) == 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.sqlite"]

    # a save that fails half way leaves the previous map untouched
    ids = sample_snapshot.objects.ids.copy()
    ids[1] = ids[0]
    broken = dataclasses.replace(
        sample_snapshot, objects=dataclasses.replace(sample_snapshot.objects, ids=ids)
    )
    with pytest.raises(ValueError, match=r"objects.ids are not unique: \[100\]"):
        save_map(broken, path)
    assert_same_snapshot(sample_snapshot, load_map(path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.sqlite"]


def test_loading_something_else_fails_clearly(sample_snapshot, tmp_path):
    with pytest.raises(FileNotFoundError, match="no such map file"):
        load_map(tmp_path / "missing.sqlite")
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE t (x)")
    with pytest.raises(ValueError, match="not an agrislam map"):
        load_map(other)
    text = tmp_path / "notes.sqlite"
    text.write_text("not a database at all, just some text padding " * 20)
    with pytest.raises(ValueError, match="not an agrislam map"):
        load_map(text)
    future = save_map(sample_snapshot, tmp_path / "future.sqlite")
    with sqlite3.connect(future) as db:
        db.execute("UPDATE format_version SET version = ?", (FORMAT_VERSION + 1,))
    with pytest.raises(ValueError, match=f"map format version {FORMAT_VERSION + 1}"):
        load_map(future)


def test_rows_written_a_chunk_at_a_time_are_the_same_tables(sample_snapshot, tmp_path, monkeypatch):
    """Rows go to SQLite CHUNK at a time (no list of Python values per column of 100,000
    plants): every table's content is the same wherever the chunk boundaries fall."""

    def dump(path):
        with closing(sqlite3.connect(path)) as db:
            return list(db.iterdump())

    whole = dump(save_map(sample_snapshot, tmp_path / "whole.sqlite"))
    monkeypatch.setattr(sqlite_sink, "CHUNK", 7)  # 30 objects, 90 belief rows, 60 poses
    assert dump(save_map(sample_snapshot, tmp_path / "chunked.sqlite")) == whole
    assert sum(line.startswith('INSERT INTO "discrete_beliefs"') for line in whole) == 30 * (7 + 3)
