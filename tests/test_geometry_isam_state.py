"""The incremental back end's state parts (geometry/isam_state.py) on their own: the
pending update against a real iSAM2, the slot table's bookkeeping, the retired rows."""

import pickle

import gtsam
import numpy as np
import pytest

from agrislam.geometry.isam_state import (
    Anchored,
    Entry,
    PendingUpdate,
    Retired,
    RetiredObjects,
    RetiredPoses,
    SlotTable,
    anchor_factor,
    per_distinct,
    values_at,
)
from agrislam.geometry.se2 import between, rotation

X0, X1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
L0, L1 = gtsam.symbol("l", 0), gtsam.symbol("l", 1)
NOISE3 = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
NOISE2 = gtsam.noiseModel.Isotropic.Sigma(2, 0.1)


def prior(key, xy=(0.0, 0.0)):
    return gtsam.PriorFactorPoint2(key, np.array(xy), NOISE2)


def test_flush_updates_isam2_returns_the_slots_and_clears():
    isam, pending = gtsam.ISAM2(), PendingUpdate()
    pending.enter(X0, np.zeros(3))
    pending.enter(L0, np.array([1.0, 2.0]))
    pending.add(gtsam.PriorFactorPose2(X0, gtsam.Pose2(), NOISE3), Entry((X0,), fid=7))
    pending.add(prior(L0, (9.0, 9.0)), Entry((L0,), fid=8))
    pending.add(prior(L0, (1.0, 2.0)), Entry((L0,), fid=9))
    assert pending.has_factor(8) and pending.has_nodes()
    np.testing.assert_array_equal(pending.guess(L0), [1.0, 2.0])
    assert pending.drop_factor(8) and not pending.drop_factor(8)  # never sent
    filled = pending.flush(isam)
    assert [(slot, e.fid) for slot, e in filled] == [(0, 7), (1, 9)]
    assert isam.getFactorsUnsafe().size() == 2
    np.testing.assert_allclose(isam.calculateEstimatePoint2(L0), [1.0, 2.0], atol=1e-9)
    # cleared: nothing pending, and a second flush has nothing to do
    assert not pending.has_nodes() and pending.guess(L0) is None
    assert not pending.has_factor(7)
    assert pending.flush(isam) is None


def test_flush_removes_slots_and_adds_the_extra_graph():
    isam, pending = gtsam.ISAM2(), PendingUpdate()
    pending.enter(L0, np.zeros(2))
    pending.add(prior(L0), Entry((L0,), fid=0))
    pending.add(prior(L0, (2.0, 0.0)), Entry((L0,), fid=1))
    pending.flush(isam)
    pending.remove([1])
    extra = gtsam.NonlinearFactorGraph()
    extra.push_back(prior(L0, (0.0, 4.0)))
    filled = pending.flush(isam, extra)
    assert [(slot, e.fid, e.keys) for slot, e in filled] == [(2, None, (L0,))]
    factors = isam.getFactorsUnsafe()
    assert not factors.exists(1) and factors.exists(2)
    np.testing.assert_allclose(isam.calculateEstimatePoint2(L0), [0.0, 2.0], atol=1e-6)
    assert pending.flush(isam) is None  # the removal was sent once


def test_dropped_nodes_and_anchors_are_not_sent():
    pending = PendingUpdate()
    pending.enter(L0, np.ones(2))  # where its anchor puts it (not on the keyframe)
    pending.enter(L1, np.ones(2))
    a0, a1 = Anchored(X0, np.ones(2), np.eye(2)), Anchored(X0, np.zeros(2) + 2, np.eye(2))
    pending.add(anchor_factor(a0, L0), Entry((X0, L0), anchor=a0))
    pending.add(anchor_factor(a1, L1), Entry((X0, L1), anchor=a1))
    assert pending.drop_anchors_of(L1) == [a1]
    assert pending.drop_anchors_of(L1) == []
    pending.drop_node(L1)
    assert pending.guess(L1) is None and pending.guess(L0) is not None
    pending.enter(X0, np.zeros(3))
    pending.add(gtsam.PriorFactorPose2(X0, gtsam.Pose2(), NOISE3), Entry((X0,), fid=0))
    filled = pending.flush(gtsam.ISAM2())
    assert [e.anchor for _, e in filled] == [a0, None]


