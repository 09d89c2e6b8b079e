"""A frame's detections placed in the map frame (DESIGN step 3), and once associated, the
objects they went to (sec. 2.4): what the stages after the front end take."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from agrislam.geometry.odometry import OdometryChain
from agrislam.records import Detection, Measurement


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


@dataclass(slots=True)
class FrameMatch:
    """A frame's detections that are mapped, with the objects they went to; the range
    errors of mapped landmarks are reported as theirs, not mapped."""

    robot: str
    robot_index: int  # the robot's number, in the order robots were first heard of
    chain: OdometryChain  # its dead reckoning
    t: float
    pose: np.ndarray  # (3,) the robot's pose when the frame was associated
    detections: list[Detection]  # those mapped
    placed: PlacedDetections  # those mapped
    object_ids: np.ndarray  # (m,) of the mapped detections, new objects included
    new_ids: np.ndarray  # the objects the frame started
    reported: np.ndarray  # (all,) each detection's object: range errors their landmark's
    mapped: np.ndarray  # (all,) which detections are mapped
    reach: float  # m, the farthest an object could be from a detection and be associated
    # (m,) the NIS of each mapped detection the GNN put on an object (NaN: new, rejoined)
    nis: np.ndarray = field(default_factory=lambda: np.empty(0))
    rejoined: bool = False  # the frame was put back on settled objects (association/rejoin.py)

    @property
    def attributes(self) -> list:
        """Each mapped detection's measured attributes."""
        return [d.attributes for d in self.detections]

    @property
    def seen(self) -> np.ndarray:
        """The objects the frame detected, each once."""
        return np.unique(self.object_ids)

    def report_ids(self) -> np.ndarray:
        """(all,) the object each of the frame's detections went to."""
        reported = self.reported.copy()
        reported[self.mapped] = self.object_ids
        return reported
