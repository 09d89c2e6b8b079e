"""YOLOv8-seg on onnxruntime (an optional extra): the detector the paper used (sec. 2.3,
App. A), for the user's own exported model (``yolo export model=best.pt format=onnx``).

Model layout (ultralytics export): input ``images`` [1, 3, H, W] (RGB in [0, 1], letterboxed
with grey 114); ``output0`` [1, 4 + nc + 32, N]: per candidate box centre, size (input
pixels), nc class probabilities and 32 mask coefficients; ``output1`` [1, 32, H/4, W/4]:
mask prototypes. Boxes handed out are in pixel-centre coordinates of the original image."""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agrislam.io.perception.detector import ImageDetection

PAD_VALUE = 114  # ultralytics letterbox grey


@dataclass(frozen=True, slots=True)
class Letterbox:
    """Resize-and-pad of an image of size `image_hw` into the model input `input_hw`."""

    image_hw: tuple[int, int]
    input_hw: tuple[int, int]
    scale: float
    pad_x: int
    pad_y: int

    @classmethod
    def fit(cls, image_hw: tuple[int, int], input_hw: tuple[int, int]) -> Letterbox:
        h, w = image_hw
        scale = min(input_hw[0] / h, input_hw[1] / w)
        new_w, new_h = round(w * scale), round(h * scale)
        pad_x = round((input_hw[1] - new_w) / 2 - 0.1)  # as ultralytics LetterBox
        pad_y = round((input_hw[0] - new_h) / 2 - 0.1)
        return cls(image_hw, input_hw, scale, pad_x, pad_y)

    @property
    def resized_hw(self) -> tuple[int, int]:
        return round(self.image_hw[0] * self.scale), round(self.image_hw[1] * self.scale)

    def apply(self, image: np.ndarray) -> np.ndarray:
        """The letterboxed image (input_hw + channels), float in the image's value range."""
        resized = resize_bilinear(image.astype(np.float32), self.resized_hw)
        out = np.full((*self.input_hw, image.shape[2]), float(PAD_VALUE), dtype=np.float32)
        rh, rw = self.resized_hw
        out[self.pad_y : self.pad_y + rh, self.pad_x : self.pad_x + rw] = resized
        return out

    def boxes_to_image(self, boxes_in: np.ndarray) -> np.ndarray:
        """Edge-coordinate boxes (x0, y0, x1, y1) of the input -> pixel-centre coordinates
        of the original image, clipped to it."""
        b = np.array(boxes_in, dtype=np.float64, copy=True)
        b[:, [0, 2]] = (b[:, [0, 2]] - self.pad_x) / self.scale
        b[:, [1, 3]] = (b[:, [1, 3]] - self.pad_y) / self.scale
        h, w = self.image_hw
        b[:, [0, 2]] = np.clip(b[:, [0, 2]], 0.0, w)
        b[:, [1, 3]] = np.clip(b[:, [1, 3]], 0.0, h)
        return b - 0.5


def resize_bilinear(image: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """Bilinear resize (pixel centres aligned as cv2.INTER_LINEAR / align_corners=False)."""
    h, w = image.shape[:2]
    ys = _sample_coords(h, out_hw[0])
    xs = _sample_coords(w, out_hw[1])
    return _bilinear(image, ys[:, None], xs[None, :])


def _sample_coords(n_in: int, n_out: int) -> np.ndarray:
    return np.clip((np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5, 0.0, n_in - 1.0)


def _bilinear(image: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Sample `image` at fractional index coordinates (y, x) (broadcast together)."""
    h, w = image.shape[:2]
    y = np.clip(y, 0.0, h - 1.0)
    x = np.clip(x, 0.0, w - 1.0)
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    y1, x1 = np.minimum(y0 + 1, h - 1), np.minimum(x0 + 1, w - 1)
    fy, fx = y - y0, x - x0
    if image.ndim == 3:
        fy, fx = fy[..., None], fx[..., None]
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def box_iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of one box (x0, y0, x1, y1) with each of `boxes`."""
    ix = np.clip(np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0]), 0, None)
    iy = np.clip(np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1]), 0, None)
    inter = ix * iy
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    return inter / np.maximum(area + areas - inter, 1e-12)


def nms(
    boxes: np.ndarray, scores: np.ndarray, iou: float, classes: np.ndarray | None = None
) -> np.ndarray:
    """Greedy non-maximum suppression, per class when `classes` is given; kept indices,
    best first."""
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    while order.size:
        i = order[0]
        keep.append(int(i))
        rest = order[1:]
        suppress = box_iou(boxes[i], boxes[rest]) > iou
        if classes is not None:
            suppress &= classes[rest] == classes[i]
        order = rest[~suppress]
    return np.asarray(keep, dtype=int)


@dataclass(frozen=True, slots=True)
class SegDetections:
    """Decoded model output in input coordinates (edge convention, pixels)."""

    boxes: np.ndarray  # (k, 4) x0, y0, x1, y1
    scores: np.ndarray  # (k,)
    classes: np.ndarray  # (k,) int
    coefficients: np.ndarray  # (k, n_proto)

    def __len__(self) -> int:
        return len(self.scores)


