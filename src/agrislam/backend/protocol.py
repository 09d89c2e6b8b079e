"""The graph back end interface (sec. 2.6): measurement types, the protocol the world model
calls, and `make_backend`, which builds the configured back end."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.noise import (
    Measurement,
    RangeBearing,
    RelativePosition,
    detection_covariance,
)

__all__ = [
    "GraphBackend",
    "Measurement",
    "RangeBearing",
    "RelativePosition",
    "detection_covariance",
    "make_backend",
]


@runtime_checkable
class GraphBackend(Protocol):
    """A pose-and-object graph: robot chains, objects, detections, rows; solved per step."""

    def add_robot(
        self,
        robot: str,
        start_pose: np.ndarray | None = None,
        start_sigma: np.ndarray | None = None,
        t: float | None = None,
    ) -> None: ...

    def add_odometry(self, robot: str, t: float, delta: np.ndarray, cov: np.ndarray) -> None: ...

    def current_pose(self, robot: str) -> np.ndarray: ...

    def current_pose_covariance(self, robot: str) -> np.ndarray: ...

    def add_gnss(self, robot: str, value: np.ndarray, cov: np.ndarray) -> None: ...

    def add_object(self, object_id: int, xy: np.ndarray) -> None: ...

    def add_observation(self, robot: str, object_id: int, measurement: Measurement) -> None: ...

    # True: this step folded a window (work that can wait is best left to the next step)
    def update(self) -> bool: ...

    def object_ids(self) -> np.ndarray: ...

    def object_positions(self, object_ids: np.ndarray) -> np.ndarray: ...

    def object_covariances(self, object_ids: np.ndarray) -> np.ndarray: ...

    def trajectory(self, robot: str) -> tuple[np.ndarray, np.ndarray]: ...

    def sightings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def merge_objects(self, keep: int, drop: int) -> None: ...

    def remove_object(self, object_id: int) -> None: ...

    # rows (sec. 2.6.2), driven by rows.RowTracker
    def add_row(self, row: int, point: np.ndarray, angle: float) -> None: ...

    def add_row_constraint(self, object_id: int, row: int) -> None: ...

    def add_row_spacing(self, row_a: int, row_b: int, distance: float) -> None: ...

    def remove_row_constraint(self, object_id: int) -> None: ...

    def remove_row(self, row: int) -> None: ...

    def set_row_angle(self, row: int, angle: float) -> None: ...

    def row_points(self, rows: np.ndarray) -> np.ndarray: ...

    def rows_of(self, object_ids: np.ndarray) -> np.ndarray: ...

    def refine(self) -> None: ...


def make_backend(slam: SlamConfig, rows: RowsConfig) -> GraphBackend:
    """The back end `slam.backend` names: "incremental" (windowed iSAM2, the default) or
    "batch" (the paper's whole-graph LM/Dogleg every step)."""
    if slam.backend == "batch":
        from agrislam.geometry.batch import BatchBackend

        return BatchBackend(slam, rows)
    from agrislam.geometry.incremental import IncrementalBackend

    return IncrementalBackend(slam, rows)
