"""A frame after association (sec. 2.4): its detections with the objects they went to."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrislam.geometry.placed import PlacedDetections
from agrislam.records import Detection


@dataclass(slots=True)
class FrameMatch:
    """A frame's detections that are mapped, with the objects they went to; the range
    errors of mapped landmarks are reported as theirs, not mapped."""

    robot: str
    t: float
    pose: np.ndarray  # (3,) the robot's pose when the frame was associated
    detections: list[Detection]  # those mapped
    placed: PlacedDetections  # those mapped
    object_ids: np.ndarray  # (m,) of the mapped detections, new objects included
    new_ids: np.ndarray  # the objects the frame started
    reported: np.ndarray  # (all,) each detection's object: range errors their landmark's
    mapped: np.ndarray  # (all,) which detections are mapped

    @property
    def seen(self) -> np.ndarray:
        """The objects the frame detected, each once."""
        return np.unique(self.object_ids)

    def report_ids(self) -> np.ndarray:
        """(all,) the object each of the frame's detections went to."""
        reported = self.reported.copy()
        reported[self.mapped] = self.object_ids
        return reported
