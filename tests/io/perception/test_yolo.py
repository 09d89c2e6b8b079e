"""YOLOv8-seg decoding on known tensors, and the onnxruntime adapter on a tiny model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agrislam.io.perception.yolo_onnx import (
    Letterbox,
    YoloSegOnnx,
    class_names_from_metadata,
    decode_output,
    instance_masks,
    nms,
    resize_bilinear,
)

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

NC, NP = 3, 32


def raw_output(
    rows: list[tuple[tuple[float, float, float, float], int, float, int]], n: int = 8
) -> np.ndarray:
    """output0 [1, 4 + NC + NP, n] with, per anchor: box (cx, cy, w, h), class, score, and
    the index of the one prototype its mask uses."""
    out = np.zeros((1, 4 + NC + NP, n), dtype=np.float32)
    for a, (box, cls, score, proto) in enumerate(rows):
        out[0, :4, a] = box
        out[0, 4 + cls, a] = score
        out[0, 4 + NC + proto, a] = 1.0
    return out


def test_decode_thresholds_and_per_class_nms() -> None:
    out = raw_output(
        [
            ((20, 20, 10, 10), 0, 0.9, 0),
            ((21, 20, 10, 10), 0, 0.8, 0),  # IoU 90/110 = 0.82 with the first: suppressed
            ((21, 20, 10, 10), 1, 0.7, 0),  # same place, other class: kept
            ((50, 40, 8, 20), 2, 0.2, 1),  # below the confidence threshold
            ((50, 40, 8, 20), 2, 0.6, 1),
        ]
    )
    found = decode_output(out, NP, conf=0.25, iou=0.45)
    np.testing.assert_allclose(found.scores, [0.9, 0.7, 0.6], rtol=1e-6)
    np.testing.assert_array_equal(found.classes, [0, 1, 2])
    np.testing.assert_allclose(found.boxes, [[15, 15, 25, 25], [16, 15, 26, 25], [46, 30, 54, 50]])
    assert found.coefficients.shape == (3, NP)
    # class-agnostic NMS would have dropped the class-1 box too
    agnostic = nms(found.boxes, found.scores, 0.45)
    np.testing.assert_array_equal(agnostic, [0, 2])


def test_masks_from_prototypes_by_hand() -> None:
    out = raw_output([((20, 20, 10, 10), 0, 0.9, 0), ((50, 40, 8, 20), 2, 0.6, 1)])
    protos = np.full((1, NP, 16, 16), -8.0, dtype=np.float32)
    protos[0, 0, 3:7, 3:7] = 8.0  # input pixels 12..27 after bilinear upsampling
    protos[0, 1] = 8.0  # everywhere: the mask is the box
    found = decode_output(out, NP)
    lb = Letterbox.fit((64, 64), (64, 64))
    masks = instance_masks(found.coefficients, protos, found.boxes, lb)
    expected0 = np.zeros((64, 64), dtype=bool)
    expected0[15:25, 15:25] = True  # prototype 12..27 cut to the box: centres 15.5..24.5
    np.testing.assert_array_equal(masks[0], expected0)
    expected1 = np.zeros((64, 64), dtype=bool)
    expected1[30:50, 46:54] = True
    np.testing.assert_array_equal(masks[1], expected1)
    protos[0, 0, 3:7, 3:7] = -8.0
    assert not instance_masks(found.coefficients, protos, found.boxes, lb)[0].any()


def test_letterbox_by_hand() -> None:
    lb = Letterbox.fit((48, 80), (64, 64))
    # scale min(64/48, 64/80) = 0.8 -> 38 x 64, padded (64 - 38) / 2 = 13 on top
    assert (lb.scale, lb.pad_x, lb.pad_y, lb.resized_hw) == (0.8, 0, 13, (38, 64))
    boxes = lb.boxes_to_image(np.array([[8.0, 23.0, 24.0, 39.0]]))
    np.testing.assert_allclose(boxes, [[9.5, 12.0, 29.5, 32.0]])  # /0.8, -13, -0.5 to centres
    img = lb.apply(np.zeros((48, 80, 3), dtype=np.uint8))
    assert (
        img.shape == (64, 64, 3)
        and img[0, 0, 0] == 114
        and img[13, 0, 0] == 0
        and img[51, 0, 0] == 114
    )


def test_resize_bilinear_by_hand() -> None:
    img = np.array([[0.0, 1.0], [2.0, 3.0]])
    out = resize_bilinear(img, (4, 4))
    np.testing.assert_allclose(out[0], [0.0, 0.25, 0.75, 1.0])
    np.testing.assert_allclose(out[:, 0], [0.0, 0.5, 1.5, 2.0])


def test_class_names_from_metadata() -> None:
    assert class_names_from_metadata({"names": "{0: 'weed', 1: 'crop'}"}) == {0: "weed", 1: "crop"}
    assert class_names_from_metadata({"names": "['a', 'b']"}) == {0: "a", 1: "b"}
    assert class_names_from_metadata({}) == {}


# ----------------------------------------------------------------------- tiny model

NAMES = "{0: 'weed', 1: 'crop_small_healthy', 2: 'crop_big_healthy'}"


def tiny_model(path: Path, outputs: int = 2) -> Path:
    """A randomly initialised conv net with YOLOv8-seg's input/output layout (64 x 64 input),
    plus constant offsets that put one known box (class 1, score 0.9) at anchor 10."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(7)
    c0 = 4 + NC + NP
    w_det = (rng.uniform(-1, 1, (c0, 3, 8, 8)) * 1e-3).astype(np.float32)
    w_proto = (rng.uniform(-1, 1, (NP, 3, 4, 4)) * 1e-3).astype(np.float32)
    bias0 = np.zeros((1, c0, 64), dtype=np.float32)
    bias0[0, :4, 10] = (32.0, 32.0, 16.0, 24.0)
    bias0[0, 4 + 1, 10] = 0.9
    bias0[0, 4 + NC + 0, 10] = 1.0
    bias1 = np.zeros((1, NP, 16, 16), dtype=np.float32)
    bias1[0, 0] = 8.0
    inits = [
        numpy_helper.from_array(w_det, "w_det"),
        numpy_helper.from_array(w_proto, "w_proto"),
        numpy_helper.from_array(bias0, "bias0"),
        numpy_helper.from_array(bias1, "bias1"),
        numpy_helper.from_array(np.array([1, c0, 64], dtype=np.int64), "shape0"),
    ]
    nodes = [
        helper.make_node("Conv", ["images", "w_det"], ["det"], strides=[8, 8]),
        helper.make_node("Reshape", ["det", "shape0"], ["det_flat"]),
        helper.make_node("Add", ["det_flat", "bias0"], ["output0"]),
        helper.make_node("Conv", ["images", "w_proto"], ["proto"], strides=[4, 4]),
        helper.make_node("Add", ["proto", "bias1"], ["output1"]),
    ]
    outs = [
        helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, c0, 64]),
        helper.make_tensor_value_info("output1", TensorProto.FLOAT, [1, NP, 16, 16]),
    ][:outputs]
    graph = helper.make_graph(
        nodes,
        "tiny_yolov8_seg",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 64, 64])],
        outs,
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.helper.set_model_props(model, {"names": NAMES, "imgsz": "[64, 64]"})
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def test_adapter_runs_a_tiny_model_end_to_end(tmp_path: Path) -> None:
    yolo = YoloSegOnnx(tiny_model(tmp_path / "tiny.onnx"))
    assert yolo.input_hw == (64, 64) and yolo.class_names[1] == "crop_small_healthy"
    image = np.random.default_rng(1).integers(0, 256, (48, 80, 3), dtype=np.uint8)
    (det,) = yolo(image)
    assert det.label == "crop_small_healthy"
    assert det.score == pytest.approx(0.9, abs=0.02)
    # input box (24, 20, 40, 44); letterbox scale 0.8, 13 px on top; pixel centres -0.5
    np.testing.assert_allclose(det.box, [29.5, 8.25, 49.5, 38.25], atol=0.05)
    expected = np.zeros((48, 80), dtype=bool)
    expected[9:39, 30:50] = True  # pixels whose centres fall inside the box
    np.testing.assert_array_equal(det.mask, expected)


def test_adapter_refuses_a_detection_only_model(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="two outputs"):
        YoloSegOnnx(tiny_model(tmp_path / "det.onnx", outputs=1))
    with pytest.raises(FileNotFoundError, match=r"nothere\.onnx"):
        YoloSegOnnx(tmp_path / "nothere.onnx")
