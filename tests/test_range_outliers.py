"""Objects made of range outliers (range_outliers.py): a young object whose every detection
lay on the ray of a settled object the frame did not detect is pruned at the end."""

import numpy as np

from agrislam.association import PlacedDetections
from agrislam.config import SemanticsConfig
from agrislam.objects import ObjectTable
from agrislam.range_outliers import OUTLIER_MAX_MEAS, RangeOutliers
from agrislam.semantics.beliefs import BeliefTable
from agrislam.spatial_index import SpatialIndex

ROBOT = np.array([0.0, 0.0, 0.0])  # at the origin, facing +x
SETTLED, ON_RAY, ASIDE = 0, 1, 2
XY = np.array([[4.0, 0.0], [2.0, 0.02], [2.0, 1.2]])  # a landmark, a point on its ray, one off
COV = np.diag([0.13**2, (2.0 * 0.015) ** 2])  # range 0.13 m, bearing 0.015 rad at 2 m


class Positions:
    def object_positions(self, ids: np.ndarray) -> np.ndarray:
        return XY[ids]


def world(enabled: bool = True):
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    ids = objects.add(len(XY), 0.0)
    for k in range(OUTLIER_MAX_MEAS + 5):  # the landmark is settled
        objects.beliefs.update(ids[:1], [{}], float(k))
    index = SpatialIndex()
    index.move(ids, XY)
    outliers = RangeOutliers()
    outliers.enabled = enabled
    return outliers, objects, index


def detect(outliers, objects, index, seen: list[int], pose_cov=None, xy=XY) -> None:
    """One frame from ROBOT detecting the objects `seen` at `xy`, the robot's pose adding
    `pose_cov` (2, 2) to each detection."""
    seen_ids = np.array(seen)
    objects.beliefs.update(seen_ids, [{}] * len(seen), 20.0)
    cov = np.repeat(COV[None], len(seen), axis=0)
    placed = PlacedDetections(
        xy=xy[seen_ids],
        cov=cov,
        measurements=[{}] * len(seen),
        robot_xy=xy[seen_ids],
        robot_cov=cov,
        pose_cov=None if pose_cov is None else np.repeat(pose_cov[None], len(seen), axis=0),
    )
    outliers.saw(ROBOT, placed, seen_ids, index, Positions(), objects)


def test_an_object_on_the_ray_of_a_landmark_the_frames_missed_is_made_of_outliers():
    outliers, objects, index = world()
    detect(outliers, objects, index, [SETTLED])  # the sensor sees as far as the landmark
    for _ in range(3):
        detect(outliers, objects, index, [ON_RAY])
    made = outliers.made_of_outliers(np.arange(len(XY)), objects.n_meas)
    assert made == [ON_RAY]


def test_an_object_off_every_ray_is_kept():
    outliers, objects, index = world()
    detect(outliers, objects, index, [SETTLED])
    detect(outliers, objects, index, [ASIDE])
    assert outliers.made_of_outliers(np.arange(len(XY)), objects.n_meas) == []


def test_a_landmark_detected_in_the_same_frame_explains_nothing():
    outliers, objects, index = world()
    detect(outliers, objects, index, [SETTLED])
    detect(outliers, objects, index, [ON_RAY])
    detect(outliers, objects, index, [ON_RAY, SETTLED])  # a second detection, not an outlier
    assert outliers.made_of_outliers(np.arange(len(XY)), objects.n_meas) == []


def test_with_a_field_prior_nothing_is_counted():
    outliers, objects, index = world(enabled=False)
    detect(outliers, objects, index, [SETTLED])
    detect(outliers, objects, index, [ON_RAY])
    assert outliers.made_of_outliers(np.arange(len(XY)), objects.n_meas) == []


def test_the_robots_pose_uncertainty_widens_the_ray():
    # 0.1 rad off the landmark's bearing: seven detection sigmas, but the robot is unsure of
    # its heading by about that much (0.2 m across at 2 m)
    xy = XY.copy()
    xy[ON_RAY] = 2.0 * np.array([np.cos(0.1), np.sin(0.1)])
    for pose_cov, made in ((None, []), (np.diag([0.0, 0.2**2]), [ON_RAY])):
        outliers, objects, index = world()
        detect(outliers, objects, index, [SETTLED], xy=xy)
        for _ in range(2):
            detect(outliers, objects, index, [ON_RAY], pose_cov=pose_cov, xy=xy)
        assert outliers.made_of_outliers(np.arange(len(XY)), objects.n_meas) == made
