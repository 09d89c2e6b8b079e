"""The RGB-D front end: one frame of 2D detections plus aligned depth -> `records.Detections`
(sec. 2.3, App. A): a robust position from the depth in the mask (or the box's centre), a
range cut-off, a length from the box (sec. 3.1.2) and the combined label split."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agrislam.io.perception.camera import PinholeCamera
from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.perception.label_map import LabelMap, UnknownLabelError
from agrislam.io.perception.length import length_from_box
from agrislam.io.perception.mask_depth import (
    DepthRejectedError,
    box_region,
    depth_in_metres,
    estimate_position,
    green_pixels,
)
from agrislam.records import Detection, Detections, Measurement


@dataclass(frozen=True, slots=True)
class ImageDetection:
    """A detector's output for one object: box (x0, y0, x1, y1) in pixels, class, score,
    and an optional boolean instance mask of the image's size."""

    box: np.ndarray
    label: str
    score: float
    mask: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class FrontEndIssue:
    """Why detection `index` of a frame was dropped (or kept without its label)."""

    index: int
    label: str
    kind: str  # no_depth, beyond_range, no_green, unknown_label, bad_mask
    message: str
    dropped: bool = True


@dataclass(frozen=True, slots=True)
class FrameResult:
    detections: Detections
    issues: tuple[FrontEndIssue, ...] = ()


class RgbdDetector:
    def __init__(
        self,
        camera: PinholeCamera,
        config: PerceptionConfig | None = None,
        label_map: LabelMap | None = None,
    ) -> None:
        self.camera = camera
        self.config = config or PerceptionConfig()
        self.label_map = label_map

    def detect(
        self,
        t: float,
        robot: str,
        depth: np.ndarray,
        detections: Sequence[ImageDetection],
        rgb: np.ndarray | None = None,
        sensor: str | None = None,
    ) -> FrameResult:
        """Base-frame detections of one frame, and what was dropped and why."""
        cfg = self.config
        depth_m = depth_in_metres(depth, cfg.depth_scale)
        green = None
        if cfg.green_filter:
            if rgb is None:
                raise ValueError("green_filter is on but the frame has no RGB image")
            green = green_pixels(rgb, cfg.green_threshold)
        objects: list[Detection] = []
        issues: list[FrontEndIssue] = []
        for i, det in enumerate(detections):
            try:
                region = self._region(det, depth_m.shape, green)
                estimate = estimate_position(depth_m, region, self.camera, cfg)
            except DepthRejectedError as err:
                issues.append(FrontEndIssue(i, det.label, err.kind, str(err)))
                continue
            except ValueError as err:
                issues.append(FrontEndIssue(i, det.label, "bad_mask", str(err)))
                continue
            attributes: dict[str, Measurement] = {}
            if cfg.length_attribute is not None:
                attributes[cfg.length_attribute] = length_from_box(
                    det.box,
                    float(estimate.point_cam[2]),
                    estimate.range,
                    self.camera,
                    cfg.length_sigma_at_1m,
                    cfg.length_axis,
                )
            obj = Detection(
                xy=estimate.xy.copy(),
                cov=estimate.cov,
                attributes=attributes,
                label=det.label,
                label_p=float(det.score),
            )
            if self.label_map:
                try:
                    obj = self.label_map.apply(obj)
                except UnknownLabelError as err:  # keep the position, drop the semantics
                    issues.append(FrontEndIssue(i, det.label, "unknown_label", str(err), False))
                    obj = dataclasses.replace(obj, label=None, label_p=None)
            objects.append(obj)
        return FrameResult(Detections(t, robot, tuple(objects), sensor), tuple(issues))

    def _region(
        self, det: ImageDetection, shape: tuple[int, ...], green: np.ndarray | None
    ) -> np.ndarray:
        if det.mask is not None:
            region = np.asarray(det.mask, dtype=bool)
            if region.shape != shape:
                raise ValueError(f"mask {region.shape} does not match the depth image {shape}")
        else:
            region = box_region(det.box, (shape[0], shape[1]), self.config.box_core)
        if green is not None:
            region = region & green
            if not region.any():
                raise DepthRejectedError("no_green", "no green pixels in the mask (green filter)")
        return region
