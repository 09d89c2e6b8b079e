"""RGB-D to detections (sec. 2.3, App. A): camera model, robust mask depth, label map,
length from the box, the YOLOv8-seg ONNX adapter (optional onnxruntime) and the front end
that turns one frame into `records.Detections`."""

from agrislam.io.perception.camera import PinholeCamera, camera_mount
from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.perception.detector import FrameResult, ImageDetection, RgbdDetector
from agrislam.io.perception.label_map import LabelMap, UnknownLabelError
from agrislam.io.perception.length import length_from_box
from agrislam.io.perception.mask_depth import DepthRejectedError, estimate_position

__all__ = [
    "DepthRejectedError",
    "FrameResult",
    "ImageDetection",
    "LabelMap",
    "PerceptionConfig",
    "PinholeCamera",
    "RgbdDetector",
    "UnknownLabelError",
    "camera_mount",
    "estimate_position",
    "length_from_box",
]
