"""Range outliers (not in the paper): without a field prior, a detection with a gross range
error of a mapped landmark goes to that landmark without moving the map, and the objects
that only such errors made are pruned at the end of the survey."""

from __future__ import annotations

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.geometry import se2
from agrislam.geometry.placed import PlacedDetections
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex
from agrislam.snapshot import STATUS_ACTIVE

# an object detected at most this often may be made of range outliers (RangeOutliers)
OUTLIER_MAX_MEAS = 10
# an object born on a settled object's ray is judged a range error once it has left the map
# (merged, pruned) or gone JUDGED_AFTER_S without growing past OUTLIER_MAX_MEAS detections,
# a landmark once grown and still in the map LANDMARK_AFTER_S after its birth. Detections
# are taken for range errors once TRUST_JUDGED were judged, at least TRUST_SHARE of them
# range errors: arena 0.98-1.0 (2 % gross range errors), Victoria Park 0.88 (23 of 26: a
# tree the laser missed and the one behind it)
JUDGED_AFTER_S, LANDMARK_AFTER_S = 30.0, 120.0
TRUST_JUDGED, TRUST_SHARE = 20, 0.95
# the run's issue that counts the detections so taken
RANGE_ERRORS = (
    "detections taken for a mapped landmark's range errors (association/range_outliers.py)"
)


