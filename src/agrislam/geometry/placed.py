"""A frame's detections placed in the map frame (DESIGN step 3), as the association and
the estimators take them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from agrislam.records import Measurement


@dataclass(frozen=True, slots=True)
class PlacedDetections:
    """A frame's detections in the map frame (DESIGN step 3)."""

    xy: np.ndarray  # (m, 2)
    cov: np.ndarray  # (m, 2, 2)
    measurements: Sequence[Mapping[str, Measurement]]
    robot_xy: np.ndarray | None = None  # (m, 2) the same detections in the robot frame
    robot_cov: np.ndarray | None = None  # (m, 2, 2)
    pose_cov: np.ndarray | None = None  # (m, 2, 2) what the robot's pose marginal adds

    def __len__(self) -> int:
        return len(self.xy)

    def subset(self, keep: np.ndarray) -> PlacedDetections:
        """The detections where `keep` (m,) is True."""
        rows = np.flatnonzero(keep)
        robot_frame = (self.robot_xy, self.robot_cov, self.pose_cov)
        return PlacedDetections(
            self.xy[rows],
            self.cov[rows],
            [self.measurements[i] for i in rows.tolist()],
            *(None if a is None else a[rows] for a in robot_frame),
        )
