"""Continuous beliefs: scalar Kalman update, H_N (sec. 2.1.2), Gaussian fusion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from agrislam.semantics.continuous import entropy_normalised, fuse, kalman_update


def test_kalman_update_by_hand():
    # K = 0.01 / (0.01 + 0.03) = 0.25: mean 0.3 + 0.25 * 0.2 = 0.35, var 0.01 * 0.03 / 0.04
    mean, var = kalman_update(np.array([0.3]), np.array([0.01]), np.array([0.5]), np.array([0.03]))
    np.testing.assert_allclose(mean, [0.35])
    np.testing.assert_allclose(var, [0.0075])


def test_kalman_zero_variances_stay_finite():
    mean, var = kalman_update(
        np.array([0.3, 0.3]), np.array([0.0, 0.01]), np.array([0.5, 0.5]), np.array([0.0, 0.0])
    )
    assert np.all(np.isfinite(mean)) and np.all(var == 0.0)
    np.testing.assert_allclose(mean, [0.3, 0.5])  # certain belief kept; certain meas taken


@given(st.floats(-10, 10), st.floats(0, 10), st.floats(-10, 10), st.floats(0, 10))
def test_kalman_variance_never_negative_nor_above_either(m, v, z, r):
    mean, var = kalman_update(np.array([m]), np.array([v]), np.array([z]), np.array([r]))
    assert np.isfinite(mean[0]) and 0.0 <= var[0] <= min(v, r) + 1e-15


def test_normalised_entropy_of_known_sigmas():
    # sigma / span = 0.1: H_N = 1/2 ln(2 pi e 0.01) = 1/2 ln(0.1707947) = -0.8836466
    assert entropy_normalised(0.06**2, 0.6) == pytest.approx(-0.8836466, abs=1e-7)
    # sigma = span / sqrt(2 pi e) makes the argument 1: H_N = 0
    assert entropy_normalised(0.6**2 / (2 * np.pi * np.e), 0.6) == pytest.approx(0.0, abs=1e-12)
    assert entropy_normalised(0.0, 0.6) == -np.inf


def test_fusion_without_prior_is_the_product_of_gaussians():
    # info 1/0.01 + 1/0.03 = 133.33: var 0.0075, mean (0.2 * 100 + 0.6 * 33.33) / 133.33 = 0.3
    mean, var = fuse(np.array([0.2]), np.array([0.01]), np.array([0.6]), np.array([0.03]))
    np.testing.assert_allclose(var, [0.0075])
    np.testing.assert_allclose(mean, [0.3])


def test_fusion_with_prior_equals_both_measurements_on_one_object():
    prior_mean, prior_var = 0.3, 0.03
    # a: prior + (0.5, 0.01): K = 0.75 -> (0.45, 0.0075); b: prior + (0.2, 0.06): K = 1/3
    a = kalman_update(
        np.array([prior_mean]), np.array([prior_var]), np.array([0.5]), np.array([0.01])
    )
    b = kalman_update(
        np.array([prior_mean]), np.array([prior_var]), np.array([0.2]), np.array([0.06])
    )
    np.testing.assert_allclose(a, [[0.45], [0.0075]])
    np.testing.assert_allclose(b, [[0.3 - 0.1 / 3], [0.02]])
    # info 133.33 + 50 - 33.33 = 150; mean (0.45*133.33 + 0.26667*50 - 0.3*33.33) / 150
    mean, var = fuse(a[0], a[1], b[0], b[1], prior_mean, prior_var)
    np.testing.assert_allclose(var, [1 / 150])
    np.testing.assert_allclose(mean, [63.333333 / 150])
    both = kalman_update(a[0], a[1], np.array([0.2]), np.array([0.06]))
    np.testing.assert_allclose((mean, var), both)


def test_fusion_never_loses_information_when_the_prior_is_outgrown():
    # both beliefs less certain than the prior (process noise grew them): the fused one is
    # at least as certain as the better of the two, never negative
    mean, var = fuse(
        np.array([0.2]), np.array([0.05]), np.array([0.4]), np.array([0.08]), 0.3, 0.01
    )
    assert 0.0 < var[0] <= 0.05 and np.isfinite(mean[0])
