"""Marginal covariances kept for association (backend/incremental/marginal_cache.py): read again
after their reuse (ten times as long for a node without a new factor since), or after a
new factor, unless the object is settled."""

from __future__ import annotations

import pickle

import gtsam
import numpy as np

from agrislam.backend.incremental.marginal_cache import SETTLED, STALE, MarginalCache


def read_at(cache: MarginalCache, key: int) -> int | None:
    """The step the kept covariance of `key` was read at (None: none is kept)."""
    kept = cache.kept(key)
    return None if kept is None else kept[0]


class Reads:
    """A stand-in for iSAM2's marginalCovariance that counts its calls."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, key: int) -> np.ndarray:
        self.count += 1
        return np.eye(2) * self.count


def test_a_seen_objects_covariance_serves_its_reuse_steps_then_is_read_again():
    cache, read = MarginalCache(), Reads()
    cache.sighted(7)
    first = cache.get(7, 0, 3, read)
    cache.sighted(7)  # seen since the read (a young object's is read again on measured)
    assert cache.get(7, 2, 3, read) is first and read.count == 1 and read_at(cache, 7) == 0
    assert cache.get(7, 3, 3, read)[0, 0] == 2.0 and read_at(cache, 7) == 3


def test_a_covariance_with_no_new_factor_serves_stale_times_as_long():
    cache, read = MarginalCache(), Reads()
    for _ in range(SETTLED + 1):
        cache.sighted(7)  # a settled object, out of sight after its read
    for key in (7, 99):  # 99: a keyframe, never sighted
        cache.get(key, 0, 3, read)
        cache.get(key, STALE * 3 - 1, 3, read)
    assert read.count == 2
    cache.measured([99])  # a fold's factor on the keyframe: read again at once
    cache.get(99, STALE * 3 - 1, 3, read)
    assert read.count == 3 and read_at(cache, 99) == STALE * 3 - 1
    cache.get(7, STALE * 3, 3, read)
    cache.get(99, 2 * STALE * 3 - 1, 3, read)
    assert read.count == 5 and read_at(cache, 7) == STALE * 3


def test_a_new_factor_calls_for_a_fresh_read_until_the_object_is_settled():
    cache, read = MarginalCache(), Reads()
    for sighting in range(SETTLED + 2):
        cache.get(7, 0, 10, read)
        cache.sighted(7)
        cache.measured([7, 99])  # 99: a pose, never sighted: always read again
        fresh = sighting < SETTLED
        assert (read_at(cache, 7) is None) == fresh, sighting
    assert read.count == SETTLED + 1  # the settled object's read served on
    cache.get(99, 0, 10, read)
    cache.measured([99])
    assert read_at(cache, 99) is None


def test_a_dropped_node_keeps_its_sightings_a_forgotten_one_does_not():
    cache, read = MarginalCache(), Reads()
    for _ in range(SETTLED + 1):
        cache.sighted(7)
    cache.get(7, 0, 10, read)
    cache.drop(7)  # folded out of the live graph
    assert cache.held() == set()
    cache.get(7, 1, 10, read)
    cache.measured([7])
    assert cache.held() == {7}
    back = pickle.loads(pickle.dumps(cache))  # a checkpoint: sightings kept, reads not
    assert back.held() == set()
    back.get(7, 2, 10, read)
    back.measured([7])
    assert back.held() == {7}
    cache.forget(7)
    cache.get(7, 2, 10, read)
    cache.measured([7])
    assert cache.held() == set()


def test_the_reads_due_come_from_one_joint_marginal_equal_to_each_read_alone():
    # a real iSAM2: a pose chain seeing three points
    isam, graph, values = gtsam.ISAM2(), gtsam.NonlinearFactorGraph(), gtsam.Values()
    x, points = [gtsam.symbol("x", i) for i in range(3)], [gtsam.symbol("l", i) for i in range(3)]
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    graph.add(gtsam.PriorFactorPose2(x[0], gtsam.Pose2(), noise))
    for i in range(3):
        values.insert(x[i], gtsam.Pose2(i, 0, 0))
        values.insert(points[i], gtsam.Point2(i, 1))
        if i:
            graph.add(gtsam.BetweenFactorPose2(x[i - 1], x[i], gtsam.Pose2(1, 0, 0), noise))
        for j in range(3):
            bearing = gtsam.Rot2.fromAngle(np.arctan2(1.0, j - i))
            sensed = gtsam.noiseModel.Diagonal.Sigmas([0.01, 0.1])
            graph.add(
                gtsam.BearingRangeFactor2D(x[i], points[j], bearing, np.hypot(1, j - i), sensed)
            )
    isam.update(graph, values)
    cache, read = MarginalCache(), Reads()
    cache.get(points[0], 0, 10, read)  # still fresh: not read again
    cache.read_jointly([points[0], points[1], points[2], points[1], x[2]], 1, 10, isam)
    for key in (points[1], points[2], x[2]):
        assert read_at(cache, key) == 1
        np.testing.assert_allclose(
            cache.get(key, 2, 10, read), isam.marginalCovariance(key), rtol=1e-9, atol=1e-12
        )
    assert read.count == 1 and read_at(cache, points[0]) == 0
    cache.sighted(points[0])
    cache.read_jointly([points[0]], 10, 10, isam)  # one due: read alone, by `get`
    assert read_at(cache, points[0]) == 0
