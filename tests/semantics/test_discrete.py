"""Discrete beliefs: eq. (1) likelihood, Bayes update, D_KLN (sec. 2.1.1), fusion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from agrislam.semantics.discrete import (
    bayes_update,
    fuse,
    ignored_measurements,
    kl_normalised,
    likelihood,
)

FLOOR = 1e-9


def test_likelihood_gives_p_to_the_measured_value_and_splits_the_rest():
    # eq. (1), n = 4: measured value p = 0.7, the three others (1 - 0.7) / 3 = 0.1 each
    lik = likelihood(np.array([2]), np.array([0.7]), 4)
    np.testing.assert_allclose(lik, [[0.1, 0.1, 0.7, 0.1]])


def test_inconsistent_type_measurements_of_a_weed():
    """The paper's example (sec. 3.2.2): a weed, measured once wrongly as crop, twice as weed.

    values (crop, weed), start uniform (0.5, 0.5):
      crop, p = 0.7: (0.5*0.7, 0.5*0.3) / 0.5          = (0.7, 0.3)
      weed, p = 0.8: (0.7*0.2, 0.3*0.8) / 0.38         = (7/19, 12/19) = (0.3684, 0.6316)
      weed, p = 0.6: (7/19*0.4, 12/19*0.6) / (10/19)   = (0.28, 0.72)
    so the belief ends on weed with some uncertainty left: D_KLN = 0.1445.
    """
    belief = np.array([[0.5, 0.5]])
    crop, weed = 0, 1
    belief = bayes_update(belief, np.array([crop]), np.array([0.7]), FLOOR)
    np.testing.assert_allclose(belief, [[0.7, 0.3]])
    belief = bayes_update(belief, np.array([weed]), np.array([0.8]), FLOOR)
    np.testing.assert_allclose(belief, [[7 / 19, 12 / 19]])
    belief = bayes_update(belief, np.array([weed]), np.array([0.6]), FLOOR)
    np.testing.assert_allclose(belief, [[0.28, 0.72]])
    # D_KLN = 1 + (0.28 ln 0.28 + 0.72 ln 0.72) / ln 2 = 1 - 0.592953 / 0.693147
    np.testing.assert_allclose(kl_normalised(belief), [0.1445492], atol=1e-7)


def test_three_valued_update_by_hand():
    # prior (0.2, 0.3, 0.5), measured value 1 with p = 0.6: others get 0.4 / 2 = 0.2
    # (0.2*0.2, 0.3*0.6, 0.5*0.2) = (0.04, 0.18, 0.10) / 0.32
    belief = bayes_update(np.array([[0.2, 0.3, 0.5]]), np.array([1]), np.array([0.6]), FLOOR)
    np.testing.assert_allclose(belief, [[0.125, 0.5625, 0.3125]])


def test_measurement_below_one_over_n_is_ignored_and_exactly_one_over_n_changes_nothing():
    prior = np.array([[0.2, 0.3, 0.5], [0.2, 0.3, 0.5]])
    assert ignored_measurements(np.array([0.3, 1 / 3, 0.34]), 3).tolist() == [True, False, False]
    post = bayes_update(prior, np.array([0, 0]), np.array([0.3, 1 / 3]), FLOOR)
    np.testing.assert_array_equal(post[0], prior[0])  # ignored: returned untouched
    np.testing.assert_allclose(post[1], prior[1])  # p = 1/n: a flat likelihood


def test_p_one_does_not_kill_the_other_values_forever():
    # p = 1 is clipped to 1 - 1e-9 and the posterior floored at 1e-9: weed keeps ~1e-9,
    # and each weed measurement at p = 0.9 multiplies the odds by 9, so after 10 of them
    # (9^10 = 3.5e9 > 1e9) weed is the more probable value, after 9 (3.9e8) not yet.
    belief = bayes_update(np.array([[0.5, 0.5]]), np.array([0]), np.array([1.0]), FLOOR)
    assert np.all(np.isfinite(belief)) and belief[0, 1] > 0.0
    np.testing.assert_allclose(belief[0, 1], 1e-9, rtol=1e-3)
    for k in range(1, 11):
        belief = bayes_update(belief, np.array([1]), np.array([0.9]), FLOOR)
        assert (belief[0, 1] > 0.5) == (k >= 10), k


def test_p_zero_is_ignored_and_never_nan():
    belief = bayes_update(np.array([[0.5, 0.5]]), np.array([0]), np.array([0.0]), FLOOR)
    np.testing.assert_array_equal(belief, [[0.5, 0.5]])


def test_long_agreeing_run_does_not_underflow_to_zero():
    belief = np.array([[0.5, 0.5]])
    for _ in range(2000):  # 0.1^2000 would underflow to exactly 0 without the floor
        belief = bayes_update(belief, np.array([0]), np.array([0.9]), FLOOR)
    assert belief[0, 1] >= FLOOR / (1 + FLOOR) and np.isclose(belief.sum(), 1.0)


def test_kl_normalised_uniform_is_zero_one_hot_is_one():
    for n in (2, 3, 7):
        assert kl_normalised(np.full(n, 1.0 / n)) == pytest.approx(0.0, abs=1e-12)
        one_hot = np.zeros(n)
        one_hot[n - 1] = 1.0
        assert kl_normalised(one_hot) == pytest.approx(1.0)
    # (0.5, 0.5, 0): 1 + 2 * 0.5 ln 0.5 / ln 3 = 1 - ln 2 / ln 3
    assert kl_normalised(np.array([0.5, 0.5, 0.0])) == pytest.approx(1 - np.log(2) / np.log(3))


def test_fusion_equals_both_measurements_on_one_object():
    prior = np.array([0.2, 0.8])
    # a: prior after "crop, p = 0.7" = (0.14, 0.24) / 0.38 = (7/19, 12/19)
    a = bayes_update(prior[None, :], np.array([0]), np.array([0.7]), FLOOR)
    # b: prior after "crop, p = 0.8" = (0.16, 0.16) / 0.32 = (0.5, 0.5)
    b = bayes_update(prior[None, :], np.array([0]), np.array([0.8]), FLOOR)
    np.testing.assert_allclose(b, [[0.5, 0.5]])
    # a b / prior = (7/19 * 0.5 / 0.2, 12/19 * 0.5 / 0.8) -> (0.7, 0.3); both on one object:
    # prior * 0.7 * 0.8 vs 0.8 * 0.3 * 0.2 = (0.112, 0.048) -> (0.7, 0.3)
    np.testing.assert_allclose(fuse(a, b, prior, FLOOR), [[0.7, 0.3]])
    both = bayes_update(a, np.array([0]), np.array([0.8]), FLOOR)
    np.testing.assert_allclose(fuse(a, b, prior, FLOOR), both)


def _distributions(n: int):
    return (
        arrays(float, (5, n), elements=st.floats(0.0, 1.0))
        .filter(lambda a: np.all(a.sum(axis=1) > 1e-3))
        .map(lambda a: a / a.sum(axis=1, keepdims=True))
    )


@given(
    st.integers(2, 8).flatmap(
        lambda n: st.tuples(
            _distributions(n),
            arrays(np.int64, 5, elements=st.integers(0, n - 1)),
            arrays(float, 5, elements=st.floats(0.0, 1.0)),
        )
    )
)
def test_update_keeps_distributions_normalised_and_kl_in_unit_interval(case):
    belief, value, p = case
    post = bayes_update(belief, value, p, FLOOR)
    assert np.all(np.isfinite(post)) and np.all(post >= 0.0)
    np.testing.assert_allclose(post.sum(axis=1), 1.0)
    d = kl_normalised(post)
    assert np.all((d >= 0.0) & (d <= 1.0))
