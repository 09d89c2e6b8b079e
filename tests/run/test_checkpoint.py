"""Checkpoints and resume (run/checkpoint.py): a world saved and read back carries on exactly
like another copy of the same save; a run killed with SIGKILL leaves its last checkpoint
readable and resumes to the map of a run never stopped; resume refuses a checkpoint of
another input or config, and starts over when there is none."""

from __future__ import annotations

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

from agrislam.config import AgrislamConfig, CheckpointConfig
from agrislam.io.sinks.jsonl import write_log
from agrislam.io.sinks.sqlite import load_map, read_checkpoint
from agrislam.io.sources import open_source
from agrislam.io.sources.sync import synchronise
from agrislam.records import TruthObject, TruthPose
from agrislam.run import checkpoint as checkpoint_module
from agrislam.run.checkpoint import (
    Checkpoints,
    InputFingerprint,
    ResumeError,
    RunState,
    config_identity,
    dump_state,
    load_state,
)
from agrislam.run.pipeline import RunError, run_survey
from agrislam.world import WorldModel
from paths import SRC as SRC_PATH

SRC = str(SRC_PATH)
EVERY = 20  # frames between checkpoints (the 40-plant survey has 178 frames)


def config(**more: object) -> AgrislamConfig:
    return AgrislamConfig.model_validate({"checkpoint": {"every_frames": EVERY}, **more})


