"""Association matrix terms (sec. 2.4) against hand-computed numbers, GNN, gating."""

import numpy as np
import pytest

from agrislam.association.gnn import (
    assign,
    association_matrix,
    distance_term,
    innovation_covariance,
    max_association_distance,
    rivals_on_one_metric,
    semantic_term,
)
from agrislam.config import AssociationConfig, FieldSchema, SemanticsConfig
from agrislam.geometry.placed import PlacedDetections
from agrislam.records import ContinuousMeasurement, DiscreteMeasurement
from agrislam.semantics.beliefs import BeliefTable
from agrislam.semantics.measurements import informative_measurements


@pytest.fixture
def table() -> BeliefTable:
    return BeliefTable(FieldSchema.preset("colour_length"), SemanticsConfig())


def test_distance_term_takes_the_smaller_of_euclidean_and_mahalanobis():
    det = np.array([[0.0, 0.0]])
    obj = np.array([[0.3, 0.4]])  # |e| = 0.5
    loose = np.array([[[1.0, 0.0], [0.0, 1.0]]])  # e^T K^-1 e = 0.25
    tight = np.array([[[0.01, 0.0], [0.0, 0.01]]])  # e^T K^-1 e = 25
    assert distance_term(det, obj, loose, d_inter=0.5)[0, 0] == pytest.approx(0.25)
    assert distance_term(det, obj, tight, d_inter=0.5)[0, 0] == pytest.approx(1.0)


def test_mahalanobis_uses_the_full_covariance():
    # K = [[2, 1], [1, 2]], K^-1 = [[2, -1], [-1, 2]] / 3; e = (1, 0) -> 2/3
    k = np.array([[[2.0, 1.0], [1.0, 2.0]]])
    got = distance_term(np.zeros((1, 2)), np.array([[1.0, 0.0]]), k, d_inter=0.1)
    assert got[0, 0] == pytest.approx(2.0 / 3.0)


def test_discrete_semantic_term_uniform_then_updated(table):
    ids = table.add(1, 0.0)
    red = {"colour": DiscreteMeasurement("red", 0.9)}
    # uniform over 7 colours: SSS = 1/7 * 0.9, term = 1 - 0.3 * SSS
    got = semantic_term(table, ids, [red], w_sem=0.3, t=0.0)
    assert got[0, 0] == pytest.approx(1 - 0.3 * 0.9 / 7)
    table.update(ids, [red], 0.0)  # posterior P(red) = 0.9 (eq. 1 with a uniform prior)
    got = semantic_term(table, ids, [red], w_sem=0.3, t=0.0)
    assert got[0, 0] == pytest.approx(1 - 0.3 * 0.9 * 0.9)


def test_continuous_semantic_term_is_tanh_of_gaussian_overlap(table):
    ids = table.add(1, 0.0)
    mean, var = table.gaussian("length", ids, 0.0)
    m = {"length": ContinuousMeasurement(float(mean[0]), 0.01)}
    s2 = var[0] + 0.01
    expected = 1 - 0.3 * np.tanh(1 / np.sqrt(2 * np.pi * s2))
    assert semantic_term(table, ids, [m], 0.3, 0.0)[0, 0] == pytest.approx(expected)
    # hand number: s2 = 0.02 -> density 2.8209, tanh 0.99289, term 0.70213
    assert 1 - 0.3 * np.tanh(1 / np.sqrt(2 * np.pi * 0.02)) == pytest.approx(0.70213, abs=1e-5)


def test_semantic_term_is_one_for_unmeasured_attributes(table):
    ids = table.add(2, 0.0)
    assert np.all(semantic_term(table, ids, [{}], 0.3, 0.0) == 1.0)


def test_measurements_below_one_over_n_take_no_part():
    schema = FieldSchema.preset("colour_size")
    got = informative_measurements(
        schema,
        {"colour": DiscreteMeasurement("red", 0.1), "size": DiscreteMeasurement("big", 0.5)},
    )
    assert list(got) == ["size"]  # 0.1 < 1/7 is ignored, 0.5 >= 1/3 kept


def test_gnn_picks_the_cheapest_joint_assignment_and_forbids_entries_above_one():
    matrix = np.array([[0.2, 0.9], [0.1, 1.5]])
    # 0->0 would force 1->1 (1.5, forbidden): the joint optimum is 0->1, 1->0
    assert assign(matrix).tolist() == [1, 0]
    assert assign(np.array([[1.2]])).tolist() == [-1]  # must start a new object
    assert assign(np.empty((2, 0))).tolist() == [-1, -1]


def test_a_far_detection_starts_a_new_object(table):
    ids = table.add(1, 0.0)
    placed = PlacedDetections(np.array([[0.0, 0.0], [5.0, 0.0]]), np.zeros((2, 2, 2)), [{}, {}])
    cov = np.array([[[0.01, 0.0], [0.0, 0.01]]])
    matrix = association_matrix(
        placed, ids, np.array([[0.05, 0.0]]), cov, table, AssociationConfig(), 0.2, 0.0
    )
    assert assign(matrix).tolist() == [0, -1]


