"""A lost robot rejoins the map (association/rejoin.py): a frame whose detections start objects near
settled ones that a small correction of the robot's pose would explain goes to those."""

from collections import Counter

import numpy as np

from agrislam.association.rejoin import LOST_WINDOW_S, REJOINED, Rejoiner
from agrislam.geometry import se2
from agrislam.geometry.placed import PlacedDetections
from agrislam.mapping.births import Births
from agrislam.mapping.spatial_index import SpatialIndex

ROBOT = np.array([0.0, 0.0, 0.0])
# settled landmarks 3-4 m ahead; the robot's true pose is ROBOT
LANDMARKS = np.array([[3.0, 0.5], [3.5, -0.8], [4.0, 0.2]])
COV = np.diag([0.13**2, 0.03**2])  # range-bearing-like, in the map frame here


class Objects:
    """The back end as the rejoiner sees it: positions and covariances of objects."""

    def __init__(self, xy: np.ndarray) -> None:
        self.xy = xy

    def object_positions(self, ids: np.ndarray) -> np.ndarray:
        return self.xy[ids]

    def object_covariances(self, ids: np.ndarray) -> np.ndarray:
        return np.repeat(0.01**2 * np.eye(2)[None], len(ids), axis=0)


def rejoin(landmarks: np.ndarray, believed: np.ndarray, seen: np.ndarray, object_ids=None):
    """The frame of detections `seen` (map frame, true pose) placed from the `believed`
    pose, all new by the GNN, LOST_WINDOW_S after `landmarks` were started."""
    index = SpatialIndex()
    ids = np.arange(len(landmarks))
    index.move(ids, landmarks)
    births = Births(LOST_WINDOW_S)
    births.record(0.0, len(ids))
    rejoiner = Rejoiner(index, births, Counter())
    rejoiner.gate_chi2 = 9.21
    c, s = np.cos(believed[2]), np.sin(believed[2])
    placed = _placed(se2.to_robot_frame(ROBOT, seen) @ np.array([[c, s], [-s, c]]) + believed[:2])
    object_ids = np.full(len(seen), -1) if object_ids is None else object_ids
    return rejoiner.rejoin(
        believed[:2], placed, object_ids, LOST_WINDOW_S + 1.0, Objects(landmarks)
    ), rejoiner


def _placed(xy: np.ndarray) -> PlacedDetections:
    cov = np.repeat(COV[None], len(xy), axis=0)
    return PlacedDetections(xy=xy, cov=cov, measurements=[{}] * len(xy))


def test_a_robot_whose_heading_drifted_past_the_gates_rejoins_its_landmarks():
    believed = np.array([0.05, -0.1, -0.15])  # 0.15 rad off: 0.5 m at 3.5 m
    ids, rejoiner = rejoin(LANDMARKS, believed, LANDMARKS)
    assert ids.tolist() == [0, 1, 2]
    assert rejoiner.issues[REJOINED] == 1


def test_one_lost_detection_is_left_to_the_gnn():
    believed = np.array([0.0, 0.0, -0.15])
    ids, rejoiner = rejoin(LANDMARKS, believed, LANDMARKS[:1])
    assert ids.tolist() == [-1]
    assert rejoiner.issues[REJOINED] == 0


def test_a_correction_larger_than_the_bounds_is_not_taken():
    believed = np.array([0.0, 0.0, -0.6])  # twice MAX_TURN_RAD
    ids, _ = rejoin(LANDMARKS, believed, LANDMARKS)
    assert ids.tolist() == [-1, -1, -1]


def test_two_places_that_fit_as_well_leave_the_frame_as_it_was():
    # a pair of landmarks seen, and its twin 0.6 m to the side: either could be it
    pair = LANDMARKS[:2]
    twins = np.vstack([pair, pair + np.array([0.0, 0.6])])
    believed = np.array([0.0, 0.3, 0.0])  # halfway: both corrections within the bounds
    ids, _ = rejoin(twins, believed, pair)
    assert ids.tolist() == [-1, -1]


def test_a_frame_already_on_settled_objects_is_not_moved():
    believed = np.array([0.0, 0.0, -0.15])
    ids, rejoiner = rejoin(LANDMARKS, believed, LANDMARKS, object_ids=np.array([0, 1, 2]))
    assert ids.tolist() == [0, 1, 2]
    assert rejoiner.issues[REJOINED] == 0
