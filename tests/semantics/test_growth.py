"""The growth time model of App. B: A(dt) by hand, its properties, and convergence of the
discretised chain to the continuous solution (the App. B figure)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agrislam.config import SECONDS_PER_DAY, GrowthModel
from agrislam.semantics.growth import (
    TransitionCache,
    grown_mean,
    grown_variance,
    propagate,
    transition_matrices,
    transition_matrix,
)


def _model(rate: float = 0.04, l_max: float = 0.6, **kw: float) -> GrowthModel:
    return GrowthModel(rate_per_day=rate, l_max=l_max, **kw)


def test_transition_matrix_n3_by_hand():
    """n = 3, e^{alpha dt} = 1.5: p_ij = 3 - (3 - i) 1.5 - (j - 1).

    p (rows i, columns j) = [[0, -1, -2], [1.5, 0.5, -0.5], [3, 2, 1]]
    clipped cumulative    = [[0,  0,  0], [1,   0.5, 0  ], [1, 1, 1]]
    a_ij = row differences = [[0, 0, 0], [1, 0.5, 0], [0, 0.5, 1]]
    Check against the ODE with l_max = 3 (unit cells): f(x) = 3 - (3 - x) / 1.5 maps cell 1
    [0, 1] to [1, 1.67] (all in cell 2), cell 2 to [1.67, 2.33] (half in 2, half in 3), cell 3
    to [2.33, 3].
    """
    rate = 0.04
    dt_s = math.log(1.5) / rate * SECONDS_PER_DAY
    A = transition_matrix(3, _model(rate, 3.0), dt_s)
    np.testing.assert_allclose(A, [[0, 0, 0], [1, 0.5, 0], [0, 0.5, 1]], atol=1e-12)
    # l_max only scales the cells: the same matrix for any l_max
    np.testing.assert_allclose(transition_matrix(3, _model(rate, 0.6), dt_s), A, atol=1e-12)


def test_transition_matrix_with_process_noise_by_hand():
    # w = 0.5 per day over 2 days leaks 1 - 0.5^2 = 0.75 uniformly: A = 0.25 A0 + 0.75 / 3,
    # with e^{2 alpha} = 1.5 so A0 is the matrix above
    rate = math.log(1.5) / 2
    A = transition_matrix(3, _model(rate, 3.0, process_noise=0.5), 2 * SECONDS_PER_DAY)
    np.testing.assert_allclose(
        A, [[0.25, 0.25, 0.25], [0.5, 0.375, 0.25], [0.25, 0.375, 0.5]], atol=1e-12
    )


def test_very_long_dt_sends_everything_to_the_last_cell():
    # e^{alpha dt} would overflow (alpha dt = 2000): every cell ends in the last one
    A = transition_matrix(4, _model(2.0, 0.6), 1000 * SECONDS_PER_DAY)
    expected = np.zeros((4, 4))
    expected[3] = 1.0
    np.testing.assert_array_equal(A, expected)


def test_two_cell_full_shift_by_hand():
    # n = 2, e^{alpha dt} = 2: f(x) = (1 + x) / 2 sends cell 1 [0, .5] to [.5, .75], cell 2
    # to [.75, 1]: everything ends in cell 2
    A = transition_matrix(2, _model(math.log(2), 1.0), SECONDS_PER_DAY)
    np.testing.assert_allclose(A, [[0, 0], [1, 1]], atol=1e-12)


@settings(max_examples=60)
@given(
    n=st.integers(2, 40),
    rate=st.floats(1e-3, 2.0),
    days=st.floats(0.0, 400.0),
    noise=st.floats(0.0, 1.0),
)
def test_columns_sum_to_one_and_zero_dt_is_identity(n, rate, days, noise):
    model = _model(rate, 0.6, process_noise=noise)
    A = transition_matrix(n, model, days * SECONDS_PER_DAY)
    assert np.all(A >= 0.0)
    np.testing.assert_allclose(A.sum(axis=0), 1.0, atol=1e-12)
    np.testing.assert_array_equal(transition_matrix(n, model, 0.0), np.eye(n))


def _chain_error(n: int, model: GrowthModel, days: float, steps: int, start: float) -> float:
    """Largest gap between the weighted mean of the n-cell chain, started on the cell
    holding `start` (a fraction of l_max), and the ODE solution from that cell's centre."""
    A = transition_matrix(n, model, days * SECONDS_PER_DAY)
    centres = (np.arange(n) + 0.5) * model.l_max / n
    cell = min(int(start * n), n - 1)
    xi = np.zeros(n)
    xi[cell] = 1.0
    x, err = centres[cell], 0.0
    for _ in range(steps):
        xi = A @ xi
        x = grown_mean(x, model, days * SECONDS_PER_DAY)
        err = max(err, abs(centres @ xi - x))
    return err


