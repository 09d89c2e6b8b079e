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


def test_config_defaults_show_the_users_fields_and_all_of_them_round_trip(tmp_path):
    result = runner.invoke(app, ["config", "--defaults"])
    assert result.exit_code == 0
    data = json.loads(result.output)
    assert "advanced" not in data
    assert data["association"]["w_sem"] == 0.3  # the paper's value
    users = [(s, k) for s, v in data.items() if isinstance(v, dict) for k in v]
    assert 15 <= len(users) <= 25
    assert AgrislamConfig.model_validate(data) == AgrislamConfig()
    every = json.loads(runner.invoke(app, ["config", "--defaults", "--all"]).output)
    assert every["advanced"]["association"]["landmark_gate_chi2"] == 9.21
    assert AgrislamConfig.model_validate(every) == AgrislamConfig()


def test_a_config_of_the_older_layout_reads_with_warnings_naming_the_new_place(tmp_path):
    old = tmp_path / "old.yaml"
    old.write_text(
        "association:\n  w_sem: 0.5\n  gate_chi2: 4.0\n  index_margin: 0.5\n"
        "slam:\n  window: 0\nmaintenance:\n  prune: false\n"
    )
    with pytest.warns(FutureWarning) as caught:
        cfg = AgrislamConfig.load(old)
    said = " ".join(str(w.message) for w in caught)
    assert "association.gate_chi2 is now advanced.association.gate_chi2" in said
    assert "slam.window is now advanced.slam.window" in said
    assert "maintenance is now advanced.maintenance" in said
    assert "association.index_margin is ignored" in said
    assert cfg.association.w_sem == 0.5 and cfg.advanced.association.gate_chi2 == 4.0
    assert cfg.advanced.slam.window == 0 and cfg.advanced.maintenance.prune is False
    new = AgrislamConfig.model_validate(
        {
            "association": {"w_sem": 0.5},
            "advanced": {
                "association": {"gate_chi2": 4.0},
                "slam": {"window": 0},
                "maintenance": {"prune": False},
            },
        }
    )
    assert cfg == new


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
    from agrislam.io.sinks.sqlite import load_map

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


# ----------------------------------------------------------------------- errors for people


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    from agrislam.io.sinks.jsonl import write_log
    from agrislam.sim.config import SimConfig
    from agrislam.sim.simulator import Simulator

    log = tmp_path_factory.mktemp("log") / "small.jsonl"
    cfg = SimConfig.model_validate({"field": {"n_plants": 30, "n_rows": 3}, "seed": 2})
    write_log(Simulator(cfg).records(), log)
    return log


def _one_message(result, code: int, *says: str) -> None:
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    for text in says:
        assert text in result.output.replace("\n", " "), (text, result.output)


@pytest.mark.parametrize(
    ("config", "says"),
    [
        ("sensor:\n  detection_sigma_depth: -0.1\n", "sensor.detection_sigma_depth: Input should"),
        ("association:\n  gate_chii: 9\n", "association.gate_chii: unknown key"),
        (
            "advanced:\n  association:\n    gate_chi2: .nan\n",
            "advanced.association.gate_chi2: Input should be a finite",
        ),
        ("association: [1,\n", "not valid YAML at line 2"),
    ],
)
def test_a_bad_config_is_one_message_without_a_traceback(small_log, tmp_path, config, says):
    path = tmp_path / "bad.yaml"
    path.write_text(config)
    result = runner.invoke(app, ["run", str(small_log), "-c", str(path), "-o", str(tmp_path / "o")])
    _one_message(result, 2, says)
    assert not (tmp_path / "o").exists()  # checked before anything ran
    _one_message(runner.invoke(app, ["config", str(path)]), 2, says)


