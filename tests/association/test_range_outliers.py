"""Range outliers (association/range_outliers.py): a detection that would start a new
object on the ray
of a settled object the frame did not detect is that object's, with a wrong range, and is
not mapped; a young object whose every detection lay on such a ray is pruned at the end."""

import numpy as np

from agrislam.association.range_outliers import (
    JUDGED_AFTER_S,
    LANDMARK_AFTER_S,
    OUTLIER_MAX_MEAS,
    RANGE_ERRORS,
    TRUST_JUDGED,
    TRUST_SHARE,
    RangeOutliers,
)
from agrislam.config import AgrislamConfig, SemanticsConfig
from agrislam.geometry.placed import PlacedDetections
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex
from agrislam.records import Detection, Detections, Meta, RobotStart
from agrislam.semantics.beliefs import BeliefTable
from agrislam.snapshot import STATUS_MERGED
from agrislam.world import WorldModel

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
    outliers = RangeOutliers(enabled)
    return outliers, objects, index


def placed_at(xy: np.ndarray, pose_cov=None) -> PlacedDetections:
    """Detections at `xy` (k, 2) from ROBOT, the robot's pose adding `pose_cov` (2, 2)."""
    cov = np.repeat(COV[None], len(xy), axis=0)
    return PlacedDetections(
        xy=xy,
        cov=cov,
        measurements=[{}] * len(xy),
        robot_xy=xy,
        robot_cov=cov,
        pose_cov=None if pose_cov is None else np.repeat(pose_cov[None], len(xy), axis=0),
    )


def detect(outliers, objects, index, seen: list[int], pose_cov=None, xy=XY) -> None:
    """One frame from ROBOT detecting the objects `seen` at `xy`, the robot's pose adding
    `pose_cov` (2, 2) to each detection."""
    seen_ids = np.array(seen)
    objects.beliefs.update(seen_ids, [{}] * len(seen), 20.0)
    placed = placed_at(xy[seen_ids], pose_cov)
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


def test_a_new_objects_detection_on_a_settled_objects_ray_is_that_objects():
    outliers, objects, index = world()
    detect(outliers, objects, index, [SETTLED])  # the sensor sees as far as the landmark
    placed = placed_at(XY[[ON_RAY, ASIDE]])
    args = (index, Positions(), objects)
    # both would start new objects: the one on the ray is the landmark's
    explained = outliers.of_new_objects(ROBOT, placed, np.array([-1, -1]), *args)
    assert explained.tolist() == [SETTLED, -1]
    # a detection association gave an object is not asked about
    associated = outliers.of_new_objects(ROBOT, placed, np.array([ASIDE, -1]), *args)
    assert associated.tolist() == [-1, -1]
    # the landmark detected in the same frame explains no other detection
    detected = outliers.of_new_objects(ROBOT, placed, np.array([-1, SETTLED]), *args)
    assert detected.tolist() == [-1, -1]


def test_a_detection_at_the_settled_objects_own_range_is_not_a_range_error():
    outliers, objects, index = world()
    detect(outliers, objects, index, [SETTLED])
    near = placed_at(np.array([[3.8, 0.05]]))  # 1.5 range sigmas short of the landmark
    assert outliers.of_new_objects(ROBOT, near, np.array([-1]), index, Positions(), objects) == -1


def test_range_errors_are_trusted_once_the_objects_they_started_were_nearly_all_short_lived():
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    ids = objects.add(TRUST_JUDGED, 0.0)
    outliers = RangeOutliers()
    outliers.born(ids, 0.0, objects)
    for k in range(OUTLIER_MAX_MEAS + 1):  # the first grows
        objects.beliefs.update(ids[:1], [{}], float(k))
    objects.seen(ids[:1], 0, np.zeros((3, 3, 3)), np.zeros((1, 2)), np.zeros((1, 2, 2)))
    outliers.born(ids[:0], JUDGED_AFTER_S + 1.0, objects)  # the others were not seen again
    assert outliers.judged == {"range error": TRUST_JUDGED - 1, "landmark": 0}
    outliers.born(ids[:0], LANDMARK_AFTER_S + 1.0, objects)  # still there: a landmark
    assert outliers.judged == {"range error": TRUST_JUDGED - 1, "landmark": 1}
    assert (TRUST_JUDGED - 1) / TRUST_JUDGED >= TRUST_SHARE and outliers.trusted
    outliers.judged["landmark"] += 1  # one landmark more: short of the share
    assert not outliers.trusted


def test_an_object_born_on_a_ray_and_merged_was_no_landmark():
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    ids = objects.add(2, 0.0)
    outliers = RangeOutliers()
    outliers.born(ids[1:], 0.0, objects)
    objects.retire(ids[1:], STATUS_MERGED, into=int(ids[0]))
    outliers.born(ids[:0], 1.0, objects)
    assert outliers.judged == {"range error": 1, "landmark": 0}


def test_a_world_reports_a_range_outlier_as_its_landmark_and_does_not_map_it():
    """Survey without a field prior: a landmark 4 m ahead seen from a standing robot, and
    now and then a frame whose range came back wrong. Each such detection starts an object
    that is never seen again, until the world has seen enough of them: then it goes to the
    landmark, no object starts, and the landmark does not move."""
    world_model = WorldModel(AgrislamConfig())
    world_model.process(Meta(robots={"r1": RobotStart(np.zeros(3), np.full(3, 1e-3))}))

    def frame(t: float, rng: float) -> Detections:
        sighting = Detection(range=rng, bearing=0.0, sigma_range=0.13, sigma_bearing=0.015)
        return Detections(t, "r1", (sighting,))

    for k in range(OUTLIER_MAX_MEAS + 2):
        landmark = int(world_model.process(frame(float(k), 4.0 + 0.05 * (-1) ** k)).object_ids[0])
    wrong_ranges = np.arange(0.8, 40.0, 0.8)  # a gate apart, none at the landmark's
    wrong_ranges = wrong_ranges[np.abs(wrong_ranges - 4.0) > 0.5][:TRUST_JUDGED]
    t = 20.0
    for rng in wrong_ranges:
        assert len(world_model.process(frame(t, rng)).new_ids) == 1  # not trusted yet
        world_model.process(frame(t + JUDGED_AFTER_S + 1.0, 4.0))  # the landmark again
        t += JUDGED_AFTER_S + 2.0
    assert world_model.stages.associator.outliers.trusted
    before = world_model.backend.object_positions(np.array([landmark]))[0].copy()
    n_meas, n_objects = int(world_model.objects.n_meas[landmark]), len(world_model.objects)
    report = world_model.process(frame(t, 2.0))
    assert report.object_ids.tolist() == [landmark] and len(report.new_ids) == 0
    assert len(world_model.objects) == n_objects
    assert world_model.objects.n_meas[landmark] == n_meas  # not mapped
    assert world_model.issues[RANGE_ERRORS] == 1  # and the user is told
    after = world_model.backend.object_positions(np.array([landmark]))[0]
    assert np.allclose(after, before, atol=1e-6)
