"""The incremental back end's state parts (backend/incremental/isam_state.py) on their own: the
pending update against a real iSAM2, the slot table's bookkeeping."""

import gtsam
import numpy as np
import pytest

from agrislam.backend.incremental.isam_state import Entry, PendingUpdate, SlotTable, per_distinct
from agrislam.backend.incremental.retired import Anchored, anchor_factor
from agrislam.backend.values import values_at

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
