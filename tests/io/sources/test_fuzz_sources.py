"""The rule for hostile input, as properties: whatever is done to one field or one
line of a valid log, or whatever bytes a file holds, a reader gives a clear error
(`LogError` / `SourceError` in strict mode, `ValueError` for a bag that cannot be opened)
or skips and counts (lenient mode); never another exception. And the pipeline on a
mutated log in lenient mode ends with its outputs (or stops at a bad meta line, the one
record lenient mode does not skip). benchmarks/fuzz_logs.py runs the same mutations
through the whole pipeline ten thousand times."""

from __future__ import annotations

import io
import json
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from agrislam.config import AgrislamConfig
from agrislam.io.sinks.jsonl import record_to_json
from agrislam.io.sinks.rosbag import write_survey_bag
from agrislam.io.sinks.run_folder import OUTPUT_NAMES
from agrislam.io.sources import SourceError, open_source
from agrislam.io.sources.jsonl import REASONS, LogError, read_log
from agrislam.run.pipeline import RunError, run_survey
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator
from agrislam.world import WorldModel
from log_mutations import N_KINDS, as_log, mutate

SMALL = {"field": {"n_plants": 30, "n_rows": 3}, "seed": 2}
FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
mutation = st.tuples(st.integers(0, 10_000), st.integers(0, 10_000), st.integers(0, N_KINDS - 1))


@pytest.fixture(scope="module")
def lines() -> list[str]:
    """The first 120 lines of a 30-plant survey: the meta, the truth, 30 timed groups of
    truth pose, odometry and detections (the fuzzing script takes the whole log)."""
    records = Simulator(SimConfig.model_validate(SMALL)).records()
    return [json.dumps(record_to_json(r)) for r in records][:120]


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("bag") / "small.mcap"
    cfg = SimConfig.model_validate({"field": {"n_plants": 8, "n_rows": 1}, "seed": 2})
    write_survey_bag(list(Simulator(cfg).records()), path)
    return path.read_bytes()


def _read_both_ways(data: bytes) -> None:
    """Strict: all records or a LogError; lenient: all good records, each bad line counted
    by a known reason, or a LogError at a bad meta line."""
    try:
        list(read_log(io.BytesIO(data), strict=True))
    except LogError as err:
        assert err.reason in REASONS and err.line >= 1
    reader = read_log(io.BytesIO(data), strict=False)
    try:
        records = list(reader)
    except LogError as err:
        assert err.fatal, f"lenient mode raised for a line that is no meta: {err}"
        return
    report = reader.report
    assert report.records == len(records)
    assert set(report.skipped) <= set(REASONS)
    assert report.n_skipped == len(report.bad_lines)


@FUZZ
@given(mutation)
def test_a_log_with_one_mutated_field_or_line_reads_clearly(lines, change):
    _read_both_ways(as_log(mutate(lines, *change)))


@FUZZ
@given(st.binary(max_size=3000))
def test_random_bytes_read_as_a_log(data):
    _read_both_ways(data)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.from_type(object).map(repr) | st.text(max_size=200), max_size=20))
def test_random_lines_read_as_a_log(texts):
    _read_both_ways("\n".join(texts).encode("utf-8", "replace"))


def _open_bag(path: Path) -> None:
    """A bag opens (and reads, maybe salvaged) or is a clear ValueError."""
    try:
        source = open_source(path, AgrislamConfig())
    except ValueError as err:
        assert str(err) and "Traceback" not in str(err)
        return
    try:
        list(source.records())
    except SourceError as err:  # only a bad meta record stops a bag
        assert getattr(err, "fatal", False)


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=2000), st.sampled_from([".mcap", ".bag", ".db3"]))
def test_random_bytes_named_as_a_bag(data, suffix):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"random{suffix}"
        path.write_bytes(data)
        _open_bag(path)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 1.0), st.integers(0, 255), st.booleans())
@example(where=0.984375, byte=9, cut=False)  # a damaged definition: Header without stamp
def test_a_cut_or_damaged_mcap_bag_is_salvaged_or_refused(small_bag, where, byte, cut):
    """A bag cut off anywhere (or with one byte changed): what is readable is read."""
    at = int(where * (len(small_bag) - 1))
    data = small_bag[:at] if cut else small_bag[:at] + bytes([byte]) + small_bag[at + 1 :]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "damaged.mcap"
        path.write_bytes(data)
        _open_bag(path)


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutation)
def test_the_pipeline_on_a_mutated_log_ends_with_its_outputs(lines, change):
    data = as_log(mutate(lines, *change))
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        try:
            result = run_survey(read_log(io.BytesIO(data), strict=False), WorldModel(), out)
        except RunError as err:
            assert isinstance(err.__cause__, LogError) and err.__cause__.fatal
            return
        written = {p.name for p in result.outputs}
        assert {"objects.csv", "trajectory.csv", "map.sqlite", "metrics.json"} <= written
        assert written <= set(OUTPUT_NAMES) and not result.output_errors