def test_semantics_can_tip_the_assignment(table):
    """Two objects equally far; the one whose colour agrees wins."""
    ids = table.add(2, 0.0)
    table.update(
        ids,
        [
            {"colour": DiscreteMeasurement("red", 0.95)},
            {"colour": DiscreteMeasurement("blue", 0.95)},
        ],
        0.0,
    )
    placed = PlacedDetections(
        np.array([[0.0, 0.0]]), np.zeros((1, 2, 2)), [{"colour": DiscreteMeasurement("blue", 0.9)}]
    )
    xy = np.array([[0.2, 0.0], [-0.2, 0.0]])
    cov = np.tile(np.eye(2) * 0.01, (2, 1, 1))
    matrix = association_matrix(placed, ids, xy, cov, table, AssociationConfig(), 0.2, 0.0)
    assert matrix[0, 1] < matrix[0, 0]
    assert assign(matrix).tolist() == [1]


def test_max_association_distance_is_where_the_best_entry_reaches_one():
    # d_inter 0.4, |Y| = 2, w 0.3: 0.4 / 0.7 = 0.5714
    r = max_association_distance(0.4, 0.1, 0.3, 2)
    assert r == pytest.approx(0.4 / 0.7)
    # at that distance, a perfect semantic match gives exactly a = 1
    assert (1 - 0.3) ** 2 * (r / 0.4) ** 2 == pytest.approx(1.0)
    assert max_association_distance(0.4, 0.8, 0.3, 0) == pytest.approx(0.8)


def test_per_pair_covariance_and_a_wider_gate():
    """K_n + R_m per pair and gate_chi2: e = (1, 0), S = 2 I -> e^T S^-1 e = 0.5, / 4."""
    k = np.array([[[1.0, 0.0], [0.0, 1.0]]])
    per_pair = k[None] + np.eye(2)[None, None]  # (1, 1, 2, 2)
    got = distance_term(np.zeros((1, 2)), np.array([[1.0, 0.0]]), per_pair, 0.1, gate_chi2=4.0)
    assert got[0, 0] == pytest.approx(0.125)


def test_pose_uncertainty_grows_with_distance_through_the_heading():
    from agrislam.geometry.se2 import pose_uncertainty_at

    pose_cov = np.diag([0.01, 0.04, 0.001])
    cov = pose_uncertainty_at(np.zeros(3), pose_cov, np.array([[2.0, 0.0]]))[0]
    # a point 2 m ahead: x takes the pose's x variance, y its y variance + (2 m)^2 var(theta)
    np.testing.assert_allclose(cov, [[0.01, 0.0], [0.0, 0.04 + 4 * 0.001]])


def test_a_detections_rivals_are_compared_on_one_metric():
    """Objects A and B 0.16 m apart, B's covariance wider, C far off. A detection of A,
    0.15 m off on A's far side (a robot's pose error), is nearer B in each object's own
    metric; on the rivals' one metric it is A's. C keeps its own."""
    placed = PlacedDetections(np.array([[-0.15, 0.0]]), (0.05**2 * np.eye(2))[None], [{}])
    object_xy = np.array([[0.0, 0.0], [0.16, 0.0], [5.0, 0.0]])
    object_cov = np.stack([0.1**2 * np.eye(2), 0.25**2 * np.eye(2), 0.3**2 * np.eye(2)])
    own = innovation_covariance(placed, object_cov)
    one = rivals_on_one_metric(own, placed.xy, object_xy, d_inter=0.15)
    np.testing.assert_allclose(one[0, 0], (own[0, 0] + own[0, 1]) / 2)
    np.testing.assert_allclose(one[0, 1], one[0, 0])
    np.testing.assert_array_equal(one[0, 2], own[0, 2])  # beyond 3 d_inter
    for covariance, chosen in ((own, 1), (one, 0)):
        matrix = distance_term(placed.xy, object_xy, covariance, d_inter=0.01, gate_chi2=9.21)
        assert assign(matrix)[0] == chosen


def test_innovation_covariance_takes_the_tighter_of_absolute_and_relative():
    r = np.diag([0.4, 0.4])
    placed = PlacedDetections(
        np.zeros((1, 2)), r[None], [{}], np.zeros((1, 2)), r[None], np.diag([9.0, 9.0])[None]
    )
    object_cov = np.stack([np.diag([16.0, 16.0]), np.diag([0.1, 0.1])])
    drift = np.stack([np.diag([0.5, 0.5]), np.diag([0.5, 0.5])])[None]  # (1, 2, 2, 2)
    got = innovation_covariance(placed, object_cov, drift, np.array([True, True]))
    # object 0 was seen lately: R + R + drift = 1.3 beats K + R + pose = 25.4
    assert got[0, 0] == pytest.approx(np.diag([1.3, 1.3]))
    # object 1 is known well in the map, but its chain is tighter still (1.3 < 9.5)
    assert got[0, 1] == pytest.approx(np.diag([1.3, 1.3]))
    # without a chain from the robot (another robot saw it last), only the absolute bound
    got = innovation_covariance(placed, object_cov, drift, np.array([True, False]))
    assert got[0, 1] == pytest.approx(np.diag([9.5, 9.5]))
    # a long drift since: the absolute bound is the tighter one
    far = np.stack([np.diag([50.0, 50.0]), np.diag([50.0, 50.0])])[None]
    got = innovation_covariance(placed, object_cov, far, np.array([True, True]))
    assert got[0, 0] == pytest.approx(np.diag([25.4, 25.4]))
    assert got[0, 1] == pytest.approx(np.diag([9.5, 9.5]))
    # no pose marginal, no chain: K_n + R_m
    bare = PlacedDetections(np.zeros((1, 2)), r[None], [{}])
    assert innovation_covariance(bare, object_cov)[0, 1] == pytest.approx(np.diag([0.5, 0.5]))
