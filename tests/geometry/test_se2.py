"""SE(2) point Jacobians (geometry/se2.py) against numeric differentiation: the one
function and each Jacobian its docstring derives from it."""

import gtsam
import numpy as np
import pytest

from agrislam.geometry import se2

POSE = np.array([3.0, -2.0, 0.7])
POINTS = np.array([[1.5, 4.0], [-2.0, 0.3], [0.0, -6.0]])
H = 1e-6


def numeric(f, n_in: int = 3) -> np.ndarray:
    """(m, 2, n_in) central differences of f: (n_in,) -> (m, 2) at 0."""
    cols = []
    for i in range(n_in):
        d = np.zeros(n_in)
        d[i] = H
        cols.append((f(d) - f(-d)) / (2 * H))
    return np.stack(cols, axis=-1)


def moved_by(xi: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2.Expmap(xi)


def test_point_jacobian_is_how_a_point_of_a_perturbed_frame_moves():
    def f(xi):
        return np.array([moved_by(xi).transformFrom(p) for p in POINTS])

    np.testing.assert_allclose(se2.point_jacobian(POINTS), numeric(f), atol=1e-6)


def test_left_perturbation_at_map_points():
    pose = gtsam.Pose2(*POSE)
    mapped = np.array([pose.transformFrom(p) for p in POINTS])

    def f(xi):
        return np.array([moved_by(xi).compose(pose).transformFrom(p) for p in POINTS])

    np.testing.assert_allclose(se2.point_jacobian(mapped), numeric(f), atol=1e-6)


def test_right_perturbation_is_the_rotated_jacobian_at_frame_points():
    """GTSAM's Pose2 tangent (its marginal covariances): T Exp(xi)."""
    pose = gtsam.Pose2(*POSE)

    def f(xi):
        return np.array([pose.compose(moved_by(xi)).transformFrom(p) for p in POINTS])

    expected = se2.rotation(POSE[2]) @ se2.point_jacobian(POINTS)
    np.testing.assert_allclose(expected, numeric(f), atol=1e-6)


def test_pose_uncertainty_is_the_jacobian_of_gtsams_tangent_squared():
    """A Pose2 marginal is in the robot's own frame: not the additive (x, y, theta)."""
    pose = gtsam.Pose2(*POSE)

    def f(xi):
        return np.array([pose.compose(moved_by(xi)).transformFrom(p) for p in POINTS])

    jac = numeric(f)
    cov = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, -0.003], [0.002, -0.003, 0.01]])
    expected = jac @ cov @ jac.transpose(0, 2, 1)
    got = se2.pose_uncertainty_at(POSE, cov, POINTS)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-9)
    # the additive Jacobian differs from it: the test tells them apart
    additive = se2.point_jacobian((se2.rotation(POSE[2]) @ POINTS.T).T)
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(additive @ cov @ additive.transpose(0, 2, 1), got, rtol=1e-3)


def test_pair_motions_find_the_motion_that_moved_a_pair():
    new = np.array([[0.0, 0.0], [3.0, 1.0], [-2.0, 4.0]])
    motion = np.array([5.0, -2.0, 0.4])
    old = np.r_[se2.turned(new, motion[2]) + motion[:2], [[40.0, 40.0]]]
    found = se2.pair_motions(new, old, 1e-6)
    # each pair of new on its own pair of old, in either order (the other turned by pi)
    assert len(found) == 6
    right = np.all(np.isclose(found, motion, atol=1e-9), axis=1)
    assert right.sum() == 3
    np.testing.assert_allclose(np.abs(se2.wrap_angle(found[~right, 2] - motion[2])), np.pi)
    np.testing.assert_allclose(se2.turned(new[1:2], np.pi / 2), [[-1.0, 3.0]], atol=1e-12)
