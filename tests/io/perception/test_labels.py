"""Combined labels split into attributes (App. A) and length from the box (sec. 3.1.2)."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.config import FieldSchema
from agrislam.io.perception.camera import PinholeCamera
from agrislam.io.perception.label_map import LabelMap, UnknownLabelError
from agrislam.io.perception.length import length_from_box
from agrislam.records import ContinuousMeasurement, Detection, DiscreteMeasurement

CROPS = FieldSchema.preset("crops_weeds")  # type crop/weed, size s/m/b, health healthy/diseased


def test_explicit_map_gives_each_attribute_the_score() -> None:
    lm = LabelMap.from_config(
        {"plant_small_healthy": {"type": "crop", "size": "small", "health": "healthy"}}, CROPS
    )
    assert lm.measurements("plant_small_healthy", 0.83) == {
        "type": DiscreteMeasurement("crop", 0.83),
        "size": DiscreteMeasurement("small", 0.83),
        "health": DiscreteMeasurement("healthy", 0.83),
    }


def test_schema_splits_labels_made_of_values() -> None:
    lm = LabelMap.from_config({}, CROPS)
    assert lm.split("weed_big_diseased") == {"type": "weed", "size": "big", "health": "diseased"}
    assert lm.split("crop_medium") == {"type": "crop", "size": "medium"}  # a subset is fine
    # the paper's own class name needs an explicit entry: 'plant' is no value of the schema
    with pytest.raises(UnknownLabelError, match="'plant'"):
        lm.split("plant_small_healthy")


def test_explicit_entry_wins_over_splitting() -> None:
    lm = LabelMap.from_config({"crop_small": {"type": "weed"}}, CROPS)
    assert lm.split("crop_small") == {"type": "weed"}


def test_ambiguous_and_repeated_values_are_refused() -> None:
    schema = FieldSchema.model_validate(
        {
            "attributes": {
                "size": {"kind": "discrete", "values": ["small", "big"]},
                "leaf": {"kind": "discrete", "values": ["small", "wide"]},
                "type": {"kind": "discrete", "values": ["crop", "weed"]},
            }
        }
    )
    lm = LabelMap(schema=schema)
    with pytest.raises(
        UnknownLabelError, match=r"attributes \['size', 'leaf'\] all have the value 'small'"
    ):
        lm.split("crop_small")
    with pytest.raises(UnknownLabelError, match="two values"):
        lm.split("crop_weed")


def test_map_entries_are_checked_against_the_schema() -> None:
    with pytest.raises(ValueError, match=r"label_map 'x': value 'tiny' is not one of 'size'"):
        LabelMap.from_config({"x": {"size": "tiny"}}, CROPS)
    with pytest.raises(ValueError, match=r"label_map 'x': 'colour' is not a discrete attribute"):
        LabelMap.from_config({"x": {"colour": "red"}}, CROPS)


def test_without_schema_only_the_explicit_map_works() -> None:
    lm = LabelMap.from_config({"a": {"type": "crop"}})
    assert lm and lm.split("a") == {"type": "crop"}
    with pytest.raises(UnknownLabelError, match="'b' is not in the label map"):
        lm.split("b")
    assert not LabelMap()


def test_apply_turns_a_label_into_attributes() -> None:
    lm = LabelMap.from_config({}, CROPS)
    det = Detection(
        xy=np.array([1.0, 0.2]),
        label="crop_small_healthy",
        label_p=0.7,
        attributes={"size": DiscreteMeasurement("big", 0.9)},  # measured on its own: kept
        truth_id="p1",
    )
    out = lm.apply(det)
    assert out.label is None and out.label_p is None and out.truth_id == "p1"
    assert out.attributes == {
        "type": DiscreteMeasurement("crop", 0.7),
        "size": DiscreteMeasurement("big", 0.9),
        "health": DiscreteMeasurement("healthy", 0.7),
    }
    plain = Detection(xy=np.zeros(2))
    assert lm.apply(plain) is plain
    with pytest.raises(ValueError, match="no score"):
        lm.apply(Detection(xy=np.zeros(2), label="crop"))
    with pytest.raises(ValueError, match="not a probability"):
        lm.apply(Detection(xy=np.zeros(2), label="crop", label_p=1.2))


# ------------------------------------------------------------------------------ length

CAM = PinholeCamera.from_camera_info([400.0, 0, 320, 0, 500.0, 240, 0, 0, 1], 640, 480)


def test_length_from_box_height_by_hand() -> None:
    # 100 px tall at 2 m with fy = 500: 100 * 2 / 500 = 0.4 m; var (0.05 * 2.5)^2
    m = length_from_box(np.array([300.0, 200.0, 350.0, 300.0]), 2.0, 2.5, CAM, 0.05)
    assert m == ContinuousMeasurement(pytest.approx(0.4), pytest.approx(0.015625))
    # 50 px wide with fx = 400: 50 * 2 / 400 = 0.25 m
    w = length_from_box(np.array([300.0, 200.0, 350.0, 300.0]), 2.0, 2.5, CAM, 0.05, axis="width")
    assert w.value == pytest.approx(0.25)
    assert length_from_box(
        np.array([300.0, 200.0, 350.0, 300.0]), 2.0, 2.5, CAM, 0.05, "max"
    ).value == pytest.approx(0.4)


def test_length_variance_grows_with_distance_squared() -> None:
    box = np.array([0.0, 0.0, 10.0, 50.0])
    near = length_from_box(box, 1.0, 1.0, CAM, 0.05)
    far = length_from_box(box, 1.0, 3.0, CAM, 0.05)
    assert far.var / near.var == pytest.approx(9.0)
    with pytest.raises(ValueError, match="depth"):
        length_from_box(box, 0.0, 1.0, CAM, 0.05)
