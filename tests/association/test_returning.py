"""A robot back from a long time without seeing the map (association/returning.py): beside
two clusters that look alike it is not given to the wrong one on its first frames' evidence,
and it is put back on the map once three landmarks agree where it is."""

import numpy as np

from agrislam.association.returning import RETURNED, two_places
from agrislam.config import AgrislamConfig
from agrislam.records import Detection, Detections, Meta, Odometry, RobotStart
from agrislam.world import WorldModel

# cluster A: a pair and a third landmark; cluster B: a pair like A's, 1.5 m to the right
PAIR_A = np.array([[3.0, 0.0], [3.0, 0.22]])
THIRD_A = np.array([[3.3, 0.45]])
PAIR_B = PAIR_A - np.array([0.0, 1.5])
LANDMARKS = np.vstack([PAIR_A, THIRD_A, PAIR_B])
SLIP = np.array([0.0, -1.5])  # where the blind robot's dead reckoning ends up, truly at rest
BLIND_S, STEP_S = 30.0, 0.5
ODOMETRY_COV = np.diag([0.15**2, 0.15**2, 0.002**2])  # a step's reported noise: the slip is 2 sigma


def frame(t: float, landmarks: np.ndarray) -> Detections:
    """Exact range-bearing sightings of `landmarks` from the origin, facing +x."""
    return Detections(
        t,
        "r1",
        tuple(
            Detection(
                range=float(np.hypot(*xy)),
                bearing=float(np.arctan2(xy[1], xy[0])),
                sigma_range=0.05,
                sigma_bearing=0.01,
            )
            for xy in landmarks
        ),
    )


def survey() -> tuple[WorldModel, np.ndarray, list[np.ndarray]]:
    """The robot maps both clusters, goes blind while its odometry slips by SLIP, then sees
    A's pair alone for a few frames and A's three landmarks after: the world, the objects
    of the five landmarks and each returning frame's objects."""
    world = WorldModel(AgrislamConfig())
    world.process(Meta(robots={"r1": RobotStart(np.zeros(3), np.full(3, 1e-3))}))
    t = 0.0
    for _ in range(40):
        mapped = world.process(frame(t, LANDMARKS)).object_ids
        world.process(Odometry(t + 0.1, "r1", delta=np.zeros(3), cov=ODOMETRY_COV * 1e-4))
        t += STEP_S
    steps = int(BLIND_S / STEP_S)
    for _ in range(steps):
        delta = np.r_[SLIP / steps, 0.0]
        world.process(Odometry(t, "r1", delta=delta, cov=ODOMETRY_COV))
        t += STEP_S
    seen = []
    for landmarks in [PAIR_A] * 4 + [np.vstack([PAIR_A, THIRD_A])] * 6:
        seen.append(world.process(frame(t, landmarks)).object_ids)
        world.process(Odometry(t + 0.1, "r1", delta=np.zeros(3), cov=ODOMETRY_COV * 1e-4))
        t += STEP_S
    return world, mapped, seen


def test_a_returning_robot_is_not_given_to_the_cluster_that_looks_like_its_own():
    world, mapped, seen = survey()
    pair_b = mapped[3:]
    assert world.issues[RETURNED] == 1
    for ids in seen[:4]:  # A's pair alone: it fits A and B alike
        assert not np.isin(world.resolve(ids), pair_b).any()


def test_a_returning_robot_is_put_back_once_three_landmarks_agree():
    world, mapped, seen = survey()
    for ids in seen[-3:]:
        assert world.resolve(ids).tolist() == mapped[:3].tolist()
    xy = world.backend.object_positions(world.active_ids())
    assert len(xy) == len(LANDMARKS)
    assert np.abs(xy - LANDMARKS[np.argsort(np.argsort(mapped))]).max() < 0.1


def test_two_places_is_a_frame_that_fits_two_shifts_far_apart():
    objects = np.vstack([PAIR_A, PAIR_B])
    pair_seen = PAIR_A + SLIP
    assert two_places(pair_seen, objects, reach=2.0, tolerance=0.1, apart=0.5)
    assert not two_places(pair_seen, objects, reach=1.0, tolerance=0.1, apart=0.5)
    three_seen = np.vstack([PAIR_A, THIRD_A]) + SLIP
    assert not two_places(three_seen, np.vstack([objects, THIRD_A]), 2.0, 0.1, 0.5)
