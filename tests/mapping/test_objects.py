"""The object table (mapping/objects.py): one owner of every object's lifecycle and sightings."""

import numpy as np

from agrislam.config import SemanticsConfig
from agrislam.mapping.objects import ObjectTable
from agrislam.semantics.beliefs import BeliefTable
from agrislam.snapshot import STATUS_ACTIVE, STATUS_MERGED, STATUS_PRUNED


def table(capacity: int = 2) -> ObjectTable:
    return ObjectTable(BeliefTable(None, SemanticsConfig(), capacity=capacity), capacity)


def test_rows_grow_by_doubling_and_start_active_and_watched():
    objects = table()
    first = objects.add(2, 0.0)
    second = objects.add(3, 1.0)
    assert first.tolist() == [0, 1] and second.tolist() == [2, 3, 4]
    assert len(objects) == 5 == len(objects.beliefs)
    assert np.all(objects.status == STATUS_ACTIVE) and np.all(objects.young)
    assert objects.last_update.tolist() == [0.0, 0.0, 1.0, 1.0, 1.0]


def test_retire_notifies_subscribers_and_resolve_follows_merges():
    objects = table()
    objects.add(4, 0.0)
    heard: list[list[int]] = []
    objects.on_retire(lambda ids: heard.append(ids.tolist()))
    objects.retire(np.array([1]), STATUS_MERGED, into=2)
    objects.retire(np.array([2]), STATUS_MERGED, into=3)
    objects.retire(np.array([0]), STATUS_PRUNED)
    assert heard == [[1], [2], [0]]
    assert objects.active_ids().tolist() == [3]
    assert objects.resolve(np.array([0, 1, 2, 3])).tolist() == [0, 3, 3, 3]
    assert objects.young.tolist() == [False, False, False, True]


def parts(scale: float) -> np.ndarray:
    """Chain drift parts (translation, heading, cross) of a chain that came `scale` far."""
    return scale * np.stack([np.eye(3), np.eye(3), np.zeros((3, 3))])


def seen(objects, ids, robot, drift, xy=(0.0, 0.0)):
    n = len(ids)
    objects.seen(np.array(ids), robot, drift, np.tile(xy, (n, 1)), np.tile(np.eye(2), (n, 1, 1)))


def test_last_seen_belongs_to_the_robot_that_saw_it_last():
    objects = table()
    objects.add(3, 0.0)
    seen(objects, [0, 1], 0, parts(1.0), xy=(1.0, 2.0))
    seen(objects, [1, 2], 1, parts(2.0))
    then = objects.last_seen(np.array([0, 1, 2]), robot=0)
    assert then.known.tolist() == [True, False, False]
    np.testing.assert_array_equal(then.drift[0], parts(1.0))
    np.testing.assert_array_equal(then.xy[0], [1.0, 2.0])  # in its dead-reckoning frame
    assert np.all(then.drift[1:] == 0)
    assert objects.n_frames.tolist() == [1, 2, 1]
    objects.retire(np.array([0]), STATUS_PRUNED)
    assert objects.last_seen(np.array([0]), robot=0).known.tolist() == [False]


def test_a_merged_object_was_last_seen_when_either_was():
    objects = table()
    objects.add(3, 0.0)
    seen(objects, [0], 0, parts(0.0))  # seen at the start
    seen(objects, [1], 0, parts(1.0), xy=(3.0, 0.0))  # its duplicate, seen later
    objects.absorb(keep=0, drop=1)
    then = objects.last_seen(np.array([0]), 0)
    np.testing.assert_array_equal(then.drift[0], parts(1.0))
    np.testing.assert_array_equal(then.xy[0], [3.0, 0.0])  # the sighting moves along
    seen(objects, [2], 1, parts(0.0))  # another robot's
    objects.absorb(keep=0, drop=2)
    assert objects.last_seen(np.array([0]), 1).known.tolist() == [True]