def test_slot_table_queries_and_removal():
    table = SlotTable()
    anchor = Anchored(X0, np.ones(2), np.eye(2))
    table.fill(
        [
            (0, Entry((X0,), fid=10)),
            (1, Entry((X0, X1), fid=11)),
            (2, Entry((X1, L0), fid=12)),
            (3, Entry((X0, L1), anchor=anchor)),
            (4, Entry((X0, X1))),  # folded history
        ]
    )
    assert table.touching({L0, L1}) == [2, 3]
    assert table.inside({X0, X1}) == [0, 1, 4]
    assert table.keys(2) == (X1, L0)
    assert table.pop_factor(11) == 1 and table.pop_factor(11) is None
    assert not table.has_factor(11) and table.inside({X0, X1}) == [0, 4]
    dropped = table.drop(table.touching({L1, L0}))
    assert [e.anchor for e in dropped] == [None, anchor]
    assert table.touching({L0, L1}) == [] and not {L0, L1} & set(table._of_key)  # unlinked
    assert not table.has_factor(12) and table.pop_factor(12) is None
    assert len(table) == 2
    table.reset([Entry((L0,), fid=20), Entry((L1,))])
    assert table.has_factor(20) and not table.has_factor(10)
    assert table.inside({L0, L1}) == [0, 1]
    with pytest.raises(KeyError):
        table.keys(4)


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
    # issue 13: a window's poses were tied to its newest keyframe alone, so a correction
    # that reached that keyframe later swung the whole window about it
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
    # the start keyframe aged away onto X1 (keyframes_kept): the places do not move
    onto = between(frames[X1], frames[X0])  # X0 in X1's frame
    table.rebase(X0, X1, onto)
    assert np.all(table.starts == X1)
    frames[X0] = np.full(3, np.nan)  # no longer read
    np.testing.assert_allclose(table.placed(rows, frame), expected, atol=1e-9)


def test_a_window_whose_start_is_unknown_is_held_by_its_end_keyframe():
    values, keys = window_poses((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), [(5.0, 0.0, 0.0)])
    values.erase(X0)
    table = RetiredPoses()
    table.put_window(keys, X0, X1, values)
    assert table.starts.tolist() == [X1]
    frame = lambda k: np.tile([10.0, 1.0, 0.0], (len(k), 1))  # noqa: E731
    np.testing.assert_allclose(table.placed(table.rows(keys), frame), [[5.0, 1.0, 0.0]])


def test_deferred_covariances_are_computed_once_when_read_or_settled():
    """A fold's covariances wait (issue 14): `pace` computes the oldest once a step unless
    a read did; a read computes only what it reads; a pop, an anchor, a rebase and a
    pickle settle first; a removal leaves unneeded work undone."""
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
    retire(keys[1:2], 8, 6.0)
    table.rebase(X0, X1, np.array([0.0, 0.0, np.pi / 2]))  # turns the settled covariance
    np.testing.assert_allclose(table.anchor(keys[1]).cov, np.eye(2) * 6.0, atol=1e-12)
    assert calls[-1] == 8


def test_values_at_reads_poses_and_points_by_key():
    values = gtsam.Values()
    values.insert(X1, gtsam.Pose2(1.0, 2.0, 0.3))
    values.insert(X0, gtsam.Pose2(4.0, 5.0, -0.2))
    values.insert(L1, np.array([7.0, 8.0]))
    values.insert(gtsam.symbol("r", 0), np.array([9.0, 9.5]))
    poses = values_at(values, np.array([X1, X0, X1], dtype=np.uint64), 3)
    np.testing.assert_array_equal(poses, [[1.0, 2.0, 0.3], [4.0, 5.0, -0.2], [1.0, 2.0, 0.3]])
    points = values_at(values, np.array([gtsam.symbol("r", 0), L1], dtype=np.uint64), 2)
    np.testing.assert_array_equal(points, [[9.0, 9.5], [7.0, 8.0]])


def test_per_distinct_calls_once_per_key():
    calls = []
    got = per_distinct(np.array([5, 3, 5, 5], dtype=np.uint64), lambda k: calls.append(k) or k * 2)
    assert got == [10, 6, 10, 10] and calls == [5, 3]
