"""What iSAM2 lets go of (backend/incremental/retired.py): retired rows, poses between their
window's keyframes, deferred covariances, frozen keyframes and the factors that tie a
retired object back."""

import pickle

import gtsam
import numpy as np

from agrislam.backend.incremental.retired import (
    Anchored,
    FrozenKeyframes,
    Retired,
    RetiredObjects,
    RetiredPoses,
)
from agrislam.backend.values import values_at
from agrislam.geometry.se2 import compose, rotation

X0, X1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
L0 = gtsam.symbol("l", 0)


def test_retired_rows_stay_dense_and_follow_their_keys():
    table = RetiredObjects()
    for n in range(40):  # past the first growth
        table.put(gtsam.symbol("l", n), X0 + n % 3, np.array([n, -n]), cov=np.eye(2) * n)
    assert len(table) == 40
    assert table.remove(gtsam.symbol("l", 3)) and not table.remove(gtsam.symbol("l", 3))
    anchor = table.pop(gtsam.symbol("l", 0))
    assert anchor.keyframe == X0 and anchor.z.tolist() == [0, 0]
    assert len(table) == 38 and gtsam.symbol("l", 0) not in table
    keys = [gtsam.symbol("l", n) for n in (39, 3, 38, 7)]
    rows = table.rows(keys)
    assert rows[1] == -1 and np.all(rows[[0, 2, 3]] >= 0)
    np.testing.assert_array_equal(table.local[rows[[0, 2, 3]]], [[39, -39], [38, -38], [7, -7]])
    np.testing.assert_array_equal(table.cov[rows[3]], np.eye(2) * 7)
    np.testing.assert_array_equal(table.keyframes[rows[[0, 3]]], [X0, X0 + 1])
    anchor = table.anchor(keys[0])
    anchor.z[:] = 0.0  # a copy: the table keeps its own
    assert table.local[rows[0]].tolist() == [39, -39]
    table.relocate(np.zeros((38, 2)))
    assert not np.any(table.local)
    poses = Retired(3)
    poses.put(X1, X0, np.array([1.0, 2.0, 0.1]))
    assert poses.row(X1) == 0 and poses.row(X0) is None


def window_poses(start, end, poses):
    """Values holding keyframes X0 (start), X1 (end) and poses x2.. at the given poses."""
    values = gtsam.Values()
    for n, pose in enumerate([start, end, *poses]):
        values.insert(gtsam.symbol("x", n), gtsam.Pose2(*pose))
    return values, [gtsam.symbol("x", 2 + n) for n in range(len(poses))]


def test_retired_poses_sit_between_their_window_keyframes_by_distance_driven():
    # tied to the window's newest keyframe alone, its poses swung with a correction
    # that reached that keyframe later
    driven = [(1.0, 0.0, 0.0), (2.0, 0.0, 0.0), (8.0, 0.0, 0.0)]
    values, keys = window_poses((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), driven)
    table = RetiredPoses()
    table.put_window(keys, X0, X1, values)
    rows = table.rows(keys)
    frames = {X0: np.array([0.0, 0.0, 0.0]), X1: np.array([10.0, 0.0, 0.0])}

    def frame(keyframes):
        return np.array([frames[int(k)] for k in keyframes]).reshape(-1, 3)

    np.testing.assert_allclose(table.placed(rows, frame), driven, atol=1e-12)
    frames[X1] = np.array([10.0, 1.0, 0.2])  # the end keyframe moved and turned later
    moved = table.placed(rows, frame)
    # shares 0.1, 0.2, 0.8 of the distance: each pose moves by its share of X1's move
    np.testing.assert_allclose(moved[:, 2], [0.02, 0.04, 0.16], atol=1e-12)
    for (x, _, _), share, got in zip(driven, (0.1, 0.2, 0.8), moved, strict=True):
        held_by_end = frames[X1][:2] + rotation(0.2) @ [x - 10.0, 0.0]
        np.testing.assert_allclose(got[:2], share * held_by_end + (1 - share) * np.array([x, 0]))
    # a solution read back: every pose placed exactly where it says
    solution, _ = window_poses(frames[X0], frames[X1], [(1.0, 0.5, 0.1), (5, 1, 0), (9, 2, 1)])
    table.relocate_at(solution)
    expected = values_at(solution, np.array(keys, dtype=np.uint64), 3)
    np.testing.assert_allclose(table.placed(rows, frame), expected, atol=1e-12)


