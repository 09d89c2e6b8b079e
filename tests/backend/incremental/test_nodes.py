"""The node table (backend/incremental/nodes.py): one state per node, changed only by its
transitions, and the same table read back from what a pickle holds."""

import pickle

import gtsam
import numpy as np
import pytest

from agrislam.backend.incremental.nodes import FROZEN, LIVE, NEW, RETIRED, NodeTable
from agrislam.backend.incremental.retired import Anchored

X0, X1, X2, X3 = (gtsam.symbol("x", i) for i in range(4))
L0, R0 = gtsam.symbol("l", 0), gtsam.symbol("r", 0)


def survey() -> NodeTable:
    """A robot's first pose (a keyframe) and two more, an object and a row, all live."""
    nodes = NodeTable()
    for key, value in ((X0, np.zeros(3)), (X1, np.array([1.0, 0, 0])), (X2, np.array([2.0, 0, 0]))):
        nodes.add(key, value)
    nodes.add(L0, np.array([1.5, 1.0]))
    nodes.add(R0, np.array([0.0, 1.0]), kept=True)
    nodes.add_keyframe("r", X0)
    for key in (X0, X1, X2, L0, R0):
        nodes.enter(key)
    return nodes


def test_a_node_is_new_until_a_factor_uses_it_then_live():
    nodes = NodeTable()
    nodes.add(L0, [1.0, 2.0])
    assert nodes.state(L0) == NEW and nodes.state(X0) is None
    held = nodes.enter(L0)
    np.testing.assert_array_equal(held, [1.0, 2.0])
    assert nodes.state(L0) == LIVE and nodes.enter(L0) is None  # live already
    with pytest.raises(KeyError, match="no estimate"):
        nodes.enter(X0)


def test_a_fold_retires_the_window_and_freezes_the_aged_keyframes():
    nodes = survey()
    nodes.add_keyframe("r", X2)
    assert nodes.window(set()) == {X1, L0}  # keyframes and rows stay live
    point = gtsam.Values()
    for key, x in ((X0, 0.0), (X1, 1.0), (X2, 2.0)):
        point.insert(key, gtsam.Pose2(x, 0.0, 0.0))
    nodes.retire_poses([X1], X0, X2, point)
    nodes.retire_object(L0, X2, np.array([-0.5, 1.0]))
    nodes.left({X1, L0})
    assert [nodes.state(k) for k in (X1, L0, X2, R0)] == [RETIRED, RETIRED, LIVE, LIVE]
    assert nodes.live() == {X0, X2, R0}
    nodes.add(X3, np.array([3.0, 0, 0]))
    nodes.enter(X3)
    nodes.add_keyframe("r", X3)
    aged = nodes.age(kept=1, per_fold=2)
    assert aged == {X2} and nodes.keyframes("r") == [X0, X3] and not nodes.is_kept(X2)
    nodes.freeze(X2, np.array([2.0, 0, 0]), np.eye(3))
    nodes.left(aged)
    assert nodes.state(X2) == FROZEN and X2 not in nodes.live()
    assert sorted(nodes.anchor_keyframes().tolist()) == [X2, X2]


def test_an_idle_robot_gives_up_every_keyframe_and_its_newest_thaws_when_it_drives_again():
    nodes = survey()
    nodes.add_keyframe("r", X2)
    aged = nodes.age(kept=1, per_fold=2, idle={"r"})
    assert aged == {X0, X2} and nodes.keyframes("r") == [] and nodes.holding() == []
    for key, x in ((X0, 0.0), (X2, 2.0)):
        nodes.freeze(key, np.array([x, 0.0, 0.1]), np.diag([0.01, 0.04, 0.001]))
    nodes.left(aged)
    pose, prior = nodes.thaw(X2, "r")
    assert nodes.state(X2) == LIVE and X2 in nodes.live() and nodes.is_kept(X2)
    assert nodes.keyframes("r") == [X2] and nodes.holding() == ["r"]
    assert X2 not in nodes.frozen and nodes.state(X0) == FROZEN
    np.testing.assert_array_equal(pose, [2.0, 0.0, 0.1])
    assert isinstance(prior, gtsam.PriorFactorPose2) and prior.keys() == [X2]
    np.testing.assert_allclose(prior.noiseModel().covariance(), np.diag([0.01, 0.04, 0.001]))


def test_a_retired_object_seen_again_comes_back_with_its_anchor_and_a_forgotten_node_is_gone():
    nodes = survey()
    nodes.retire_object(L0, X0, np.array([1.5, 1.0]))
    nodes.defer([L0], lambda: [np.eye(2)])
    nodes.left({L0})
    held = nodes.enter(L0)
    assert isinstance(held, Anchored) and held.keyframe == X0
    np.testing.assert_array_equal(held.cov, np.eye(2))
    assert nodes.state(L0) == LIVE
    nodes.forget(L0)
    nodes.forget(R0)
    assert nodes.state(L0) is None and nodes.state(R0) is None
    assert L0 not in nodes.live() and not nodes.is_kept(R0)


def test_a_pickled_table_reads_back_with_each_node_in_its_state():
    nodes = survey()
    nodes.add(X3, np.zeros(3))
    nodes.retire_object(L0, X0, np.array([1.5, 1.0]))
    nodes.freeze(X1, np.zeros(3), np.eye(3))
    nodes.left({L0, X1})
    back = pickle.loads(pickle.dumps(nodes))
    for key in (X0, X1, X2, X3, L0, R0):
        assert back.state(key) == nodes.state(key)
    assert back.live() == nodes.live()
