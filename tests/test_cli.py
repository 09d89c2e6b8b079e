"""The command line end to end: a small simulated field through `agrislam simulate`, the
recorded log through `agrislam run`, the config, and bad config values."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from agrislam import __version__
from agrislam.cli import app
from agrislam.config import AgrislamConfig

runner = CliRunner()


def test_version_and_help():
    assert __version__ in runner.invoke(app, ["--version"]).output
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("simulate", "run", "config"):
        assert command in result.output


def test_config_defaults_round_trip(tmp_path):
    result = runner.invoke(app, ["config", "--defaults"])
    assert result.exit_code == 0
    data = json.loads(result.output)
    assert AgrislamConfig.model_validate(data) == AgrislamConfig()
    assert data["association"]["w_sem"] == 0.3  # the paper's value


def test_a_bad_config_value_names_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("association:\n  w_sem: 1.7\n")
    result = runner.invoke(app, ["config", str(bad)])
    assert result.exit_code != 0
    assert "w_sem" in str(result.exception) or "w_sem" in result.output


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    log = out / "survey.jsonl"
    args = ["simulate", "--plants", "150", "--seed", "3", "--out", str(out), "--record", str(log)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return out, log


def test_simulate_writes_every_output(small_run):
    out, log = small_run
    for name in ("objects.csv", "trajectory.csv", "map.sqlite", "map.geojson", "report.png"):
        assert (out / name).stat().st_size > 0, name
    assert log.stat().st_size > 0
    geo = json.loads((out / "map.geojson").read_text())
    assert geo["type"] == "FeatureCollection" and geo["features"]


def test_simulate_maps_the_field_well(small_run):
    out, _ = small_run
    m = json.loads((out / "metrics.json").read_text())
    objects = m["objects"]
    assert objects["mapped_fraction"] >= 0.95
    assert objects["duplicates"] + objects["false_objects"] <= 0.03 * objects["n_truth"]
    assert m["attributes"]["colour"]["accuracy"] >= 0.97
    assert m["attributes"]["size"]["accuracy"] >= 0.90
    optimised = m["trajectory"]["optimised"]["rms_position"]
    assert optimised <= 0.15
    assert optimised < m["trajectory"]["dead_reckoning"]["rms_position"]


def test_run_on_the_recorded_log_gives_the_same_map(small_run, tmp_path):
    out, log = small_run
    result = runner.invoke(app, ["run", str(log), "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "objects.csv").read_text() == (out / "objects.csv").read_text()


def test_run_stops_at_a_bad_line_in_strict_mode_and_skips_it_in_lenient(small_run, tmp_path):
    _, log = small_run
    lines = log.read_text().splitlines()
    broken = tmp_path / "broken.jsonl"
    broken.write_text("\n".join([*lines[:50], "{not json", *lines[50:]]) + "\n")
    strict = runner.invoke(app, ["run", str(broken), "--strict", "--out", str(tmp_path / "s")])
    assert strict.exit_code == 1 and "51" in strict.output
    lenient = runner.invoke(app, ["run", str(broken), "--out", str(tmp_path / "l")])
    assert lenient.exit_code == 0 and "1 bad line" in lenient.output


def test_the_simulated_survey_as_an_mcap_bag_gives_the_same_map(small_run, tmp_path):
    """simulate --record sim.mcap, then run the bag: the map equals the JSONL run's."""
    out, _ = small_run
    bag = tmp_path / "sim.mcap"
    args = ["simulate", "--plants", "150", "--seed", "3", "--out", str(tmp_path / "a")]
    assert runner.invoke(app, [*args, "--record", str(bag)]).exit_code == 0
    result = runner.invoke(app, ["run", str(bag), "--out", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    from agrislam.sinks.sqlite import load_map

    jsonl_map, bag_map = load_map(out / "map.sqlite"), load_map(tmp_path / "b" / "map.sqlite")
    assert np.array_equal(jsonl_map.objects.ids, bag_map.objects.ids)
    np.testing.assert_allclose(bag_map.objects.xy, jsonl_map.objects.xy, atol=1e-6)
    for name, belief in jsonl_map.objects.discrete.items():
        np.testing.assert_allclose(bag_map.objects.discrete[name], belief, atol=1e-9)
    assert (tmp_path / "b" / "map.mcap").stat().st_size > 0


def test_run_on_a_sim_uri_is_simulate(small_run, tmp_path):
    """The simulator is one more source: `run sim:?...` maps what `simulate` maps."""
    out, _ = small_run
    result = runner.invoke(app, ["run", "sim:?plants=150&seed=3", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "sim:?plants=150&seed=3&preset=colour_size: 406 Detections" in result.output
    assert (tmp_path / "objects.csv").read_text() == (out / "objects.csv").read_text()


def test_run_reads_the_bag_and_sim_sections_of_one_config(small_run, tmp_path):
    _, log = small_run
    config = tmp_path / "c.yaml"
    config.write_text("bag:\n  odometry_form: delta\nsim:\n  seed: 3\n")
    result = runner.invoke(app, ["run", str(log), "-c", str(config), "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    config.write_text("sim:\n  field:\n    n_rows: 0\n")  # each source checks its own section
    result = runner.invoke(app, ["run", "sim:?plants=20", "-c", str(config)])
    assert result.exit_code == 2 and "field.n_rows" in result.output


def test_run_names_what_it_reads_when_the_input_is_unknown(tmp_path):
    (tmp_path / "survey.txt").write_text("")
    result = runner.invoke(app, ["run", str(tmp_path / "survey.txt")])
    assert result.exit_code == 2
    assert "not a kind of input agrislam reads" in result.output and ".jsonl" in result.output
    result = runner.invoke(app, ["run", str(tmp_path / "missing.jsonl")])
    assert result.exit_code == 2 and "no such file" in result.output
