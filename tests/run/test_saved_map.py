"""A saved map given to continue (`agrislam run --map`) or to show (`agrislam history`,
run/saved_map.py): a file that cannot be continued is one line with exit code 2 naming what
is wrong, before the output folder is touched; the map of a run that did not finish says to
resume that run; a map without history (an older one) is continued."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from typer.testing import CliRunner

from agrislam.cli import app
from agrislam.io.sinks.jsonl import write_log
from agrislam.io.sinks.sqlite import load_map, write_checkpoint
from agrislam.io.sources import open_source
from agrislam.run.checkpoint import FORMAT

runner = CliRunner()


@pytest.fixture(scope="module")
def mapped(tmp_path_factory) -> tuple[Path, Path]:
    """A 60-plant survey log (enough to re-localise in) and the folder of its finished run."""
    folder = tmp_path_factory.mktemp("mapped")
    log = folder / "survey.jsonl"
    write_log(open_source("sim:?plants=60&seed=2").records(), log)
    result = runner.invoke(app, ["run", str(log), "--out", str(folder / "run")])
    assert result.exit_code == 0, result.output
    return log, folder / "run"


def _one_line(result, code: int, *says: str) -> None:
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output and "please report" not in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output  # no wrapping in tests
    for text in says:
        assert text in result.output, (text, result.output)


def _random(path: Path, good: Path) -> None:
    path.write_bytes(bytes(range(256)) * 40)


def _truncated(path: Path, good: Path) -> None:
    path.write_bytes(good.read_bytes()[: 3 * 4096])


def _corrupt_pages(path: Path, good: Path) -> None:
    data = bytearray(good.read_bytes())
    data[2 * 4096 : 4 * 4096] = bytes(range(256)) * 32  # two b-tree pages overwritten
    path.write_bytes(bytes(data))


def _other_tables(path: Path, good: Path) -> None:
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE plants (id INTEGER, x REAL)")


def _killed_run(path: Path, good: Path) -> None:
    """What a run killed after a checkpoint leaves: its map so far and the checkpoint."""
    entries = {
        "format": FORMAT,
        "state": b"\x80\x05N.",
        "input": json.dumps({"input": "day2.jsonl", "files": {}}).encode(),
        "position": b"812",
    }
    write_checkpoint(path, entries, load_map(good))


def _cut_checkpoint(path: Path, good: Path) -> None:
    """A run killed while it wrote a checkpoint: the map and SQLite's hot journal."""
    path.write_bytes(good.read_bytes())
    path.with_name(path.name + "-journal").write_bytes(b"\xd9\xd5\x05\xf9\x20\xa1\x63\xd7")


@pytest.mark.parametrize(
    ("make", "says"),
    [
        (_random, "is not a SQLite file"),
        (_truncated, "is damaged (database disk image is malformed)"),
        (_corrupt_pages, "is damaged ("),
        (_other_tables, "not an agrislam map (no such table: format_version)"),
        (_killed_run, "agrislam run day2.jsonl --out"),
        (_cut_checkpoint, "is the map of a run that did not finish"),
    ],
)
def test_a_bad_map_is_one_line_before_the_output_folder_is_touched(mapped, tmp_path, make, says):
    log, run = mapped
    bad = tmp_path / "map.sqlite"
    make(bad, run / "map.sqlite")
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("{}")  # an earlier run's output, which --force removes
    result = runner.invoke(app, ["run", str(log), "--map", str(bad), "--out", str(out), "--force"])
    _one_line(result, 2, f"--map {bad}", says)
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]  # nothing touched


def test_the_map_of_a_killed_run_says_which_record_and_how_to_finish_it(mapped, tmp_path):
    log, run = mapped
    bad = tmp_path / "map.sqlite"
    _killed_run(bad, run / "map.sqlite")
    result = runner.invoke(app, ["run", str(log), "--map", str(bad), "--out", str(tmp_path / "o")])
    _one_line(
        result,
        2,
        "did not finish (killed or stopped; it holds its checkpoint at record 812)",
        f"`agrislam run day2.jsonl --out {tmp_path} --resume`",
        "then continue its map",
    )


def test_a_map_inside_out_is_refused_and_kept_with_force(mapped, tmp_path):
    """`run day2 --map D/map.sqlite --out D --force` deleted the map it was to continue."""
    log, run = mapped
    folder = tmp_path / "D"
    folder.mkdir()
    for path in run.iterdir():
        (folder / path.name).write_bytes(path.read_bytes())
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    result = runner.invoke(
        app, ["run", str(log), "--map", str(folder / "map.sqlite"), "--out", str(folder), "--force"]
    )
    _one_line(result, 2, "--map", "is the map.sqlite this run writes in --out", "another --out")
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_a_map_without_history_is_continued(mapped, tmp_path):
    """A map of an older agrislam has no history tables, so no time: its beliefs are taken
    as of the new survey's start (it ended the run with 'time t = nan is not finite')."""
    log, run = mapped
    older = tmp_path / "older.sqlite"
    older.write_bytes((run / "map.sqlite").read_bytes())
    with sqlite3.connect(older) as db:
        db.execute("DROP TABLE surveys")
        db.execute("DROP TABLE plant_history")
    result = runner.invoke(
        app, ["run", str(log), "--map", str(older), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["season"]["localised"], metrics["season"]
    assert (tmp_path / "o" / "changes.csv").exists()


def test_history_of_a_bad_map_is_one_line(tmp_path):
    bad = tmp_path / "map.sqlite"
    _random(bad, bad)
    _one_line(runner.invoke(app, ["history", str(bad)]), 2, f"MAP {bad} is not a SQLite file")
