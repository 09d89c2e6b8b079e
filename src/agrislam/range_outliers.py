"""Objects made of range outliers (issue 11, not in the paper): a survey without a field
prior keeps, at its end, none of the objects that only its sensor's gross range errors
made."""

from __future__ import annotations

import numpy as np

from agrislam.association import PlacedDetections
from agrislam.geometry import se2
from agrislam.geometry.backend import GraphBackend
from agrislam.objects import ObjectTable
from agrislam.spatial_index import SpatialIndex

# an object detected at most this often may be made of range outliers (RangeOutliers)
OUTLIER_MAX_MEAS = 10


class RangeOutliers:
    """Objects made of range outliers. A range-bearing sensor's gross range error puts a
    detection on the ray of the landmark it saw, at a wrong range; the object it starts
    catches the next such detections from about the same viewpoint in its gate and lives
    on a few (arena: 2-9 where landmarks have hundreds).
    A detection of a young object (detected at most OUTLIER_MAX_MEAS times) is explained
    when a settled object the frame did not detect lies on its ray (within three bearing
    sigmas, the robot's pose uncertainty included) at another range (beyond three of the
    detection's range sigmas); an object all of whose detections
    are explained is pruned at the end of the survey. Without a field prior only
    (`enabled`): a crop camera sees plants in rows along its rays."""

    def __init__(self) -> None:
        self.enabled = False
        self._explained: dict[int, int] = {}  # young object -> its detections explained
        self._reach = 0.0  # m, the farthest detection so far

    def saw(
        self,
        pose: np.ndarray,  # (3,) the robot's pose
        placed: PlacedDetections,
        object_ids: np.ndarray,  # (m,) where they went
        index: SpatialIndex,
        backend: GraphBackend,
        objects: ObjectTable,
    ) -> None:
        """Counts the frame's detections of young objects that settled objects explain."""
        robot_xy, cov, n_meas = placed.robot_xy, placed.robot_cov, objects.n_meas
        if not self.enabled or robot_xy is None or cov is None:
            return
        young = np.flatnonzero(n_meas[object_ids] <= OUTLIER_MAX_MEAS)
        if len(robot_xy):  # the farthest the sensor sees, so far: where a landmark may stand
            self._reach = max(self._reach, float(np.linalg.norm(robot_xy, axis=1).max()))
        if len(young) == 0:
            return
        rng = np.linalg.norm(robot_xy[young], axis=1)
        around = index.query(pose[None, :2], self._reach + 1.0)
        around = around[(n_meas[around] > OUTLIER_MAX_MEAS) & ~np.isin(around, object_ids)]
        if len(around) == 0:
            return
        settled = se2.to_robot_frame(pose, backend.object_positions(around))
        along = robot_xy[young] / np.maximum(rng, 1e-9)[:, None]  # (y, 2) unit rays
        across = along @ np.array([[0.0, 1.0], [-1.0, 0.0]])
        cov = cov[young]
        sigma_r = np.sqrt(np.einsum("yi,yij,yj->y", along, cov, along))
        if placed.pose_cov is not None:  # the robot unsure of its pose widens the bearing
            turn = se2.rotation(pose[2])
            cov = cov + turn.T @ placed.pose_cov[young] @ turn
        sigma_b = np.sqrt(np.einsum("yi,yij,yj->y", across, cov, across)) / rng
        bearing = np.arctan2(along[:, 1], along[:, 0])
        off = np.abs(se2.wrap_angle(bearing[:, None] - np.arctan2(settled[:, 1], settled[:, 0])))
        range_off = np.abs(rng[:, None] - np.linalg.norm(settled, axis=1)[None, :])
        explained = (off <= 3.0 * sigma_b[:, None]) & (range_off > 3.0 * sigma_r[:, None])
        for obj in object_ids[young[explained.any(axis=1)]].tolist():
            self._explained[obj] = self._explained.get(obj, 0) + 1

    def made_of_outliers(self, ids: np.ndarray, n_meas: np.ndarray) -> list[int]:
        """Those of `ids` (active objects) whose every detection was explained."""
        return [i for i in ids.tolist() if 0 < n_meas[i] <= self._explained.get(i, 0)]
