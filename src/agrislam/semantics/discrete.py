"""Discrete attribute beliefs: the Bayes update with the sensor model of Assumption 1,
the normalised KL divergence D_KLN and the fusion of two beliefs.

A belief is a row of an (k, n) array: k objects, n values, each row sums to one.
"""

from __future__ import annotations

import numpy as np


def ignored_measurements(p: np.ndarray, n_values: int) -> np.ndarray:
    """Which measurements carry no evidence: p < 1/n is deemed invalid (sec. 2.3)."""
    return np.asarray(p) < 1.0 / n_values


def likelihood(value_index: np.ndarray, p: np.ndarray, n_values: int) -> np.ndarray:
    """P(y = s_m | x = s_j) for each measurement (k,) over the n values: (k, n)."""
    p = np.asarray(p, dtype=float)
    # eq. (1): the measured value gets p, every other value (1 - p) / (n - 1)
    lik = np.repeat(((1.0 - p) / (n_values - 1))[:, None], n_values, axis=1)
    lik[np.arange(len(p)), value_index] = p
    return lik


def floor_and_normalise(belief: np.ndarray, floor: float) -> np.ndarray:
    """Normalise each row of non-negative weights, lift every probability to at least
    `floor`, and renormalise."""
    belief = np.maximum(belief / belief.sum(axis=-1, keepdims=True), floor)
    return belief / belief.sum(axis=-1, keepdims=True)


def bayes_update(
    belief: np.ndarray, value_index: np.ndarray, p: np.ndarray, floor: float
) -> np.ndarray:
    """Posterior of k beliefs (k, n) after one measurement each (sec. 2.5.1).

    Rows whose measurement has p < 1/n come back unchanged. Edge cases: p is clipped into
    [floor, 1 - floor], so p = 1 does not zero the other values in one step, and the posterior
    is floored at `floor` and renormalised, so a long run of agreeing measurements cannot
    underflow a value to exactly 0; a value at 0 could never come back (0 times any
    likelihood is 0), a floored one recovers after a few contradicting measurements.
    """
    n_values = belief.shape[1]
    p = np.asarray(p, dtype=float)
    used = ~ignored_measurements(p, n_values)
    lik = likelihood(value_index, np.clip(p, floor, 1.0 - floor), n_values)
    # Bayes: posterior = likelihood * prior / evidence, the evidence being the row sum
    posterior = floor_and_normalise(lik * belief, floor)
    return np.where(used[:, None], posterior, belief)


def kl_normalised(belief: np.ndarray) -> np.ndarray:
    """D_KLN per row: 0 for a uniform belief, 1 for a one-hot one (sec. 2.1.1)."""
    n_values = belief.shape[-1]
    # 0 ln 0 = 0: a zero meets ln of the smallest positive double, not ln 0
    log_p = np.log(np.maximum(belief, np.finfo(float).tiny))
    # sec. 2.1.1: D_KLN = 1 + (1 / ln n) sum_s P(s) ln P(s)
    d = 1.0 + np.einsum("...j,...j->...", belief, log_p) / np.log(n_values)
    return np.clip(d, 0.0, 1.0)


def fuse(belief_a: np.ndarray, belief_b: np.ndarray, prior: np.ndarray, floor: float) -> np.ndarray:
    """Belief of one object seen as two: independent evidence on a shared prior.

    Each belief is prior x its own likelihoods, so the product counts the prior twice;
    dividing it out once gives prior x all likelihoods.
    """
    return floor_and_normalise(belief_a * belief_b / np.maximum(prior, floor), floor)