def test_debug_shows_the_traceback(small_log, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("association:\n  w_sem: 7\n")
    result = runner.invoke(app, ["--debug", "run", str(small_log), "-c", str(path)])
    assert result.exit_code != 0 and isinstance(result.exception, ValueError)


@pytest.mark.parametrize(
    ("name", "content", "says"),
    [
        ("random.bag", bytes(range(256)) * 20, "is not a ROS 1 bag, or a damaged one"),
        ("empty.mcap", b"", "is empty"),
        ("random.db3", b"SQLite format 2\x00" * 100, "is not a rosbag2 SQLite bag"),
        ("folder", None, "a rosbag2 folder needs its metadata.yaml"),
    ],
)
def test_an_unreadable_bag_is_one_message(tmp_path, name, content, says):
    path = tmp_path / name
    if content is None:
        path.mkdir()
        (path / "folder_0.mcap").write_bytes(b"\x89MCAP0\r\n")
    else:
        path.write_bytes(content)
    _one_message(runner.invoke(app, ["run", str(path), "-o", str(tmp_path / "o")]), 2, says)


def test_out_is_checked_before_mapping(small_log, tmp_path):
    (tmp_path / "afile").write_text("x")
    result = runner.invoke(app, ["run", str(small_log), "-o", str(tmp_path / "afile")])
    _one_message(result, 2, "is a file, not a folder")
    out = str(tmp_path / "run")
    assert runner.invoke(app, ["run", str(small_log), "-o", out]).exit_code == 0
    again = runner.invoke(app, ["run", str(small_log), "-o", out])
    _one_message(again, 2, "holds the outputs of an earlier run", "use --force")
    forced = runner.invoke(app, ["run", str(small_log), "-o", out, "--force"])
    assert forced.exit_code == 0 and "--force: replaced the earlier run's" in forced.output


def test_strict_stops_at_the_line_and_keeps_the_map_so_far(small_log, tmp_path):
    lines = small_log.read_text().splitlines()
    broken = tmp_path / "broken.jsonl"
    record = json.loads(lines[100])
    record["t"] = "soon"
    lines[100] = json.dumps(record)
    broken.write_text("\n".join(lines) + "\n")
    strict = runner.invoke(app, ["run", str(broken), "--strict", "-o", str(tmp_path / "s")])
    _one_message(strict, 1, "broken.jsonl:101: bad_value: 't' must be a number", "--lenient")
    assert "frames before it is in" in strict.output
    assert (tmp_path / "s" / "objects.csv").exists()
    lenient = runner.invoke(app, ["run", str(broken), "-o", str(tmp_path / "l")])
    assert lenient.exit_code == 0 and "listed in skipped.csv" in lenient.output
    skipped = (tmp_path / "l" / "skipped.csv").read_text().splitlines()
    assert skipped[0] == "line,reason,message" and skipped[1].startswith("101,bad_value,")
    metrics = json.loads((tmp_path / "l" / "metrics.json").read_text())
    assert metrics["input"]["skipped"] == {"bad_value": 1}


def test_a_log_without_usable_data_says_so(small_log, tmp_path):
    meta_only = tmp_path / "meta.jsonl"
    meta_only.write_text(small_log.read_text().splitlines()[0] + "\n")
    result = runner.invoke(app, ["run", str(meta_only), "-o", str(tmp_path / "o")])
    _one_message(result, 1, "no usable data")


def test_a_bad_meta_stops_lenient_mode_too(small_log, tmp_path):
    lines = small_log.read_text().splitlines()
    bad = tmp_path / "bad_meta.jsonl"
    meta = json.loads(lines[0])
    meta["anchor"]["lat"] = 95.0
    bad.write_text("\n".join([json.dumps(meta), *lines[1:]]))
    result = runner.invoke(app, ["run", str(bad), "-o", str(tmp_path / "o")])
    _one_message(result, 1, "bad_meta.jsonl:1: out_of_bounds: anchor.lat", "contract")
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------- no option deletes an input


@pytest.mark.parametrize(
    ("command", "named"),
    [
        (["run", "{log}", "-c", "{out}/metrics.json", "--force"], "--config"),
        (["simulate", "--plants", "20", "--record", "{out}/map.mcap", "--force"], "--record"),
    ],
)
def test_force_never_replaces_an_input_of_the_run(small_log, tmp_path, command, named):
    """--force removes an earlier run's outputs: an input among them is refused, untouched."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    (out / "map.mcap").write_bytes(b"\x89MCAP0\r\n")
    args = [a.format(log=small_log, out=out) for a in command]
    result = runner.invoke(app, [*args, "--out", str(out)])
    _one_message(result, 2, named, "this run writes in --out", "(nothing was changed)")
    assert (out / "metrics.json").read_text() == "{}"
    assert (out / "map.mcap").read_bytes() == b"\x89MCAP0\r\n"


def test_a_season_into_an_earlier_one_is_refused_before_its_logs_are_written(tmp_path):
    log = tmp_path / "day_000.jsonl"
    log.write_text("an earlier season's log\n")
    result = runner.invoke(app, ["simulate", "--days", "0", "7", "--out", str(tmp_path)])
    _one_message(result, 2, "holds the logs of an earlier season (day_000.jsonl)", "--force")
    assert log.read_text() == "an earlier season's log\n"


def test_history_plot_makes_its_folder_and_an_unwritable_one_is_one_message(small_run, tmp_path):
    out, _ = small_run
    plot = tmp_path / "new" / "folder" / "season.png"
    result = runner.invoke(app, ["history", str(out / "map.sqlite"), "--plot", str(plot)])
    assert result.exit_code == 0, result.output
    assert plot.read_bytes().startswith(b"\x89PNG")
    (tmp_path / "afile").write_text("x")
    blocked = tmp_path / "afile" / "season.png"
    result = runner.invoke(app, ["history", str(out / "map.sqlite"), "--plot", str(blocked)])
    _one_message(result, 2, f"--plot {blocked} cannot be written", "choose a file in a folder")


def test_a_bad_source_section_of_the_config_is_one_line(tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text("sim:\n  field:\n    plant_spacing: [-0.4, 0.5]\n")
    result = runner.invoke(app, ["run", "sim:?plants=20", "-c", str(config), "-o", str(tmp_path)])
    _one_message(result, 2, "SimConfig: field: plant_spacing: need 0 <= low <= high")
    assert len(result.output.strip().splitlines()) == 1


# ------------------------------------------------------------------- compressed logs


def test_a_truncated_gzip_log_maps_the_lines_before_the_cut(small_log, tmp_path):
    """A .jsonl.gz cut short (a copy that stopped) ended the run with EOFError and no outputs:
    the lines before the cut are mapped, the cut is a bad line of skipped.csv."""
    import gzip

    data = gzip.compress(small_log.read_bytes())
    cut = tmp_path / "cut.jsonl.gz"
    cut.write_bytes(data[: len(data) * 2 // 3])
    result = runner.invoke(app, ["run", str(cut), "-o", str(tmp_path / "l")])
    assert result.exit_code == 0, result.output
    assert "1 truncated" in result.output and "the file was cut short" in result.output
    metrics = json.loads((tmp_path / "l" / "metrics.json").read_text())
    assert metrics["input"]["skipped"] == {"truncated": 1}
    assert metrics["objects"]["mapped_fraction"] > 0.3
    skipped = (tmp_path / "l" / "skipped.csv").read_text().splitlines()
    assert skipped[1].split(",")[1] == "truncated"
    strict = runner.invoke(app, ["run", str(cut), "--strict", "-o", str(tmp_path / "s")])
    _one_message(strict, 1, "cut.jsonl.gz:", "truncated: the file was cut short", "--lenient")
    assert (tmp_path / "s" / "map.sqlite").exists()  # the map of the lines before the cut


def test_a_plain_text_log_named_gz_is_one_message(small_log, tmp_path):
    named = tmp_path / "survey.jsonl.gz"
    named.write_bytes(small_log.read_bytes())
    result = runner.invoke(app, ["run", str(named), "-o", str(tmp_path / "o")])
    _one_message(result, 2, "is named .gz but is not gzip-compressed", "rename it to survey.jsonl")
    assert not (tmp_path / "o").exists()
