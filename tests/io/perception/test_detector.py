"""The RGB-D front end: a synthetic frame with known plants -> records.Detections."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.config import FieldSchema
from agrislam.io.perception.camera import PinholeCamera, camera_mount
from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.perception.detector import ImageDetection, RgbdDetector
from agrislam.io.perception.label_map import LabelMap
from agrislam.io.perception.synthetic import (
    FacingDisc,
    Sphere,
    instance_box,
    render_depth,
    render_rgb,
)
from agrislam.records import DiscreteMeasurement

CAM = PinholeCamera.from_camera_info(
    [300.0, 0, 160, 0, 300.0, 120, 0, 0, 1],
    320,
    240,
    camera_to_base=camera_mount([0.3, 0.0, 0.6], pitch=0.35),
)
SCHEMA = FieldSchema.model_validate(
    {
        "attributes": {
            "type": {"kind": "discrete", "values": ["crop", "weed"]},
            "size": {"kind": "discrete", "values": ["small", "big"]},
            "length": {"kind": "continuous", "min": 0.0, "max": 0.6},
        }
    }
)
PLANTS = [
    FacingDisc(np.array([1.5, 0.25, 0.12]), 0.1),  # 1: a crop, 0.2 m tall
    Sphere(np.array([1.3, -0.35, 0.08]), 0.08),  # 2: a weed
    FacingDisc(np.array([3.4, 0.0, 0.2]), 0.2),  # 3: beyond the 2.5 m cut-off
    FacingDisc(np.array([1.1, 0.3, 0.1]), 0.06),  # 4: labelled with an unknown class
]


def frame() -> tuple[np.ndarray, np.ndarray, list[ImageDetection]]:
    depth, instance = render_depth(CAM, PLANTS)
    labels = ["crop_small", "weed_big", "crop_big", "plant_x"]
    dets = [
        ImageDetection(instance_box(instance, k + 1), labels[k], 0.8 - 0.1 * k, instance == k + 1)
        for k in range(len(PLANTS))
    ]
    # 5: a box over a patch where the sensor returned nothing
    depth[5:25, 5:25] = 0.0
    dets.append(ImageDetection(np.array([5.0, 5.0, 24.0, 24.0]), "crop_small", 0.9))
    return depth, instance, dets


def test_frame_to_detections() -> None:
    depth, _, dets = frame()
    cfg = PerceptionConfig(length_attribute="length")
    result = RgbdDetector(CAM, cfg, LabelMap.from_config({}, SCHEMA)).detect(
        12.5, "r1", (depth * 1000).astype(np.uint16), dets, sensor="front"
    )
    out = result.detections
    assert (out.t, out.robot, out.sensor, len(out.objects)) == (12.5, "r1", "front", 3)
    crop, weed, unknown = out.objects
    np.testing.assert_allclose(crop.xy, PLANTS[0].center[:2], atol=3e-3)  # mm depth: 1 mm steps
    assert crop.attributes["type"] == DiscreteMeasurement("crop", 0.8)
    assert crop.attributes["size"] == DiscreteMeasurement("small", 0.8)
    assert crop.attributes["length"].value == pytest.approx(0.2, abs=0.01)
    assert crop.label is None
    assert weed.attributes["type"] == DiscreteMeasurement("weed", pytest.approx(0.7))
    assert np.linalg.norm(weed.xy - PLANTS[1].center[:2]) < 0.08  # visible-surface bias
    # the unknown class keeps its position, loses its semantics, and is reported
    np.testing.assert_allclose(unknown.xy, PLANTS[3].center[:2], atol=3e-3)
    assert unknown.label is None and set(unknown.attributes) == {"length"}
    kinds = {(i.index, i.kind, i.dropped) for i in result.issues}
    assert kinds == {(2, "beyond_range", True), (3, "unknown_label", False), (4, "no_depth", True)}
    # covariance: symmetric positive definite, larger along the ray than across it
    for obj in out.objects:
        w = np.linalg.eigvalsh(obj.cov)
        assert w[0] > 0 and w[1] > w[0]


def test_without_label_map_the_label_is_passed_on() -> None:
    depth, _, dets = frame()
    out = RgbdDetector(CAM).detect(1.0, "r1", depth, dets[:1]).detections
    (obj,) = out.objects
    assert (obj.label, obj.label_p, obj.attributes) == ("crop_small", 0.8, {})


def test_green_filter_needs_colour_and_uses_it() -> None:
    depth, instance, dets = frame()
    boxes_only = [ImageDetection(d.box, d.label, d.score) for d in dets[:2]]
    cfg = PerceptionConfig(green_filter=True, box_core=1.0, outlier_mad=1e6, outlier_band=1e6)
    detector = RgbdDetector(CAM, cfg)
    with pytest.raises(ValueError, match="RGB"):
        detector.detect(0.0, "r1", depth, boxes_only)
    out = detector.detect(0.0, "r1", depth, boxes_only, rgb=render_rgb(instance)).detections
    np.testing.assert_allclose(out.objects[0].xy, PLANTS[0].center[:2], atol=3e-3)
    plain = RgbdDetector(CAM, cfg.model_copy(update={"green_filter": False}))
    loose = plain.detect(0.0, "r1", depth, boxes_only).detections
    assert np.linalg.norm(loose.objects[0].xy - PLANTS[0].center[:2]) > 0.01


def test_mask_of_the_wrong_size_is_reported() -> None:
    depth, _, dets = frame()
    bad = ImageDetection(dets[0].box, "crop_small", 0.5, np.ones((10, 10), dtype=bool))
    result = RgbdDetector(CAM).detect(0.0, "r1", depth, [bad])
    assert result.detections.objects == ()
    (issue,) = result.issues
    assert issue.kind == "bad_mask" and "(10, 10)" in issue.message
