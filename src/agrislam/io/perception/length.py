"""Continuous plant length from a detection box and depth (sec. 3.1.2): the box's extent at
the plant's depth, with a variance that grows with the distance squared."""

from __future__ import annotations

from typing import Literal

import numpy as np

from agrislam.io.perception.camera import PinholeCamera
from agrislam.records import ContinuousMeasurement


def length_from_box(
    box: np.ndarray,
    depth: float,
    distance: float,
    camera: PinholeCamera,
    sigma_at_1m: float,
    axis: Literal["height", "width", "max"] = "height",
) -> ContinuousMeasurement:
    """Metric extent of box (x0, y0, x1, y1) at optical depth `depth` (pinhole: size_px * z /
    f), with variance (sigma_at_1m * distance)^2 (sec. 3.1.2)."""
    if not (depth > 0.0 and np.isfinite(depth)):
        raise ValueError(f"depth must be positive and finite, got {depth}")
    x0, y0, x1, y1 = (float(v) for v in box)
    height = (y1 - y0) * depth / camera.K[1, 1]
    width = (x1 - x0) * depth / camera.K[0, 0]
    value = {"height": height, "width": width, "max": max(height, width)}[axis]
    return ContinuousMeasurement(value=float(value), var=float((sigma_at_1m * distance) ** 2))
