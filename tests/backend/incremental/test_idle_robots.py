"""Many short-lived robots (backend/incremental/fold.py, `_idle`): with more robots holding
keyframes than half of `slam.keyframes_kept`, those that stopped driving give their
keyframes up, so the live graph follows the robots that drive; one that drives again takes
its newest keyframe up again where it stood, and maps on."""

import numpy as np
import pytest

from agrislam.backend import RelativePosition, detection_covariance, make_backend
from agrislam.backend.graph import POSE, key_kind
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.se2 import compose, to_robot_frame

STEP = np.array([0.5, 0.0, 0.0])  # each robot drives along x
ODOMETRY = np.diag([1e-4, 1e-4, 1e-5])
START_SIGMA = np.array([0.01, 0.01, 0.005])
SIGHT = 1.5  # m, how far a robot sees


def _frame(g, robot: str, pose: np.ndarray, landmarks: np.ndarray) -> None:
    """One frame of `robot` at `pose`: the landmarks within SIGHT, then the update."""
    for k in np.flatnonzero(np.hypot(*(landmarks - pose[:2]).T) < SIGHT):
        z = to_robot_frame(pose, landmarks[k])
        g.add_observation(robot, int(k), RelativePosition(z, detection_covariance(z, 0.03, 0.01)))
    g.update()


@pytest.fixture
def forty_robots():
    """Forty robots of three frames each along a strip of landmarks, one after the other
    (a fold every 4 steps, 6 keyframes kept): the back end, the robots' last poses, the
    landmarks and the live poses after each robot."""
    slam = SlamConfig(window=4, keyframes_kept=6, refine_turn_deg=0.0)
    g = make_backend(slam, RowsConfig())
    landmarks = np.column_stack([np.arange(0.0, 24.0, 0.4), np.tile([0.5, -0.5], 30)])
    for k, xy in enumerate(landmarks):
        g.add_object(k, xy)
    robots = {f"r{n}": np.array([0.5 * n, 0.0, 0.0]) for n in range(40)}
    live_poses = []
    for t, (robot, pose) in enumerate(robots.items()):
        g.add_robot(robot, pose, START_SIGMA, float(3 * t))
        _frame(g, robot, pose, landmarks)
        for step in (1, 2):
            pose = robots[robot] = compose(pose, STEP)
            g.add_odometry(robot, float(3 * t + step), STEP, ODOMETRY)
            _frame(g, robot, pose, landmarks)
        live_poses.append(sum(key_kind(int(k)) == POSE for k in g.node_keys("live")))
    return g, robots, landmarks, live_poses


def _drive(g, robot: str, pose: np.ndarray, landmarks: np.ndarray, steps: int) -> np.ndarray:
    for step in range(1, steps + 1):
        pose = compose(pose, STEP)
        g.add_odometry(robot, 200.0 + step, STEP, ODOMETRY)
        _frame(g, robot, pose, landmarks)
    return pose


def _rms(g, landmarks: np.ndarray) -> float:
    placed = g.object_positions(np.arange(len(landmarks)))
    return float(np.sqrt(np.mean(np.sum((placed - landmarks) ** 2, axis=1))))


def test_robots_that_stopped_give_their_keyframes_up_and_one_that_drives_again_maps_on(
    forty_robots,
):
    g, robots, landmarks, live_poses = forty_robots
    # 40 robots held 2 keyframes each at least (80 live poses); now the idle ones let go
    assert max(live_poses) <= 12
    newest = g.graph.robot("r0").keys[-1]
    assert g.node_state(newest) == "frozen" and g.keyframes("r0") == []
    np.testing.assert_allclose(g.current_pose("r0"), robots["r0"], atol=0.05)
    # r0 drives on from where it stopped: its newest keyframe live again, held where it was
    pose = _drive(g, "r0", robots["r0"], landmarks, 3)
    assert g.node_state(newest) == "live" and g.keyframes("r0")[0] == newest
    np.testing.assert_allclose(g.current_pose("r0"), pose, atol=0.05)
    g.refine()
    assert _rms(g, landmarks) < 0.05


def test_an_object_last_seen_by_a_robot_that_let_go_retires_on_a_keyframe_that_drives(
    forty_robots,
):
    """A row constraint brings back a plant whose robot has no keyframe left: the next
    fold retires it on a keyframe of the robot that drives."""
    g, robots, landmarks, _ = forty_robots
    g.add_row(0, np.array([0.0, 0.5]), 0.0)
    g.add_row_constraint(0, 0)  # landmark 0, last seen by r2
    assert g.node_state(g.graph.require_object(0)) == "live"
    g.add_robot("r40", robots["r39"], START_SIGMA, 150.0)
    _frame(g, "r40", robots["r39"], landmarks)
    _drive(g, "r40", robots["r39"], landmarks, 4)  # a fold
    assert g.node_state(g.graph.require_object(0)) == "retired"
    assert g.anchor_of(g.graph.require_object(0)).keyframe in g.keyframes("r40")
    assert _rms(g, landmarks) < 0.05