@settings(max_examples=40, deadline=None)
@given(
    rate=st.floats(0.005, 0.5),
    days=st.floats(0.05, 10.0),
    steps=st.integers(1, 150),
    start=st.floats(0.0, 0.999),
    n=st.sampled_from([2, 4, 16, 64]),
)
def test_weighted_mean_stays_within_half_a_cell_of_the_continuous_solution(
    rate, days, steps, start, n
):
    """App. B: the chain's weighted mean tracks f(x, t) within half a cell, l_max / (2 n),
    so it approaches the continuous solution as n grows."""
    model = _model(rate, 2.0)
    assert _chain_error(n, model, days, steps, start) <= 2.0 / (2 * n) + 1e-9


def test_app_b_figure_error_shrinks_with_n():
    # the figure's setting: dt = 1 day, alpha = 0.04; 100 days from a seedling
    model = _model(0.04, 0.6)
    errors = [_chain_error(n, model, 1.0, 100, 0.05) for n in (3, 5, 10, 20, 40, 80, 160)]
    assert all(b < a for a, b in itertools.pairwise(errors))
    assert errors[-1] < 0.6 / 320 + 1e-12 and errors[0] > 0.05


def test_continuous_propagation_by_hand():
    model = _model(0.04, 0.6, variance_per_day=1e-4)
    dt = 10 * SECONDS_PER_DAY
    # 0.6 - 0.5 e^{-0.4} = 0.6 - 0.5 * 0.670320
    assert grown_mean(0.1, model, dt) == pytest.approx(0.26483998, abs=1e-8)
    # 0.01 e^{-0.8} + 1e-4 (1 - e^{-0.8}) / 0.08 = 0.00449329 + 0.00068834
    assert grown_variance(0.01, model, dt) == pytest.approx(0.00518163, abs=1e-8)
    assert grown_mean(0.1, model, 0.0) == 0.1 and grown_variance(0.01, model, 0.0) == 0.01
    # never backwards in time
    assert grown_mean(0.1, model, -dt) == 0.1


def test_continuous_propagation_composes():
    # two steps equal one: when a lazy belief is brought forward does not matter
    model = _model(0.07, 0.6, variance_per_day=3e-4)
    a, b = 3.3 * SECONDS_PER_DAY, 11.9 * SECONDS_PER_DAY
    assert grown_mean(grown_mean(0.2, model, a), model, b) == pytest.approx(
        grown_mean(0.2, model, a + b)
    )
    assert grown_variance(grown_variance(0.004, model, a), model, b) == pytest.approx(
        grown_variance(0.004, model, a + b)
    )


def test_transition_cache_matches_direct_computation():
    model = _model(0.1, 0.6, process_noise=0.01)
    cache = TransitionCache(3, model, max_entries=8)
    rng = np.random.default_rng(3)
    for _ in range(20):  # small draws hit and refill the cache, big ones bypass it
        dts = rng.choice([0.0, 3600.0, 86400.0, 5e5], rng.integers(1, 12))
        if rng.random() < 0.3:
            dts = np.concatenate([dts, rng.uniform(0, 1e6, 10)])
        np.testing.assert_allclose(cache(dts), transition_matrices(3, model, dts))
    # propagation keeps the distribution normalised
    xi = propagate(np.array([[0.7, 0.2, 0.1]]), cache(np.array([86400.0 * 30])))
    assert xi.sum() == pytest.approx(1.0) and xi[0, 2] > 0.1


def test_transition_cache_of_no_objects_is_empty():
    """A belief read that finds no objects gets no transitions (a growth model on a discrete
    attribute once stopped every run with 'need at least one array to stack' there)."""
    cache = TransitionCache(3, GrowthModel(l_max=0.6), max_entries=8)
    assert cache(np.empty(0)).shape == (0, 3, 3)


def test_a_survey_with_growth_on_a_discrete_attribute_runs():
    from agrislam.config import AgrislamConfig, FieldSchema
    from agrislam.records import Detection, Detections, DiscreteMeasurement, Meta, Odometry
    from agrislam.world import WorldModel

    schema = FieldSchema.model_validate(
        {
            "attributes": {
                "size": {
                    "kind": "discrete",
                    "values": ["small", "medium", "big"],
                    "time_model": {"kind": "growth", "l_max": 0.6},
                }
            }
        }
    )
    world = WorldModel(AgrislamConfig())
    world.process(Meta(schema=schema))
    det = Detection(xy=np.array([1.0, 0.2]), attributes={"size": DiscreteMeasurement("big", 0.8)})
    for k, t in enumerate((0.0, 0.5, 86_400.0)):  # with and without a time gap
        world.process(Odometry(t, "r1", delta=np.array([0.1 * (k > 0), 0.0, 0.0])))
        world.process(Detections(t, "r1", (det,)))
        world.process(Detections(t, "r1", ()))  # a frame that saw nothing: no beliefs to read
    world.finish()
    snap = world.snapshot()
    assert len(snap.objects) >= 1 and snap.objects.discrete["size"].shape[1] == 3
