"""Odometry that can be doubted (frontend/doubt.py): what a robot's motion so far makes a
suspect, how a frame's detections judge it, and the chain holding both versions."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from agrislam.config import SemanticsConfig
from agrislam.frontend.doubt import (
    CONTRADICTED,
    DOUBTED,
    FLOORED,
    JITTER_EVERY,
    MAX_WAIT,
    MOVES,
    MotionDoubt,
)
from agrislam.geometry.odometry import OdometryChain, guessed_motion_covariance
from agrislam.mapping.births import Births
from agrislam.mapping.map_state import MapState
from agrislam.mapping.objects import ObjectTable
from agrislam.semantics.beliefs import BeliefTable

COV = np.diag([1e-6, 1e-6, 1e-8])  # a record's odometry covariance
STEP = np.array([0.2, 0.0, 0.0])  # the robot's motion over each 0.5 s


def _driven(doubt: MotionDoubt, steps: int = MOVES + 5) -> None:
    """A robot 'r' that drove straight, its motion a little uneven."""
    rng = np.random.default_rng(0)
    for _ in range(steps):
        wobble = rng.normal(0.0, [2e-3, 1e-3, 1e-3])
        assert doubt.check("r", STEP + wobble, 0.5, COV) is None


@pytest.fixture
def doubt() -> MotionDoubt:
    """A motion doubt over a map with plants every 0.5 m along y = +-0.5 m."""
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    state = MapState(objects, Births(30.0))
    xy = np.array([(x, y) for x in np.arange(0.0, 10.0, 0.5) for y in (-0.5, 0.5)])
    ids = objects.add(len(xy), 0.0)
    state.index.move(ids, xy)
    return MotionDoubt(state, Counter())


@pytest.mark.parametrize(
    ("motion", "impossible"),
    [
        (STEP + np.array([2.0, 0.0, 0.0]), True),  # a jump of 2 m: ten times its fastest
        (STEP + np.array([0.0, 0.0, 1.0]), False),  # a spin, or the first turn of a robot
        (STEP * 4.0, False),  # four times as fast, within ten times
    ],
)
def test_a_change_far_beyond_the_robots_is_a_suspect(doubt, motion, impossible):
    _driven(doubt)
    suspect = doubt.check("r", np.asarray(motion), 0.5, COV)
    assert suspect is not None and suspect.impossible == impossible
    np.testing.assert_allclose(suspect.instead, STEP, atol=0.01)  # its latest motion on


def test_nothing_is_a_suspect_before_the_robot_moved_enough(doubt):
    _driven(doubt, MOVES - 1)
    assert doubt.check("r", STEP + np.array([2.0, 0.0, 0.0]), 0.5, COV) is None


def test_the_record_after_a_glitch_is_no_suspect(doubt):
    """A glitch of a `pose` record is two jumps (there and back); a motion that changes
    back to the robot's latest believed one is no suspect, whatever came before."""
    _driven(doubt)
    assert doubt.check("r", STEP + np.array([0.0, 0.0, 1.0]), 0.5, COV) is not None
    assert doubt.check("r", STEP, 0.5, COV) is None


def test_an_odometry_covariance_far_below_the_robots_jitter_is_raised_to_it(doubt):
    """A robot whose increments differ by millimetres from one to the next, each claiming
    a sigma of 1e-8 m: once its jitter is known, a record's translation and heading are
    raised to the noise that jitter means; a record within CONTRADICTED of it is not."""
    sure = np.diag([1e-16, 1e-16, 1e-16])
    assert doubt.covariance("r", sure, 0.5) is sure  # no jitter known yet
    rng = np.random.default_rng(1)
    for _ in range(2 * JITTER_EVERY):
        doubt.check("r", STEP + rng.normal(0.0, [4e-3, 4e-3, 5e-4]), 0.5, sure)
    raised = doubt.covariance("r", sure, 0.5)
    assert doubt.issues == {FLOORED: 1}
    sigmas = np.sqrt(np.diag(raised))
    np.testing.assert_allclose(sigmas, [4e-3, 4e-3, 5e-4], rtol=0.5)
    fair = np.diag((sigmas / CONTRADICTED * 2.0) ** 2)
    assert doubt.covariance("r", fair, 0.5) is fair
    cut = fair / 100.0  # a record cut at a frame's time: a share of the covariance
    assert doubt.covariance("r", cut, 0.5 / 100.0) is cut


