"""The field schema part of config.py: loading, presets, and errors that name the attribute."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pydantic import ValidationError

from agrislam.config import (
    COLOURS,
    SCHEMA_PRESETS,
    SIZES,
    AgrislamConfig,
    ContinuousAttribute,
    DiscreteAttribute,
    FieldSchema,
    GrowthModel,
)

YAML_SCHEMA = """\
attributes:
  type:
    kind: discrete
    values: [crop, weed]
  size:
    kind: discrete
    values: [small, medium, big]
    prior: [0.5, 0.3, 0.2]
    time_model: {kind: growth, rate_per_day: 0.05, l_max: 0.6, process_noise: 0.01}
  length:
    kind: continuous
    min: 0.0
    max: 0.6
    prior_mean: 0.1
    time_model: {l_max: 0.6, variance_per_day: 0.0001}
"""

TOML_SCHEMA = """\
[attributes.type]
kind = "discrete"
values = ["crop", "weed"]

[attributes.size]
kind = "discrete"
values = ["small", "medium", "big"]
prior = [0.5, 0.3, 0.2]
time_model = { kind = "growth", rate_per_day = 0.05, l_max = 0.6, process_noise = 0.01 }

[attributes.length]
kind = "continuous"
min = 0.0
max = 0.6
prior_mean = 0.1
time_model = { l_max = 0.6, variance_per_day = 0.0001 }
"""

JSON_SCHEMA = {
    "attributes": {
        "type": {"kind": "discrete", "values": ["crop", "weed"]},
        "size": {
            "kind": "discrete",
            "values": ["small", "medium", "big"],
            "prior": [0.5, 0.3, 0.2],
            "time_model": {
                "kind": "growth",
                "rate_per_day": 0.05,
                "l_max": 0.6,
                "process_noise": 0.01,
            },
        },
        "length": {
            "kind": "continuous",
            "min": 0.0,
            "max": 0.6,
            "prior_mean": 0.1,
            "time_model": {"l_max": 0.6, "variance_per_day": 0.0001},
        },
    }
}

# the meta line of shared/spec/log-format.md, verbatim
META_LINE = (
    '{"type": "meta", "version": 1, "schema": {"attributes": {'
    '"type": {"kind": "discrete", "values": ["crop", "weed"]}, '
    '"size": {"kind": "discrete", "values": ["small", "medium", "big"]}, '
    '"health": {"kind": "discrete", "values": ["healthy", "diseased"]}, '
    '"length": {"kind": "continuous", "min": 0.0, "max": 0.6}}}, '
    '"robots": {"r1": {"start_pose": [0.0, 0.0, 0.0], "start_sigma": [0.01, 0.01, 0.005]}}, '
    '"anchor": {"lat": 51.4488, "lon": 5.4905, "h": 20.0, "yaw_deg": 0.0}, '
    '"field": {"row_spacing": 1.0, "min_plant_distance": 0.3, "row_angle_deg": null}}'
)


def _check_loaded(schema: FieldSchema) -> None:
    assert list(schema.attributes) == ["type", "size", "length"]
    assert list(schema.discrete) == ["type", "size"] and list(schema.continuous) == ["length"]
    size = schema.discrete["size"]
    assert size.values == ["small", "medium", "big"] and size.prior == [0.5, 0.3, 0.2]
    assert size.time_model == GrowthModel(rate_per_day=0.05, l_max=0.6, process_noise=0.01)
    length = schema.continuous["length"]
    assert (length.min, length.max, length.initial_mean) == (0.0, 0.6, 0.1)
    assert length.initial_var == pytest.approx(0.36 / 12)  # uniform over [0, 0.6]
    assert length.time_model is not None and length.time_model.rate_per_day == 0.04  # default


@pytest.mark.parametrize(
    ("filename", "text"),
    [
        ("schema.yaml", YAML_SCHEMA),
        ("schema.yml", YAML_SCHEMA),
        ("schema.toml", TOML_SCHEMA),
        ("schema.json", json.dumps(JSON_SCHEMA)),
        ("wrapped.json", json.dumps({"schema": JSON_SCHEMA})),
    ],
)
def test_load_yaml_toml_json(tmp_path: Path, filename: str, text: str):
    path = tmp_path / filename
    path.write_text(text, encoding="utf-8")
    schema = FieldSchema.load(path)
    _check_loaded(schema)
    assert schema == FieldSchema.model_validate(JSON_SCHEMA)


def test_schema_from_the_log_meta_record(tmp_path: Path):
    meta = json.loads(META_LINE)
    schema = FieldSchema.model_validate(meta["schema"])
    assert list(schema.discrete) == ["type", "size", "health"]
    assert schema.discrete["health"].values == ["healthy", "diseased"]
    assert (schema.continuous["length"].min, schema.continuous["length"].max) == (0.0, 0.6)
    # the meta record saved as a JSON file loads the same (its `schema` key is taken)
    path = tmp_path / "meta.json"
    path.write_text(META_LINE, encoding="utf-8")
    assert FieldSchema.load(path) == schema


def test_schema_round_trips_through_its_dump():
    schema = FieldSchema.model_validate(JSON_SCHEMA)
    assert FieldSchema.model_validate(schema.model_dump()) == schema
    assert FieldSchema.model_validate_json(schema.model_dump_json()) == schema


def test_the_four_presets_are_the_papers_tables():
    assert sorted(SCHEMA_PRESETS) == [
        "colour_length",
        "colour_size",
        "crops_weeds",
        "intercropping",
    ]
    colour_size = FieldSchema.preset("colour_size")  # Table 1, discrete plant size
    assert (
        colour_size.discrete["colour"].values
        == COLOURS
        == ["blue", "cyan", "green", "orange", "pink", "red", "yellow"]
    )
    assert colour_size.discrete["size"].values == SIZES == ["small", "medium", "big"]
    colour_length = FieldSchema.preset("colour_length")  # Table 1, continuous plant size
    assert list(colour_length.discrete) == ["colour"]
    length = colour_length.continuous["length"]
    assert isinstance(length, ContinuousAttribute) and length.min < 0.12 and length.max > 0.57
    intercropping = FieldSchema.preset("intercropping")  # Table 2
    assert {k: v.values for k, v in intercropping.discrete.items()} == {
        "type": ["A", "B"],
        "size": SIZES,
        "health": ["healthy", "diseased"],
    }
    crops_weeds = FieldSchema.preset("crops_weeds")  # Table 2
    assert {k: v.values for k, v in crops_weeds.discrete.items()} == {
        "type": ["crop", "weed"],
        "size": SIZES,
        "health": ["healthy", "diseased"],
    }
    assert (
        all(isinstance(a, DiscreteAttribute) for a in crops_weeds.attributes.values())
        and not crops_weeds.continuous
    )


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown schema preset 'weeds'.*crops_weeds"):
        FieldSchema.preset("weeds")


@pytest.mark.parametrize(
    ("attribute", "spec", "message"),
    [
        ("size", {"kind": "discrete", "values": ["small"]}, "needs at least 2 values"),
        ("size", {"kind": "discrete", "values": []}, "needs at least 2 values"),
        ("size", {"kind": "discrete", "values": ["s", "m", "s"]}, r"duplicate values \['s'\]"),
        ("length", {"kind": "continuous", "min": 0.6, "max": 0.6}, "min 0.6 must be below max"),
        ("length", {"kind": "continuous", "min": 1.0, "max": 0.0}, "min 1.0 must be below max"),
        ("length", {"kind": "continuous", "min": 0.0, "max": "inf"}, "max: .*finite"),
        ("height", {"kind": "fuzzy", "values": ["a", "b"]}, "unknown kind 'fuzzy'"),
        ("height", {"values": ["a", "b"]}, "unknown kind None"),
        (
            "type",
            {"kind": "discrete", "values": ["a", "b"], "prior": [0.7, 0.7]},
            "not a probability distribution",
        ),
        ("type", {"kind": "discrete", "values": ["a", "b"], "prior": [1.0]}, "prior has 1 entries"),
        ("type", {"kind": "discrete", "values": ["a", "b"], "shade": 1}, "shade"),
        (
            "size",
            {"kind": "discrete", "values": ["s", "b"], "time_model": {"l_max": 0.0}},
            "time_model.l_max",
        ),
        ("length", {"kind": "continuous", "min": 0, "max": 1, "prior_var": -1.0}, "prior_var"),
        ("type", "crop", "expected a mapping"),
    ],
)
def test_invalid_schema_names_the_attribute(attribute: str, spec: object, message: str):
    good = {"kind": "discrete", "values": ["x", "y"]}
    data = {"attributes": {"fine": good, attribute: spec}}
    with pytest.raises(ValidationError, match=rf"attribute '{attribute}': .*{message}"):
        FieldSchema.model_validate(data)


def test_invalid_schema_file_names_the_attribute(tmp_path: Path):
    path = tmp_path / "bad.yaml"
    path.write_text("attributes:\n  size: {kind: discrete, values: [s, m, s]}\n")
    with pytest.raises(ValidationError, match=r"attribute 'size': duplicate values"):
        FieldSchema.load(path)


def test_unknown_file_format_and_non_mapping_are_refused(tmp_path: Path):
    path = tmp_path / "schema.ini"
    path.write_text("[attributes]\n")
    with pytest.raises(ValueError, match=r"unknown config format '\.ini'"):
        FieldSchema.load(path)
    listing = tmp_path / "list.yaml"
    listing.write_text("- a\n- b\n")
    with pytest.raises(ValueError, match="expected a mapping at the top level"):
        FieldSchema.load(listing)


def test_empty_schema_means_no_attributes():
    schema = FieldSchema.model_validate({})
    assert schema.attributes == {} and schema.discrete == {} and schema.continuous == {}


def test_a_renamed_association_key_is_still_read_with_a_warning():
    with pytest.warns(FutureWarning, match="detection_covariance is now .*innovation_gate"):
        cfg = AgrislamConfig.model_validate({"association": {"detection_covariance": True}})
    assert cfg.advanced.association.innovation_gate is True


def test_a_removed_association_key_is_ignored_with_a_warning():
    with pytest.warns(FutureWarning, match="weak_tentative is ignored: .*maintenance.existence"):
        cfg = AgrislamConfig.model_validate({"association": {"weak_tentative": False}})
    assert cfg.advanced.maintenance.existence is None  # left to the survey


@pytest.mark.parametrize(
    ("data", "where"),
    [
        ({"advanced": {"gnss": {"fix_sigma": {"rtk_fixed": -0.01}}}}, "fix_sigma.rtk_fixed"),
        ({"advanced": {"gnss": {"fix_sigma": {"dgps": 0.0}}}}, "fix_sigma.dgps"),
        ({"advanced": {"gnss": {"fix_sigma": {"rtk_fix": 0.01}}}}, "fix_sigma.rtk_fix"),
        ({"advanced": {"season": {"start_tolerance": [0.5, -0.2]}}}, "start_tolerance.1"),
    ],
)
def test_a_sigma_or_tolerance_that_is_not_positive_is_refused(data: dict, where: str):
    """A negative GNSS sigma floor was accepted (squared, it passed for a positive one; zero
    left an RTK fix without noise), and a misspelt fix type silently dropped the real one."""
    with pytest.raises(ValidationError, match=where):
        AgrislamConfig.model_validate(data)


def test_the_fix_types_of_the_config_are_those_of_the_records():
    from typing import get_args

    from agrislam.config.gnss import FixType
    from agrislam.records import FIX_TYPES

    assert set(get_args(FixType)) == set(FIX_TYPES)
    defaults = {"rtk_fixed": 0.01, "rtk_float": 0.2, "dgps": 0.5, "single": 1.5}
    assert AgrislamConfig().advanced.gnss.fix_sigma == defaults