def decode_output(
    output0: np.ndarray,
    n_proto: int = 32,
    conf: float = 0.25,
    iou: float = 0.45,
    max_det: int = 300,
) -> SegDetections:
    """Boxes, scores, classes and mask coefficients from ``output0`` [1, 4+nc+n_proto, N],
    after a confidence threshold and per-class NMS."""
    pred = np.asarray(output0, dtype=np.float64)[0].T  # (N, 4 + nc + n_proto)
    nc = pred.shape[1] - 4 - n_proto
    if nc < 1:
        raise ValueError(f"output0 has {pred.shape[1]} rows: too few for 4 + nc + {n_proto}")
    class_prob = pred[:, 4 : 4 + nc]
    classes = np.argmax(class_prob, axis=1)
    scores = class_prob[np.arange(len(pred)), classes]
    cand = np.nonzero(scores > conf)[0]
    cx, cy, w, h = pred[cand, :4].T
    boxes = np.column_stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
    keep = nms(boxes, scores[cand], iou, classes[cand])[:max_det]
    return SegDetections(
        boxes=boxes[keep],
        scores=scores[cand][keep],
        classes=classes[cand][keep],
        coefficients=pred[cand[keep], 4 + nc :],
    )


def instance_masks(
    coefficients: np.ndarray, protos: np.ndarray, boxes_in: np.ndarray, letterbox: Letterbox
) -> np.ndarray:
    """Boolean masks (k, H, W) in the original image: sigmoid(coefficients . prototypes)
    sampled bilinearly at each image pixel, > 0.5 inside the detection's box."""
    p = np.asarray(protos, dtype=np.float64)[0]  # (n_proto, mh, mw)
    n_proto, mh, mw = p.shape
    logits = np.asarray(coefficients, dtype=np.float64) @ p.reshape(n_proto, -1)
    prob = 1.0 / (1.0 + np.exp(-logits.reshape(-1, mh, mw)))
    h, w = letterbox.image_hw
    # original pixel centre -> input (edge) coordinates -> prototype index coordinates
    xs_in = (np.arange(w) + 0.5) * letterbox.scale + letterbox.pad_x
    ys_in = (np.arange(h) + 0.5) * letterbox.scale + letterbox.pad_y
    xs_p = xs_in * mw / letterbox.input_hw[1] - 0.5
    ys_p = ys_in * mh / letterbox.input_hw[0] - 0.5
    masks = np.zeros((len(prob), h, w), dtype=bool)
    for k, (m, box) in enumerate(zip(prob, boxes_in, strict=True)):
        inside_x = (xs_in >= box[0]) & (xs_in <= box[2])
        inside_y = (ys_in >= box[1]) & (ys_in <= box[3])
        if not (inside_x.any() and inside_y.any()):
            continue
        sub = _bilinear(m, ys_p[inside_y][:, None], xs_p[inside_x][None, :]) > 0.5
        masks[k][np.ix_(inside_y, inside_x)] = sub
    return masks


def class_names_from_metadata(metadata: dict[str, str]) -> dict[int, str]:
    """The ``names`` entry ultralytics writes into the ONNX metadata ("{0: 'crop', ...}")."""
    raw = metadata.get("names")
    if not raw:
        return {}
    names = ast.literal_eval(raw)
    if isinstance(names, list):
        return dict(enumerate(names))
    return {int(k): str(v) for k, v in names.items()}


class YoloSegOnnx:
    """Runs a YOLOv8-seg ONNX model on RGB images and returns ImageDetections."""

    def __init__(
        self,
        model_path: str | Path,
        class_names: dict[int, str] | list[str] | None = None,
        conf: float = 0.25,
        iou: float = 0.45,
        max_det: int = 300,
        providers: list[str] | None = None,
    ) -> None:
        try:
            import onnxruntime as ort
        except ImportError as err:  # optional extra
            raise ImportError(
                "the YOLO adapter needs onnxruntime: pip install 'agrislam[onnx]'"
            ) from err
        path = Path(model_path)
        if not path.is_file():
            raise FileNotFoundError(f"ONNX model {path} not found")
        self.session = ort.InferenceSession(
            str(path), providers=providers or ["CPUExecutionProvider"]
        )
        meta = self.session.get_modelmeta().custom_metadata_map
        names = class_names if class_names is not None else class_names_from_metadata(meta)
        self.class_names = dict(enumerate(names)) if isinstance(names, list) else dict(names)
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.input_hw = self._input_size(inp.shape, meta)
        outputs = self.session.get_outputs()
        if len(outputs) < 2:
            raise ValueError(
                f"{path}: expected a segmentation model with two outputs (output0, output1), "
                f"got {[o.name for o in outputs]}"
            )
        self.output_names = [outputs[0].name, outputs[1].name]
        self.conf, self.iou, self.max_det = conf, iou, max_det

    @staticmethod
    def _input_size(shape: list, meta: dict[str, str]) -> tuple[int, int]:
        if len(shape) == 4 and all(isinstance(s, int) for s in shape[2:]):
            return int(shape[2]), int(shape[3])
        if "imgsz" in meta:
            h, w = ast.literal_eval(meta["imgsz"])
            return int(h), int(w)
        return 640, 640

    def __call__(self, rgb: np.ndarray) -> list[ImageDetection]:
        """Detections in an RGB image (H, W, 3; uint8 0-255)."""
        if rgb.ndim != 3 or rgb.shape[2] < 3:
            raise ValueError(f"expected an RGB image (H, W, 3), got shape {rgb.shape}")
        letterbox = Letterbox.fit(rgb.shape[:2], self.input_hw)
        x = letterbox.apply(rgb[..., :3]) / 255.0
        x = np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)
        output0, output1 = self.session.run(self.output_names, {self.input_name: x})
        found = decode_output(output0, output1.shape[1], self.conf, self.iou, self.max_det)
        masks = instance_masks(found.coefficients, output1, found.boxes, letterbox)
        boxes = letterbox.boxes_to_image(found.boxes)
        return [
            ImageDetection(
                box=boxes[k],
                label=self.class_names.get(int(c), str(int(c))),
                score=float(s),
                mask=masks[k],
            )
            for k, (c, s) in enumerate(zip(found.classes, found.scores, strict=True))
        ]