def _frame(doubt: MotionDoubt, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The robot-frame detections of the map's plants within 2 m ahead of `pose`."""
    xy = doubt.map.index.position(np.arange(len(doubt.map.objects)))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    local = (xy - pose[:2]) @ np.array([[c, -s], [s, c]])
    ahead = local[(local[:, 0] > 0.3) & (local[:, 0] < 2.0)]
    return ahead, np.repeat(np.diag([0.01, 0.0025])[None], len(ahead), axis=0)


def test_the_frame_judges_by_how_its_detections_fit_the_map(doubt):
    _driven(doubt)
    jump = STEP + np.array([2.2, 0.0, 0.0])
    doubt.hold("r", doubt.check("r", jump, 0.5, COV))
    node = np.array([3.0, 0.0, 0.0])
    truth = node + STEP  # the robot really moved its usual step
    fit = doubt.fit("r", node, (jump, STEP), *_frame(doubt, truth))
    assert fit is not None and fit[1] < fit[0]
    assert doubt.judge("r", fit, looked=True) is True
    assert doubt.issues == {DOUBTED: 1} and not doubt.held


def test_a_motion_the_detections_confirm_is_believed_and_widens_the_robots_own(doubt):
    _driven(doubt)
    turn = STEP + np.array([0.0, 0.0, 0.6])
    doubt.hold("r", doubt.check("r", turn, 0.5, COV))
    node = np.array([3.0, 0.0, 0.0])
    truth = node + np.array([0.2, 0.0, 0.6])
    fit = doubt.fit("r", node, (turn, STEP), *_frame(doubt, truth))
    assert doubt.judge("r", fit, looked=True) is False
    assert not doubt.issues
    assert doubt.check("r", turn, 0.5, COV) is None  # its turns so far hold it now


def test_a_frame_off_the_map_cannot_judge(doubt):
    _driven(doubt)
    turn = STEP + np.array([0.0, 0.0, 0.6])
    doubt.hold("r", doubt.check("r", turn, 0.5, COV))
    far = np.array([[0.5, 30.0], [1.0, 30.0]])
    cov = np.repeat(np.eye(2)[None] * 0.01, 2, axis=0)
    fit = doubt.fit("r", np.array([3.0, 0.0, 0.0]), (turn, STEP), far, cov)
    assert fit is None
    for _ in range(MAX_WAIT - 1):
        assert doubt.judge("r", None, looked=True) is None
        assert doubt.judge("r", None, looked=False) is None  # a frame without detections
    assert doubt.judge("r", None, looked=True) is False  # believed: it may be a first turn


def test_an_impossible_jump_no_frame_can_judge_is_doubted_at_once(doubt):
    _driven(doubt)
    doubt.hold("r", doubt.check("r", STEP + np.array([50.0, 0.0, 0.0]), 0.5, COV))
    assert doubt.judge("r", None, looked=False) is True
    assert doubt.issues == {DOUBTED: 1}


def test_the_chain_holds_both_versions_until_the_frame_settles():
    chain = OdometryChain()
    chain.start(np.zeros(3), 0.0)
    chain.move(0.5, STEP, COV)
    chain.take_pending()
    jump, instead = STEP + np.array([2.0, 0.0, 0.0]), STEP
    chain.move(1.0, jump, COV, instead)
    chain.move(1.5, STEP, COV)
    recorded, replaced = chain.in_doubt
    np.testing.assert_allclose(recorded, [2.4, 0.0, 0.0])
    np.testing.assert_allclose(replaced, [0.4, 0.0, 0.0])
    chain.settle(True)
    assert chain.in_doubt is None
    np.testing.assert_allclose(chain.pose, [0.6, 0.0, 0.0])
    np.testing.assert_allclose(chain.track()[1][:, 0], [0.0, 0.2, 0.4, 0.6])
    delta, parts = chain.take_pending()
    np.testing.assert_allclose(delta, [0.4, 0.0, 0.0])
    guessed = guessed_motion_covariance(instead)
    np.testing.assert_allclose(parts.sum(axis=0), 2 * COV + guessed, atol=1e-8)


def test_a_settled_belief_leaves_the_chain_as_recorded():
    chain = OdometryChain()
    chain.start(np.zeros(3), 0.0)
    chain.move(0.5, STEP + np.array([0.0, 0.0, 0.6]), COV, STEP)
    chain.settle(False)
    assert chain.in_doubt is None
    np.testing.assert_allclose(chain.pose, [0.2, 0.0, 0.6])
