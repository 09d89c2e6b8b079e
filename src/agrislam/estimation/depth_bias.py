"""The detector's depth bias (sec. 2.3), learned: a mask's depth pixels see a plant's near
side, so detections lie short of its centre; once bearings from several poses fix a plant,
the along-ray residuals of new detections of it measure the bias, fed back into placement."""

from __future__ import annotations

import numpy as np


class DepthBiasEstimator:
    """A constant offset along the viewing ray, learned from along-ray residuals."""

    def __init__(self, initial: float = 0.0, gain: float = 0.2, limit: float = 0.2) -> None:
        self.bias = initial
        self.gain = gain
        self.limit = limit
        self.n_samples = 0

    def correct(self, xy: np.ndarray) -> np.ndarray:
        """Detections (m, 2) in the sensor frame pushed out along their rays by the bias."""
        r = np.linalg.norm(xy, axis=-1, keepdims=True)
        return xy * (1.0 + self.bias / np.maximum(r, 1e-9))

    def observe(self, measured_xy: np.ndarray, predicted_xy: np.ndarray) -> None:
        """Corrected detections and where the map now predicts them (both sensor frame):
        their mean range difference moves the estimate a step of `gain`."""
        if len(measured_xy) == 0:
            return
        residual = np.linalg.norm(predicted_xy, axis=1) - np.linalg.norm(measured_xy, axis=1)
        self.bias = float(np.clip(self.bias + self.gain * residual.mean(), -self.limit, self.limit))
        self.n_samples += len(residual)
