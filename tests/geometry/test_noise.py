"""Noise models of the graph: detection covariance along/across the ray (sec. 2.3, 2.6),
the relative-position <-> bearing-range conversion, row noise acting across rows only."""

import math

import gtsam
import numpy as np
import pytest

from agrislam.backend import detection_covariance
from agrislam.config import SlamConfig
from agrislam.geometry.noise import (
    check_covariance,
    one_direction,
    range_bearing_jacobian,
    range_bearing_to_relative,
    relative_to_range_bearing,
    robust,
    row_direction,
    row_normal,
)


def test_detection_covariance_straight_ahead_and_to_the_left():
    # ahead: depth along x; to the left (bearing 90 deg): depth along y
    ahead = detection_covariance(np.array([2.0, 0.0]), 0.1, 0.03)
    left = detection_covariance(np.array([0.0, 2.0]), 0.1, 0.03)
    np.testing.assert_allclose(ahead, [[0.01, 0.0], [0.0, 0.0009]], atol=1e-15)
    np.testing.assert_allclose(left, [[0.0009, 0.0], [0.0, 0.01]], atol=1e-15)


def test_detection_covariance_at_45_degrees_by_hand():
    # R diag(sd^2, sl^2) R^T at 45 deg: (sd^2 + sl^2)/2 on the diagonal, (sd^2 - sl^2)/2 off it
    cov = detection_covariance(np.array([1.0, 1.0]), 0.2, 0.1)
    np.testing.assert_allclose(cov, [[0.025, 0.015], [0.015, 0.025]], atol=1e-15)
    values, vectors = np.linalg.eigh(cov)
    np.testing.assert_allclose(values, [0.01, 0.04])
    assert abs(abs(vectors[:, 1] @ np.array([1.0, 1.0]) / math.sqrt(2)) - 1.0) < 1e-12


def test_detection_covariance_is_vectorised():
    xy = np.array([[2.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    cov = detection_covariance(xy, np.array([0.1, 0.1, 0.2]), np.array([0.03, 0.03, 0.1]))
    assert cov.shape == (3, 2, 2)
    np.testing.assert_allclose(cov[2], detection_covariance(xy[2], 0.2, 0.1))


def test_range_bearing_round_trip_and_jacobian():
    xy = np.array([1.2, -0.7])
    cov = detection_covariance(xy, 0.15, 0.02)
    bearing, rng, cov_br = relative_to_range_bearing(xy, cov)
    assert bearing == pytest.approx(math.atan2(-0.7, 1.2))
    assert rng == pytest.approx(math.hypot(1.2, -0.7))
    # a ray-aligned covariance is diagonal in (bearing, range): sl / r and sd
    np.testing.assert_allclose(cov_br, np.diag([(0.02 / rng) ** 2, 0.15**2]), atol=1e-15)
    back_xy, back_cov = range_bearing_to_relative(bearing, rng, cov_br)
    np.testing.assert_allclose(back_xy, xy, atol=1e-15)
    np.testing.assert_allclose(back_cov, cov, atol=1e-15)
    # the Jacobian against central differences
    eps = 1e-7
    numeric = np.column_stack(
        [
            (
                np.array(relative_to_range_bearing(xy + d, cov)[:2])
                - np.array(relative_to_range_bearing(xy - d, cov)[:2])
            )
            / (2 * eps)
            for d in (np.array([eps, 0.0]), np.array([0.0, eps]))
        ]
    )
    np.testing.assert_allclose(range_bearing_jacobian(xy), numeric, atol=1e-7)


def test_detection_at_the_robot_origin_is_an_error():
    with pytest.raises(ValueError, match="origin"):
        relative_to_range_bearing(np.zeros(2), np.eye(2))


def test_row_noise_penalises_only_the_cross_row_component():
    angle = math.radians(30)
    noise = one_direction(row_normal(angle), 0.05)
    across = noise.whiten(0.1 * row_normal(angle))
    along = noise.whiten(3.0 * row_direction(angle))
    assert np.linalg.norm(across) == pytest.approx(0.1 / 0.05)
    assert np.linalg.norm(along) == pytest.approx(0.0, abs=1e-12)


def test_robust_kernel_wraps_only_when_configured():
    base = gtsam.noiseModel.Isotropic.Sigma(2, 0.1)
    assert isinstance(robust(SlamConfig(robust_kernel="huber"), base), gtsam.noiseModel.Robust)
    assert robust(SlamConfig(robust_kernel="none"), base) is base


@pytest.mark.parametrize(
    ("cov", "message"),
    [
        (np.eye(3), "must be 2x2"),
        (np.array([[1.0, 0.5], [0.4, 1.0]]), "not symmetric"),
        (np.array([[1.0, 0.0], [0.0, -1.0]]), "not positive definite"),
        (np.array([[np.nan, 0.0], [0.0, 1.0]]), "non-finite"),
    ],
)
def test_bad_covariance_names_what(cov, message):
    with pytest.raises(ValueError, match=f"detection 7: covariance .*{message}|{message}"):
        check_covariance(cov, 2, "detection 7")