class RangeOutliers:
    """Objects made of range outliers. A range-bearing sensor's gross range error puts a
    detection on the ray of the landmark it saw, at a wrong range; the object it starts
    catches the next such detections from about the same viewpoint in its gate and lives
    on a few (arena: 2-9 where landmarks have hundreds).
    A detection is explained when a settled object (detected more than OUTLIER_MAX_MEAS
    times) the frame did not detect lies on its ray (within three bearing sigmas, the
    robot's pose uncertainty included) at another range (beyond three of the detection's
    range sigmas). A detection that would start a new object and is explained is a
    detection of that object, with a wrong range: it is reported as such and not mapped
    (`on_rays`, `WorldModel.step`), once the survey has shown that such detections are
    range errors: the objects they started were nearly all short-lived (`trusted`); a
    laser that misses a tree and sees the one behind it starts real landmarks on the
    rays. A young object (detected at most OUTLIER_MAX_MEAS times)
    all of whose detections are explained (the settled object came later, or the frame
    had detected it) is pruned at the end of the survey. Without a field prior only
    (`enabled`): a crop camera sees plants in rows along its rays."""

    def __init__(self, enabled: bool = False) -> None:
        self.enabled = enabled
        self._explained: dict[int, int] = {}  # young object -> its detections explained
        self._reach = 0.0  # m, the farthest detection so far
        self._born: dict[int, float] = {}  # object born on a settled ray -> birth time
        self.judged = {"range error": 0, "landmark": 0}  # what those objects turned out

    @property
    def trusted(self) -> bool:
        """Whether a detection on a settled object's ray is taken for its range error."""
        judged = sum(self.judged.values())
        return judged >= TRUST_JUDGED and self.judged["range error"] >= TRUST_SHARE * judged

    def born(self, ids: np.ndarray, t: float, objects: ObjectTable) -> None:
        """New objects `ids` started by detections on settled objects' rays, watched until
        judged; those watched so far are judged as of time `t`."""
        self._born.update(dict.fromkeys(ids.tolist(), t))
        for obj, birth in list(self._born.items()):
            grown = objects.n_meas[obj] > OUTLIER_MAX_MEAS
            if objects.status[obj] != STATUS_ACTIVE or (
                not grown and objects.last_update[obj] < t - JUDGED_AFTER_S
            ):
                self.judged["range error"] += 1  # merged, pruned, or never seen again
            elif grown and birth < t - LANDMARK_AFTER_S:
                self.judged["landmark"] += 1
            else:
                continue
            del self._born[obj]

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
        if not self.enabled or placed.robot_xy is None:
            return
        if len(placed):  # the farthest the sensor sees, so far: where a landmark may stand
            reach = float(np.linalg.norm(placed.robot_xy, axis=1).max())
            self._reach = max(self._reach, reach)
        young = np.flatnonzero(objects.n_meas[object_ids] <= OUTLIER_MAX_MEAS)
        explaining = self.on_rays(pose, placed, young, object_ids, index, backend, objects)
        for obj in object_ids[young[explaining >= 0]].tolist():
            self._explained[obj] = self._explained.get(obj, 0) + 1

    def of_new_objects(
        self,
        pose: np.ndarray,  # (3,) the robot's pose
        placed: PlacedDetections,
        object_ids: np.ndarray,  # (m,) where association put them, -1: a new object
        index: SpatialIndex,
        backend: GraphBackend,
        objects: ObjectTable,
    ) -> np.ndarray:
        """(m,) for each detection that would start a new object, the settled object that
        explains it (its detection with a gross range error); -1 for the others."""
        new = np.flatnonzero(object_ids < 0)
        explaining = np.full(len(object_ids), -1, dtype=np.int64)
        detected = object_ids[object_ids >= 0]
        explaining[new] = self.on_rays(pose, placed, new, detected, index, backend, objects)
        return explaining

    def on_rays(
        self,
        pose: np.ndarray,  # (3,) the robot's pose
        placed: PlacedDetections,
        rows: np.ndarray,  # the detections asked about
        detected: np.ndarray,  # objects the frame detected: they explain no other detection
        index: SpatialIndex,
        backend: GraphBackend,
        objects: ObjectTable,
    ) -> np.ndarray:
        """(len(rows),) for each detection the settled object that explains it (the nearest
        to its ray in bearing sigmas), -1 where none does."""
        explaining = np.full(len(rows), -1, dtype=np.int64)
        robot_xy, cov, n_meas = placed.robot_xy, placed.robot_cov, objects.n_meas
        if not self.enabled or robot_xy is None or cov is None or len(rows) == 0:
            return explaining
        rng = np.linalg.norm(robot_xy[rows], axis=1)
        around = objects.active(index.query(pose[None, :2], self._reach + 1.0))
        around = around[(n_meas[around] > OUTLIER_MAX_MEAS) & ~np.isin(around, detected)]
        if len(around) == 0:
            return explaining
        settled = se2.to_robot_frame(pose, backend.object_positions(around))
        along = robot_xy[rows] / np.maximum(rng, 1e-9)[:, None]  # (y, 2) unit rays
        across = along @ np.array([[0.0, 1.0], [-1.0, 0.0]])
        cov = cov[rows]
        sigma_r = np.sqrt(np.einsum("yi,yij,yj->y", along, cov, along))
        if placed.pose_cov is not None:  # the robot unsure of its pose widens the bearing
            turn = se2.rotation(pose[2])
            cov = cov + turn.T @ placed.pose_cov[rows] @ turn
        sigma_b = np.sqrt(np.einsum("yi,yij,yj->y", across, cov, across)) / rng
        bearing = np.arctan2(along[:, 1], along[:, 0])
        off = np.abs(se2.wrap_angle(bearing[:, None] - np.arctan2(settled[:, 1], settled[:, 0])))
        off /= sigma_b[:, None]
        range_off = np.abs(rng[:, None] - np.linalg.norm(settled, axis=1)[None, :])
        off[range_off <= 3.0 * sigma_r[:, None]] = np.inf  # at its range: not a range error
        nearest = np.argmin(off, axis=1)
        explained = off[np.arange(len(rows)), nearest] <= 3.0
        explaining[explained] = around[nearest[explained]]
        return explaining

    def made_of_outliers(self, ids: np.ndarray, n_meas: np.ndarray) -> list[int]:
        """Those of `ids` (active objects) whose every detection was explained."""
        return [i for i in ids.tolist() if 0 < n_meas[i] <= self._explained.get(i, 0)]
