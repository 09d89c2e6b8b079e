"""A run's outputs survive: every file is written atomically (a kill -9 leaves the
old file or the new one, whole), map.sqlite passes PRAGMA integrity_check after a kill in
the middle of writing it, a run stopped by an error of the core still writes the map of
what it read, one run at a time per output folder (a lock; a dead owner's lock is taken
over), and an earlier run's outputs are replaced only with --force, leaving none of them,
and never one of the run's own inputs."""

from __future__ import annotations

import csv
import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from agrislam.io.sinks.atomic import atomic_path, is_temporary
from agrislam.io.sinks.run_folder import LOCK_NAME, RunFolder, RunFolderError
from agrislam.io.sinks.sqlite import load_map, save_map
from agrislam.io.sources import open_source
from agrislam.run.pipeline import RunError, run_survey
from agrislam.world import WorldModel
from paths import SRC as SRC_PATH

SMALL = "sim:?plants=30&seed=2"
SRC = str(SRC_PATH)


def _python(code: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": SRC}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], env=env)


def _wait_for(path: Path, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < end, f"{path} never appeared"
        time.sleep(0.02)


def test_an_atomic_write_replaces_the_file_whole_or_not_at_all(tmp_path):
    target = tmp_path / "objects.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half of the new")
        raise RuntimeError("killed")
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["objects.csv"]
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".csv" and is_temporary(tmp.name)
        tmp.write_text("new\n")
    assert target.read_text() == "new\n" and os.listdir(tmp_path) == ["objects.csv"]


def test_map_sqlite_killed_while_it_is_written_stays_a_whole_database(tmp_path, snapshot_factory):
    """kill -9 at several moments of a process that keeps saving a large map: the file is
    always a database that passes integrity_check and loads."""
    source = save_map(snapshot_factory(n_rows=40, per_row=500), tmp_path / "source.sqlite")
    path = tmp_path / "map.sqlite"
    writer = f"""
        from agrislam.io.sinks.sqlite import load_map, save_map
        snapshot = load_map({str(source)!r})
        while True:
            save_map(snapshot, {str(path)!r})
    """
    for delay in (0.05, 0.2, 0.35):
        proc = _python(writer)
        _wait_for(path)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        with sqlite3.connect(path) as db:
            assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        assert len(load_map(path).objects) == 20_000
    source.unlink()
    # the process only ever writes: each kill caught it mid-write, leaving its temporary file
    assert [p for p in tmp_path.iterdir() if is_temporary(p.name)]
    with RunFolder(tmp_path, force=True) as folder:  # the next run clears what kills left
        assert folder.replaced == ["map.sqlite"]
    assert not [p for p in tmp_path.iterdir() if is_temporary(p.name)]


def test_out_must_be_a_folder_that_can_be_written(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(RunFolderError, match="is a file, not a folder"):
        RunFolder(tmp_path / "afile").open()
    with pytest.raises(RunFolderError, match="afile/sub"):
        RunFolder(tmp_path / "afile" / "sub").open()
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(RunFolderError, match="cannot be written"):
            RunFolder(locked / "run").open()


def test_a_second_run_into_a_folder_in_use_refuses_and_a_dead_owners_lock_is_taken(tmp_path):
    holder = f"""
        import time
        from agrislam.io.sinks.run_folder import RunFolder
        RunFolder({str(tmp_path)!r}).open()
        open({str(tmp_path / "held")!r}, "w").close()
        time.sleep(60)
    """
    proc = _python(holder)
    try:
        _wait_for(tmp_path / "held")
        with pytest.raises(RunFolderError, match=f"in use by process {proc.pid} on"):
            RunFolder(tmp_path).open()
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert (tmp_path / LOCK_NAME).exists()  # kill -9: the file stays, the OS lock does not
    (tmp_path / "held").unlink()
    with RunFolder(tmp_path) as folder:
        owner = json.loads((tmp_path / LOCK_NAME).read_text())
        assert owner["pid"] == os.getpid() and folder.path == tmp_path
    assert not (tmp_path / LOCK_NAME).exists()


def test_an_earlier_run_is_replaced_only_with_force_and_leaves_no_file(tmp_path):
    out = tmp_path / "run"
    run_survey(open_source(SMALL), WorldModel(), out)
    with pytest.raises(RunFolderError, match=r"earlier run \(finished: .*use --force"):
        run_survey(open_source(SMALL), WorldModel(), out)
    stale = out / "skipped.csv"  # an older run's file this run does not write
    stale.write_text("line,reason,message\n")
    mine = out / "notes.txt"
    mine.write_text("the user's own file")
    result = run_survey(open_source(SMALL), WorldModel(), out, force=True)
    names = {p.name for p in result.outputs}
    assert not stale.exists() and mine.exists()
    assert {p.name for p in out.iterdir()} == names | {"notes.txt"}


def test_force_refuses_a_folder_whose_outputs_would_replace_an_input(tmp_path):
    """An input by another name (a link) or a bag folder the outputs would go into."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "map.sqlite").write_bytes(b"the saved map")
    os.link(out / "map.sqlite", tmp_path / "day1.sqlite")
    (tmp_path / "alias").symlink_to(out)
    for given in (tmp_path / "day1.sqlite", tmp_path / "alias" / "map.sqlite"):
        with pytest.raises(RunFolderError, match=r"is the map\.sqlite this run writes in --out"):
            RunFolder(out, force=True, inputs={"--map": given}).open()
    with pytest.raises(RunFolderError, match=r"lies inside the input .*outside it"):
        RunFolder(out / "sub", force=True, inputs={"the input": out}).open()
    assert (out / "map.sqlite").read_bytes() == b"the saved map"
    assert sorted(p.name for p in out.iterdir()) == ["map.sqlite"]  # not even locked


def test_a_run_stopped_by_the_core_still_writes_the_map_so_far(tmp_path, monkeypatch):
    calls = {"n": 0}
    step = WorldModel.step

    def failing(self, frame):
        calls["n"] += 1
        if calls["n"] == 40:
            raise ValueError("covariance is not positive definite")  # what used to escape
        return step(self, frame)

    monkeypatch.setattr(WorldModel, "step", failing)
    with pytest.raises(RunError) as err:
        run_survey(open_source(SMALL), WorldModel(), tmp_path / "run")
    result = err.value.result
    assert "stopped after" in str(err.value) and "not positive definite" in str(err.value)
    assert isinstance(err.value.__cause__, ValueError)
    assert {p.name for p in result.outputs} >= {"objects.csv", "map.sqlite", "metrics.json"}
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["run"]["status"].startswith("stopped after")
    with (tmp_path / "run" / "objects.csv").open() as f:
        assert len(list(csv.DictReader(f))) == len(result.snapshot.objects) > 0


def test_one_output_that_fails_costs_that_file_only(tmp_path, monkeypatch):
    import agrislam.run.pipeline as pipeline

    def broken(*args, **kwargs):
        raise MemoryError("no memory for the figure")

    monkeypatch.setattr(pipeline, "write_report", broken)
    result = run_survey(open_source(SMALL), WorldModel(), tmp_path / "run")
    assert result.output_errors == {"report.png": "MemoryError: no memory for the figure"}
    assert not (tmp_path / "run" / "report.png").exists()
    assert (tmp_path / "run" / "map.sqlite").exists()
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["run"]["output_errors"] == result.output_errors
    assert not [p for p in (tmp_path / "run").iterdir() if is_temporary(p.name)]
    assert np.isfinite(metrics["run"]["wall_seconds"])


def test_an_interest_surface_that_cannot_be_made_costs_the_surface_only(tmp_path, monkeypatch):
    import agrislam.run.pipeline as pipeline

    def broken(*args, **kwargs):
        raise MemoryError("no memory for the grid")

    monkeypatch.setattr(pipeline, "interest_surface", broken)
    result = run_survey(open_source(SMALL), WorldModel(), tmp_path / "run")
    assert result.error is None and result.snapshot.interest_surface is None
    assert result.issues["no interest surface: MemoryError: no memory for the grid"] == 1
    assert {"objects.csv", "map.sqlite", "report.png"} <= {p.name for p in result.outputs}


def test_an_interrupt_between_records_writes_the_map_so_far(tmp_path):
    """What the CLI's Ctrl-C and SIGTERM do: stop after the record in hand."""
    seen = {"n": 0}

    def progress():
        seen["n"] += 1
        if seen["n"] == 150:
            raise KeyboardInterrupt

    with pytest.raises(RunError, match="interrupted") as err:
        run_survey(open_source(SMALL), WorldModel(), tmp_path / "run", progress)
    assert isinstance(err.value.__cause__, KeyboardInterrupt)
    assert "objects.csv" in {p.name for p in err.value.result.outputs}


def test_truth_trajectories_straight_from_the_arrays():
    """The report's true trajectories come from the truth's arrays (no object per pose):
    the same as evaluation.truth_trajectories of its poses, also for poses out of order."""
    from agrislam.evaluation.metrics import truth_trajectories
    from agrislam.records import TruthPose
    from agrislam.run.pipeline import Truth

    truth = Truth()
    rng = np.random.default_rng(1)
    times = [(0.0, "a"), (2.0, "b"), (1.0, "a"), (1.0, "a"), (0.5, "b"), (3.0, "a")]
    records = [TruthPose(t=t, robot=robot, pose=rng.normal(size=3)) for t, robot in times]
    for record in records:
        truth.add_pose(record)
    got, expected = truth.trajectories(), truth_trajectories(records)
    assert list(got) == list(expected) == ["a", "b"]
    for robot, trajectory in expected.items():
        np.testing.assert_array_equal(got[robot].t, trajectory.t, strict=True)
        np.testing.assert_array_equal(got[robot].poses, trajectory.poses, strict=True)


def test_a_released_world_lets_its_state_go_before_the_outputs(tmp_path, monkeypatch):
    """release_world (the CLI's run): the outputs are the same, the back end and the
    object table are freed before they are written (their memory is the outputs' to
    reuse), and a later use of the world says that it was released."""
    import weakref

    from agrislam.run import pipeline

    kept = run_survey(open_source(SMALL), WorldModel(), tmp_path / "kept")
    world = WorldModel()
    parts, alive_at_outputs = [], []
    finish = world.finish

    def finish_and_watch():  # the survey's stages, as they end it
        parts.extend(weakref.ref(p) for p in (world.stages, world.backend, world.objects))
        return finish()

    monkeypatch.setattr(world, "finish", finish_and_watch)

    def write_outputs(*args, **kwargs):
        alive_at_outputs.extend(part() is not None for part in parts)
        return write(*args, **kwargs)

    def interest_surface(*args, **kwargs):
        alive_at_outputs.extend(part() is not None for part in parts)
        return surface(*args, **kwargs)

    write, surface = pipeline.write_outputs, pipeline.interest_surface
    monkeypatch.setattr(pipeline, "write_outputs", write_outputs)
    monkeypatch.setattr(pipeline, "interest_surface", interest_surface)
    released = run_survey(open_source(SMALL), world, tmp_path / "released", release_world=True)
    assert alive_at_outputs == [False] * 6  # at the surface, then at the outputs
    np.testing.assert_array_equal(
        released.snapshot.interest_surface.values, kept.snapshot.interest_surface.values
    )
    assert [p.name for p in released.outputs] == [p.name for p in kept.outputs]
    for name in ("objects.csv", "trajectory.csv"):
        assert (tmp_path / "released" / name).read_text() == (tmp_path / "kept" / name).read_text()
    with pytest.raises(RuntimeError, match="was released once the run"):
        world.snapshot()
    with pytest.raises(RuntimeError, match="'stages' was released"):
        len(world.objects)