def test_a_window_whose_start_is_unknown_is_held_by_its_end_keyframe():
    values, keys = window_poses((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), [(5.0, 0.0, 0.0)])
    values.erase(X0)
    table = RetiredPoses()
    table.put_window(keys, X0, X1, values)
    assert table.starts.tolist() == [X1]
    frame = lambda k: np.tile([10.0, 1.0, 0.0], (len(k), 1))  # noqa: E731
    np.testing.assert_allclose(table.placed(table.rows(keys), frame), [[5.0, 1.0, 0.0]])


def test_deferred_covariances_are_computed_once_when_read_or_settled():
    """A fold's covariances wait: `pace` computes the oldest once a step unless
    a read did; a read computes only what it reads; a pop, an anchor and a pickle
    settle first; a removal leaves unneeded work undone."""
    table, calls = RetiredObjects(), []
    keys = [gtsam.symbol("l", n) for n in range(6)]

    def retire(some: list[int], first: int, scale: float) -> None:
        for key in some:
            table.put(key, X0, np.array([1.0, 0.0]), cov=np.full((2, 2), np.nan))

        def compute():
            calls.append(first)
            return [np.eye(2) * scale] * len(some)

        table.defer(some, compute)

    for n, first in enumerate(range(0, 6, 2)):
        retire(keys[first : first + 2], first, n + 1.0)
    assert calls == []
    table.pace()  # the oldest
    assert calls == [0]
    rows = table.rows(keys[4:5])
    np.testing.assert_array_equal(table.covariances(rows), [np.eye(2) * 3])
    assert calls == [0, 4]  # only the computation that gives what was read
    table.pace()  # a read settled one since the last pace: nothing more this step
    assert calls == [0, 4]
    np.testing.assert_array_equal(table.anchor(keys[2]).cov, np.eye(2) * 2)
    assert calls == [0, 4, 2] and not np.isnan(table.cov).any()
    retire(keys[:2], 7, 4.0)
    assert table.remove(keys[0]) and table.remove(keys[1])  # pruned: nobody waits for it
    table.settle()
    assert calls == [0, 4, 2]
    retire(keys[:1], 9, 5.0)
    copy = pickle.loads(pickle.dumps(table))  # a checkpoint: computed before, not after
    assert calls[-1] == 9 and table.anchor(keys[0]).cov[0, 0] == 5.0
    np.testing.assert_array_equal(copy.cov, table.cov)


def test_an_object_on_a_frozen_keyframe_comes_back_with_a_prior_where_it_stands():
    """keyframes_kept: an aged keyframe is held where it stood; an object retired onto it
    comes back with a prior at keyframe (+) z, as uncertain as z given the keyframe plus
    the keyframe's own uncertainty carried along its lever arm (a heading error of the
    keyframe moves a plant 10 m ahead sideways by 10 m x the heading's sigma)."""
    frozen = FrozenKeyframes()
    anchor = Anchored(X0, np.array([10.0, 0.0]), np.diag([0.01, 0.04]))
    live = frozen.anchor_factor(anchor, L0)
    assert list(live.keys()) == [X0, L0]  # a live keyframe: tied to it, as before
    pose, pose_cov = np.array([1.0, 2.0, np.pi / 2]), np.diag([0.0, 0.0, 0.01**2])
    frozen.freeze(X0, pose, pose_cov)
    assert X0 in frozen and X1 not in frozen and len(frozen) == 1
    factor = frozen.anchor_factor(anchor, L0)
    assert list(factor.keys()) == [L0]
    np.testing.assert_allclose(factor.prior(), compose(pose, np.r_[anchor.z, 0.0])[:2])
    # turned by 90 degrees: z's x variance lies along y; the heading's 0.01 rad at 10 m
    # adds 0.1 m sideways, along -x
    expected = np.diag([0.04 + 0.1**2, 0.01])
    cov = np.linalg.inv(factor.noiseModel().R().T @ factor.noiseModel().R())
    np.testing.assert_allclose(cov, expected, atol=1e-12)
    values = gtsam.Values()
    values.insert(X0, gtsam.Pose2(5.0, 6.0, 0.1))
    frozen.moved_to(values)  # a refine of the whole record moves it
    np.testing.assert_allclose(frozen.pose(X0), [5.0, 6.0, 0.1])
    np.testing.assert_array_equal(frozen.covariance(X0), pose_cov)
    assert frozen.pose(X1) is None and frozen.covariance(X1) is None
