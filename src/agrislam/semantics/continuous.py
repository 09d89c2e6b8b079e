"""Continuous attribute beliefs: Gaussians (mean, variance) updated by a scalar Kalman
filter, their normalised entropy H_N and the fusion of two of them (sec. 2.1.2, 2.5)."""

from __future__ import annotations

import numpy as np


def kalman_update(
    mean: np.ndarray, var: np.ndarray, value: np.ndarray, meas_var: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and variance after one measurement (value, meas_var) each (sec. 2.5)."""
    total = var + meas_var
    # a zero total means a certain belief met a certain measurement: keep the belief
    gain = np.divide(var, total, out=np.zeros_like(total, dtype=float), where=total > 0.0)
    # P' = P R / (P + R) rather than (1 - K) P: a product of non-negatives, never below zero
    new_var = np.divide(
        var * meas_var, total, out=np.zeros_like(total, dtype=float), where=total > 0.0
    )
    return mean + gain * (value - mean), new_var


def entropy_normalised(var: np.ndarray, span: float) -> np.ndarray:
    """H_N of a Gaussian with variance `var` over an attribute range of width `span`."""
    # sec. 2.1.2: H_N = 1/2 ln(2 pi e (sigma / (s_max - s_min))^2); -inf for var = 0
    with np.errstate(divide="ignore"):
        return 0.5 * np.log(2.0 * np.pi * np.e * np.asarray(var, dtype=float) / span**2)


def fuse(
    mean_a: np.ndarray,
    var_a: np.ndarray,
    mean_b: np.ndarray,
    var_b: np.ndarray,
    prior_mean: float | None = None,
    prior_var: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One Gaussian from two beliefs of the same object, as independent evidence.

    Without a prior this is the plain product of the two Gaussians. With one, the prior
    (which both beliefs started from) is divided out once in information form; the fused
    information is never less than the better of the two, so a prior that time updates
    have outgrown cannot make it negative.
    """
    info_a, info_b = 1.0 / np.asarray(var_a, float), 1.0 / np.asarray(var_b, float)
    info = info_a + info_b
    weighted = mean_a * info_a + mean_b * info_b
    if prior_var is not None:
        prior_info = 1.0 / prior_var
        info = np.maximum(info - prior_info, np.maximum(info_a, info_b))
        weighted = weighted - (prior_mean if prior_mean is not None else 0.0) * (
            info_a + info_b - info
        )
    return weighted / info, 1.0 / info
