"""A refine folds the whole history onto the keyframes (backend/incremental/refold.py): with several
robots sharing landmarks, into one dense factor over every keyframe, which iSAM2 would
re-eliminate at every step after. A refine during the survey refuses such a
fold and relinearises the keyframe graph instead."""

import itertools

import numpy as np

from agrislam.backend import RelativePosition, detection_covariance, make_backend
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.se2 import compose, rotation

LANDMARKS = np.array([[2.0, 0.0], [0.0, 2.0], [-2.0, 0.0], [0.0, -2.0]])
ROBOTS = 3
STEP = np.array([0.2, 0.0, 0.2])  # each robot circles inside the landmarks


def survey(steps: int = 60, robots: int = ROBOTS, refine_turn_deg: float = 0.0, bias=0.0, kept=100):
    """Robots circling inside four landmarks, seeing them all at every step; the odometry
    reports `bias` rad more turn than was driven."""
    slam = SlamConfig(window=5, refine_turn_deg=refine_turn_deg, keyframes_kept=kept)
    g = make_backend(slam, RowsConfig())
    poses = {}
    for n in range(robots):
        angle = 2 * np.pi * n / robots
        poses[f"r{n}"] = np.array([np.cos(angle), np.sin(angle), angle + np.pi / 2])
        g.add_robot(f"r{n}", poses[f"r{n}"], np.array([1e-3, 1e-3, 1e-4]))
    for obj, xy in enumerate(LANDMARKS):
        g.add_object(obj, xy)
    for k in range(steps):
        name = f"r{k % robots}"
        if k >= robots:
            poses[name] = compose(poses[name], STEP)
            reported = STEP + np.array([0.0, 0.0, bias])
            g.add_odometry(name, float(k), reported, np.diag([1e-3, 1e-3, 1e-4]))
        look(g, name, poses[name])
        g.update()
    return g


def look(g, robot: str, pose: np.ndarray) -> None:
    """`robot` at `pose` sees the four landmarks."""
    for obj, xy in enumerate(LANDMARKS):
        rel = rotation(pose[2]).T @ (xy - pose[:2])
        g.add_observation(robot, obj, RelativePosition(rel, detection_covariance(rel, 0.05, 0.01)))


def widest_live_factor(g) -> int:
    factors = g.isam_factors()
    return max(factors.at(n).size() for n in range(factors.size()) if factors.exists(n))


def test_the_history_of_robots_sharing_landmarks_folds_into_one_factor_over_every_keyframe():
    g = survey()
    keyframes = sum(len(g.keyframes(robot)) for robot in g.graph.robots)
    g.refine()  # the end of a survey: no step comes after
    assert widest_live_factor(g) == keyframes > 30
    np.testing.assert_allclose(g.object_positions(np.arange(4)), LANDMARKS, atol=1e-3)


def test_a_refine_during_the_survey_refuses_so_wide_a_fold_and_relinearises_instead():
    g = survey()
    refines = g.refines
    g.refine(max_keys=10)
    assert widest_live_factor(g) <= 10 and g.refines == refines + 1
    assert g.whole_refine < g.refines  # not a whole refine: the index need not move all
    np.testing.assert_allclose(g.object_positions(np.arange(4)), LANDMARKS, atol=1e-3)
    g.update()  # and the survey goes on


def test_with_several_robots_a_turn_relinearises_during_the_survey_and_alone_it_refolds():
    """A keyframe turned by more than refine_turn_deg calls a refine: one robot's history
    is refolded at the batch solution; several robots' would tie all their keyframes."""
    for robots, whole in ((1, True), (ROBOTS, False)):
        g = survey(robots=robots, refine_turn_deg=0.5, bias=0.1)
        assert g.refines > 0
        assert (g.whole_refine > 0) == whole
        if robots > 1:
            keyframes = sum(len(g.keyframes(robot)) for robot in g.graph.robots)
            assert widest_live_factor(g) < keyframes


def test_robots_sharing_the_map_share_the_keyframes_it_keeps():
    """Each fold links every robot's keyframes through the landmarks they share: kept per
    robot, five robots' graph would grow five times as wide."""
    alone, together = survey(steps=40, robots=1, kept=6), survey(steps=120, robots=3, kept=6)
    assert [len(alone.keyframes(r)) for r in alone.graph.robots] == [7]  # the first + 6
    assert [len(together.keyframes(r)) for r in together.graph.robots] == [3, 3, 3]
    assert len(together.node_keys("frozen")) > 0
    np.testing.assert_allclose(together.object_positions(np.arange(4)), LANDMARKS, atol=1e-3)


def test_a_robot_that_joins_shrinks_the_others_share_a_keyframe_a_fold():
    """Aged at once, the first robot's surplus would be folded away in one stalling step."""
    g = make_backend(SlamConfig(window=5, refine_turn_deg=0.0, keyframes_kept=6), RowsConfig())
    for obj, xy in enumerate(LANDMARKS):
        g.add_object(obj, xy)
    poses = {"r0": np.array([1.0, 0.0, np.pi / 2]), "r1": np.array([-1.0, 0.0, -np.pi / 2])}
    kept = []
    for k in range(100):
        name = "r0" if k < 40 or k % 2 else "r1"
        if name not in g.graph.robots:
            g.add_robot(name, poses[name], np.array([1e-3, 1e-3, 1e-4]))
        else:
            poses[name] = compose(poses[name], STEP)
            g.add_odometry(name, float(k), STEP, np.diag([1e-3, 1e-3, 1e-4]))
        look(g, name, poses[name])
        g.update()
        kept.append(len(g.keyframes("r0")))
    assert kept[39] == 7  # alone, the first keyframe and its six
    assert all(before - after <= 1 for before, after in itertools.pairwise(kept))
    assert kept[-1] == 4  # then the first and half of six
