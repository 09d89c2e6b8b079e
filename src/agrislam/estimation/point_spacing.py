"""The distance scale d_inter (sec. 2.4, 2.6.3) of a survey that does not give it: three
times the median sharpest sigma of its first detections, seen from near and far. Nearer
than that, a detection cannot tell two objects apart."""

from __future__ import annotations

import numpy as np

D_INTER_SAMPLE = 500  # detections the estimate is taken from
SIGMAS = 3.0


class PointSpacing:
    """d_inter: the configured or the field prior's (`fixed`), else learned from the first
    D_INTER_SAMPLE detections' covariances."""

    def __init__(self, fixed: float | None) -> None:
        self.d_inter = fixed
        self._sharpest = np.empty(0)
        self.settled = fixed is not None

    def observe(self, detection_cov: np.ndarray) -> None:
        """A frame's detection covariances (m, 2, 2), until the sample is full."""
        if self.settled or len(detection_cov) == 0:
            return
        sharpest = np.sqrt(np.linalg.eigvalsh(detection_cov)[:, 0])
        self._sharpest = np.r_[self._sharpest, sharpest]
        self.d_inter = SIGMAS * float(np.median(self._sharpest))
        self.settled = len(self._sharpest) >= D_INTER_SAMPLE
