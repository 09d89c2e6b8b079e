"""Interest heuristic h (sec. 2.7, eq. 2) and the field interest surface."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class InterestSurface:
    """h spread over a regular grid covering the field; cell (i, j) has its centre at
    (x0 + (j + 0.5) * resolution, y0 + (i + 0.5) * resolution)."""

    x0: float
    y0: float
    resolution: float
    values: np.ndarray  # (ny, nx), each in [0, 1]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax), as matplotlib's imshow takes it."""
        ny, nx = self.values.shape
        return (self.x0, self.x0 + nx * self.resolution, self.y0, self.y0 + ny * self.resolution)
