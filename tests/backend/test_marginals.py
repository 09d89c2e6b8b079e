"""The fold's batched marginal covariances (conditioning.marginal_covariances) against
GTSAM's own, where the Schur complement serves and where GTSAM must decide."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from agrislam.backend.graph import object_key, pose_key
from agrislam.backend.incremental.conditioning import indeterminate_key, marginal_covariances

rng = np.random.default_rng(4)
ODOMETRY = gtsam.noiseModel.Diagonal.Sigmas([0.05, 0.02, 0.01])
SIGHTING = gtsam.noiseModel.Diagonal.Sigmas([0.02, 0.04])  # bearing (rad), range


def survey(poses: int = 12, objects: int = 20) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """A robot driving along x, each object seen (as a 2-D point, relative) from 3 poses."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.push_back(gtsam.PriorFactorPose2(pose_key(0, 0), gtsam.Pose2(), ODOMETRY))
    for i in range(poses):
        values.insert(pose_key(0, i), gtsam.Pose2(0.5 * i, 0.01 * i, 0.002 * i))
        if i:
            step = gtsam.Pose2(0.5, 0.01, 0.002)
            graph.push_back(
                gtsam.BetweenFactorPose2(pose_key(0, i - 1), pose_key(0, i), step, ODOMETRY)
            )
    for j in range(objects):
        xy = np.array([0.3 * j, rng.uniform(-1, 1)])
        values.insert(object_key(j), xy)
        for i in rng.choice(poses, 3, replace=False):
            pose = values.atPose2(pose_key(0, int(i)))
            seen = pose.transformTo(xy)
            bearing, distance = gtsam.Rot2(np.arctan2(seen[1], seen[0])), np.hypot(*seen)
            graph.push_back(
                gtsam.BearingRangeFactor2D(
                    pose_key(0, int(i)), object_key(j), bearing, distance, SIGHTING
                )
            )
    return graph, values


def gtsam_marginals(graph, values, keys):
    marginals = gtsam.Marginals(graph, values)
    return np.array([marginals.marginalCovariance(key) for key in keys])


def test_batched_marginals_equal_gtsams():
    graph, values = survey()
    keys = [object_key(j) for j in range(0, 20, 3)]
    covs = np.array(marginal_covariances(graph, values, keys))
    np.testing.assert_allclose(covs, gtsam_marginals(graph, values, keys), rtol=1e-8, atol=1e-14)


def test_objects_tied_together_are_left_to_gtsam():
    graph, values = survey()
    tie = gtsam.noiseModel.Isotropic.Sigma(2, 0.01)
    graph.push_back(gtsam.BetweenFactorPoint2(object_key(1), object_key(2), np.zeros(2), tie))
    keys = [object_key(1), object_key(2), object_key(5)]
    covs = np.array(marginal_covariances(graph, values, keys))
    np.testing.assert_allclose(covs, gtsam_marginals(graph, values, keys), rtol=1e-8, atol=1e-14)


def test_an_indeterminate_object_is_named_by_gtsam():
    graph, values = survey()
    values.insert(object_key(99), np.array([1.0, 1.0]))  # in the graph, constrained in x only
    along_x = gtsam.noiseModel.Diagonal.Precisions([1 / 0.03**2, 0.0])
    graph.push_back(gtsam.PriorFactorPoint2(object_key(99), np.array([1.0, 1.0]), along_x))
    with pytest.raises(RuntimeError, match=r"Indeterminate|near variable"):
        marginal_covariances(graph, values, [object_key(1), object_key(99)])


def test_an_object_outside_the_graph_is_a_runtime_error_naming_it():
    """A fold's deferred job asks for an object that a merge of far-apart objects left out
    of its keyframe's part (as on Victoria Park): the error is one the fold turns into a
    weak covariance and an issue, not a KeyError that ends the run."""
    graph, values = survey()
    values.insert(object_key(99), np.array([1.0, 1.0]))  # a value, but no factor here
    with pytest.raises(RuntimeError, match="l99 are not in the graph") as err:
        marginal_covariances(graph, values, [object_key(1), object_key(99)])
    assert indeterminate_key(err.value) is None  # so `isolating` does not try to isolate it