@pytest.fixture(scope="module", autouse=True)
def every_frames_apart():
    """Checkpoints EVERY frames apart, however large the state they save."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(checkpoint_module, "FRAMES_PER_MB", 0.0)
        yield


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("log") / "survey.jsonl"
    write_log(list(open_source("sim:?plants=40&seed=3").records()), path)
    return path


@pytest.fixture(scope="module")
def uninterrupted(log, tmp_path_factory):
    """The survey run to its end with checkpoints."""
    out = tmp_path_factory.mktemp("uninterrupted")
    result = _run(log, out, config())
    assert result.checkpoints["taken"] == 178 // EVERY
    return result


def _checkpoints(log: Path, out: Path, cfg: AgrislamConfig) -> Checkpoints:
    identity = config_identity(cfg, strict=False)
    return Checkpoints(out / "map.sqlite", InputFingerprint(log), identity, cfg.checkpoint)


def _run(log: Path, out: Path, cfg: AgrislamConfig, resume: bool = False, progress=None):
    checkpoints = _checkpoints(log, out, cfg)
    source = open_source(log, cfg)
    return run_survey(
        source, WorldModel(cfg), out, progress, checkpoints=checkpoints, resume=resume
    )


def _same_map(a, b) -> None:
    np.testing.assert_array_equal(a.objects.ids, b.objects.ids)
    np.testing.assert_allclose(a.objects.xy, b.objects.xy, rtol=0.0, atol=1e-9)
    for robot, trajectory in a.trajectories.items():
        np.testing.assert_allclose(trajectory.poses, b.trajectories[robot].poses, atol=1e-9)


@pytest.mark.parametrize(
    "backend",
    [
        {"advanced": {"slam": {"window": 100}}},
        {"advanced": {"slam": {"window": 0}}},
        {"slam": {"backend": "batch"}},
    ],
)
def test_a_saved_world_read_back_twice_carries_on_the_same_both_times(log, backend):
    """What resume relies on: every part of the world pickles (a part that cannot fails
    here), and two worlds read back from one save map the rest of the survey alike."""
    cfg = config(**backend)
    records = [
        r
        for r in synchronise(open_source(log, cfg).records())
        if not isinstance(r, (TruthObject, TruthPose))
    ]
    half = len(records) // 2
    world = WorldModel(cfg)
    for record in records[:half]:
        world.process(record)
    blob = dump_state(RunState(world, None))
    copies = [load_state(blob).world for _ in range(2)]
    for copy in copies:
        for record in records[half:]:
            copy.process(record)
        copy.finish()
    _same_map(*(c.snapshot() for c in copies))
    assert len(copies[0].active_ids()) > 30


def test_a_run_killed_with_sigkill_leaves_a_readable_checkpoint_and_resumes_to_the_same_map(
    log, uninterrupted, tmp_path
):
    out = tmp_path / "run"
    runner = f"""
        import time
        from agrislam.run.checkpoint import Checkpoints, InputFingerprint, config_identity
        from agrislam.config import AgrislamConfig, CheckpointConfig
        from agrislam.run.pipeline import run_survey
        from agrislam.io.sources import open_source
        from agrislam.world import WorldModel
        import agrislam.run.checkpoint
        agrislam.run.checkpoint.FRAMES_PER_MB = 0.0
        cfg = AgrislamConfig.model_validate({{"checkpoint": {{"every_frames": {EVERY}}}}})
        log, out = {str(log)!r}, {str(out)!r}
        checkpoints = Checkpoints(
            __import__("pathlib").Path(out) / "map.sqlite", InputFingerprint(log),
            config_identity(cfg, strict=False), cfg.checkpoint,
        )
        run_survey(open_source(log, cfg), WorldModel(cfg), out, lambda: time.sleep(0.01),
                   checkpoints=checkpoints)
    """
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(runner)], env=env)
    try:
        end = time.monotonic() + 120
        while _position(out / "map.sqlite") < 2 * EVERY:  # past its second checkpoint
            assert proc.poll() is None and time.monotonic() < end, "no checkpoint in time"
            time.sleep(0.05)
        time.sleep(0.3)  # somewhere after it, maybe inside the next one
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert not (out / "metrics.json").exists()  # killed, not finished
    with sqlite3.connect(out / "map.sqlite") as db:
        assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    assert len(load_map(out / "map.sqlite").objects) > 10  # the map of the last checkpoint
    result = _run(log, out, config(), resume=True)
    assert result.checkpoints["resumed_at_record"] >= 2 * EVERY
    _same_map(uninterrupted.snapshot, result.snapshot)
    _same_map(uninterrupted.snapshot, load_map(out / "map.sqlite"))
    assert read_checkpoint(out / "map.sqlite") is None  # a finished run's map keeps none


def _position(path: Path) -> int:
    """The record the checkpoint in `path` was taken at (0: none yet)."""
    try:
        entries = read_checkpoint(path) if path.exists() else None
    except sqlite3.Error:  # being written for the first time
        return 0
    return int(entries["position"]) if entries and "position" in entries else 0


def _stopped_run(log: Path, out: Path, after: int) -> None:
    """A run stopped (as by Ctrl-C) after `after` records: it keeps its last checkpoint."""
    seen = [0]

    def interrupt() -> None:
        seen[0] += 1
        if seen[0] == after:
            raise KeyboardInterrupt

    with pytest.raises(RunError, match="interrupted"):
        _run(log, out, config(), progress=interrupt)


def test_a_stopped_run_resumes_to_the_same_map(log, uninterrupted, tmp_path):
    _stopped_run(log, tmp_path, after=300)
    entries = read_checkpoint(tmp_path / "map.sqlite")
    assert entries is not None and 0 < int(entries["position"]) < 300
    result = _run(log, tmp_path, config(), resume=True)
    _same_map(uninterrupted.snapshot, result.snapshot)
    assert result.health.rows() == uninterrupted.health.rows()  # kept in the checkpoint


def test_resume_refuses_a_checkpoint_of_another_log_or_config(log, tmp_path):
    _stopped_run(log, tmp_path, after=300)
    with pytest.raises(ResumeError, match="another config"):
        _run(log, tmp_path, config(advanced={"maintenance": {"prune": False}}), resume=True)
    other = tmp_path / "other.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    changed = lines[3].replace("1", "2", 1)  # one digit of an early record
    assert changed != lines[3]
    other.write_text("".join([*lines[:3], changed, *lines[4:]]))
    with pytest.raises(ResumeError, match=r"another input than .*other.jsonl \(the first"):
        _run(other, tmp_path, config(), resume=True)
    other.write_text("".join(lines[:100]))
    with pytest.raises(ResumeError, match="the file is shorter than the"):
        _run(other, tmp_path, config(), resume=True)
    assert read_checkpoint(tmp_path / "map.sqlite") is not None  # refused: nothing touched
    # a checkpoint of an older version (its state is of another shape) is refused, not misread
    with sqlite3.connect(tmp_path / "map.sqlite") as db:
        older = b"agrislam-checkpoint 1"
        db.execute("UPDATE checkpoint SET value = ? WHERE key = 'format'", (older,))
    with pytest.raises(ResumeError, match="a checkpoint of another version"):
        _run(log, tmp_path, config(), resume=True)


def test_resume_without_a_checkpoint_starts_from_the_first_record(log, uninterrupted, tmp_path):
    out = tmp_path / "fresh"
    result = _run(log, out, config(), resume=True)
    assert result.checkpoints["resumed_at_record"] is None
    _same_map(uninterrupted.snapshot, result.snapshot)
    with pytest.raises(ResumeError, match="finished run, with no checkpoint"):
        _run(log, out, config(), resume=True)


def test_the_cli_takes_resume_but_not_with_force(log, tmp_path):
    from typer.testing import CliRunner

    from agrislam.cli import app

    args = ["run", str(log), "--out", str(tmp_path / "run"), "--resume"]
    result = CliRunner().invoke(app, [*args, "--force"])
    assert result.exit_code == 2 and "give one" in result.output
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "no checkpoint in --out to resume from" in result.output
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "finished run, with no checkpoint" in result.output


def test_checkpoints_grow_apart_with_the_state_they_save(tmp_path, monkeypatch):
    monkeypatch.setattr(checkpoint_module, "FRAMES_PER_MB", 1000.0)
    every = CheckpointConfig(every_frames=10)
    checkpoints = Checkpoints(tmp_path / "map.sqlite", InputFingerprint("sim:"), "", every)
    assert not checkpoints.due(9) and checkpoints.due(10)
    checkpoints._after(10, b"x" * 5_000)  # 5 kB: 5 frames, less than every_frames
    assert not checkpoints.due(19) and checkpoints.due(20)
    checkpoints._after(20, b"x" * 50_000)  # 50 kB: 50 frames
    assert not checkpoints.due(69) and checkpoints.due(70)
    never = CheckpointConfig(every_frames=0)
    assert not Checkpoints(tmp_path / "m", InputFingerprint("sim:"), "", never).due(1000)


def test_force_removes_the_journal_of_a_checkpoint_cut_by_a_kill(tmp_path):
    """A hot journal left beside a new map.sqlite would be rolled back into it."""
    from agrislam.io.sinks.run_folder import RunFolder, RunFolderError

    (tmp_path / "map.sqlite-journal").write_bytes(b"journal of a killed checkpoint")
    with pytest.raises(RunFolderError, match=r"map\.sqlite-journal"):
        RunFolder(tmp_path).open()
    with RunFolder(tmp_path, force=True):
        assert not (tmp_path / "map.sqlite-journal").exists()


def test_a_checkpoint_that_cannot_be_written_is_an_issue_and_the_run_goes_on(
    log, uninterrupted, tmp_path, monkeypatch
):
    def full_disk(*args, **kwargs):
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr("agrislam.run.checkpoint.write_checkpoint", full_disk)
    result = _run(log, tmp_path, config())
    assert result.issues["checkpoint not written: OperationalError: database or disk is full"]
    _same_map(uninterrupted.snapshot, result.snapshot)


def test_a_state_that_cannot_be_saved_turns_checkpoints_off_and_the_run_goes_on(
    log, uninterrupted, tmp_path, monkeypatch
):
    """A part added to the world that pickle refuses must not stop users' runs (the first
    test of this file is what fails for it)."""
    real_step = WorldModel.step

    def step(self, frame):
        self.unsaveable = lambda: None  # pickle cannot take a lambda
        return real_step(self, frame)

    monkeypatch.setattr(WorldModel, "step", step)
    result = _run(log, tmp_path, config())
    assert any(k.startswith("checkpoints off: the state cannot be saved") for k in result.issues)
    assert result.checkpoints["taken"] == 0 and len(result.snapshot.objects.ids) > 30
