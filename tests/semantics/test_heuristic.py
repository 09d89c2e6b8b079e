"""Interest heuristic h (eq. 2, sec. 2.7) and the field interest surface."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from agrislam.config import SemanticsConfig
from agrislam.semantics import heuristic
from agrislam.semantics.heuristic import interest, interest_surface, sigmoid

CONFIG = SemanticsConfig()


def test_sigmoid_of_sec_2_7():
    # l(beta) = 1/2; l(0) = 1 / (1 + e^{2 * 0.2}) = 1 / (1 + 1.4918247) = 0.4013123
    assert sigmoid(0.2, 2.0, 0.2) == pytest.approx(0.5)
    assert sigmoid(0.0, 2.0, 0.2) == pytest.approx(0.4013123, abs=1e-7)
    assert sigmoid(-np.inf, 2.0, 0.2) == 0.0


def test_never_measured_object_is_fully_interesting():
    # n_meas = 0 makes the count factor 0: h = 1 whatever the beliefs
    certain = np.array([[1.0, 0.0]])
    assert interest(np.array([0]), [certain], [np.array([-5.0])], CONFIG) == pytest.approx(1.0)


def test_certain_object_measured_three_times():
    # D_KLN = 1 and l(H_N -> -inf) = 0: probability term 1, h = 1 - 3/4 = 0.25
    one_hot = np.array([[0.0, 1.0, 0.0]])
    h = interest(np.array([3]), [one_hot, one_hot[:, :2]], [np.array([-np.inf])], CONFIG)
    assert h == pytest.approx(0.25)


def test_uniform_beliefs_keep_h_at_one():
    h = interest(np.array([7]), [np.full((1, 4), 0.25)], [], CONFIG)
    assert h == pytest.approx(1.0)


def test_mixed_case_by_hand():
    # discrete (0.28, 0.72): D_KLN = 0.1445492; continuous H_N = 0: 1 - l(0) = 0.5986877;
    # n = 1: h = 1 - 1/2 * (0.1445492 + 0.5986877) / 2 = 0.8141908
    h = interest(np.array([1]), [np.array([[0.28, 0.72]])], [np.array([0.0])], CONFIG)
    assert h == pytest.approx(0.8141908, abs=1e-7)


def test_no_attributes_probability_term_is_one():
    # h = 1 - n / (n + 1)
    h = interest(np.array([0, 1, 3]), [], [], CONFIG)
    np.testing.assert_allclose(h, [1.0, 0.5, 0.25])


def test_sigmoid_parameters_come_from_the_config():
    steep = SemanticsConfig(heuristic_alpha=10.0, heuristic_beta=0.0)
    # 1 - l(0) = 1/2 whatever alpha when beta = 0: h = 1 - 1/2 * 1/2
    assert interest(np.array([1]), [], [np.array([0.0])], steep) == pytest.approx(0.75)


@given(
    st.integers(1, 6).flatmap(
        lambda k: st.tuples(
            arrays(np.int64, k, elements=st.integers(0, 10**6)),
            arrays(float, (k, 3), elements=st.floats(0.0, 1.0)).filter(
                lambda a: np.all(a.sum(axis=1) > 1e-6)
            ),
            arrays(float, k, elements=st.floats(-1e6, 1e6) | st.just(-np.inf)),
        )
    )
)
def test_h_stays_in_unit_interval(case):
    n_meas, weights, h_n = case
    belief = weights / weights.sum(axis=1, keepdims=True)
    h = interest(n_meas, [belief], [h_n], CONFIG)
    assert np.all((h >= 0.0) & (h <= 1.0))


# ------------------------------------------------------------------------ surface


def _cell_value(surface, x: float, y: float) -> float:
    j = int((x - surface.x0) / surface.resolution)
    i = int((y - surface.y0) / surface.resolution)
    return float(surface.values[i, j])


def test_surface_reads_h_on_a_lone_object_and_one_far_away():
    cfg = SemanticsConfig(surface_resolution=0.1, surface_sigma=0.25)
    xy = np.array([[0.55, 0.55]])  # on a cell centre of the grid below
    s = interest_surface(xy, np.array([0.2]), cfg, bounds=(0.0, 3.0, 0.0, 2.0))
    assert s.values.shape == (20, 30) and s.extent == pytest.approx((0.0, 3.0, 0.0, 2.0))
    assert _cell_value(s, 0.55, 0.55) == pytest.approx(0.2, abs=1e-6)
    # one cell over (0.1 m): w = exp(-0.01 / 0.125) = 0.9231163: 1 - 0.9231163 * 0.8
    assert _cell_value(s, 0.65, 0.55) == pytest.approx(1 - 0.9231163 * 0.8, abs=1e-6)
    assert _cell_value(s, 2.5, 1.5) == 1.0  # beyond 3 sigma
    assert np.all((s.values >= 0.0) & (s.values <= 1.0))


def test_surface_between_two_objects_by_hand():
    cfg = SemanticsConfig(surface_resolution=0.1, surface_sigma=0.25)
    xy = np.array([[0.55, 0.55], [1.15, 0.55]])
    h = np.array([0.2, 0.6])
    s = interest_surface(xy, h, cfg, bounds=(0.0, 2.0, 0.0, 1.0))
    # midpoint 0.3 m from both: w = exp(-0.09 / 0.125) = 0.4867523 each, sum < 1:
    # v = 1 - 0.4867523 * (0.8 + 0.4) = 0.4159 (the two objects' knowledge adds up)
    assert _cell_value(s, 0.85, 0.55) == pytest.approx(1 - 0.4867523 * 1.2, abs=1e-6)
    # on object 1: own w = 1, the other's w = exp(-0.36 / 0.125) = 0.0561348; sum > 1, so
    # the w-weighted mean of h: (0.2 + 0.0561348 * 0.6) / 1.0561348
    assert _cell_value(s, 0.55, 0.55) == pytest.approx(
        (0.2 + 0.0561348 * 0.6) / 1.0561348, abs=1e-6
    )


def test_surface_crowded_objects_read_their_mean_h():
    xy = np.array([[0.55, 0.55]] * 4)
    h = np.array([0.1, 0.3, 0.5, 0.9])
    s = interest_surface(xy, h, CONFIG, bounds=(0.0, 2.0, 0.0, 2.0))
    assert _cell_value(s, 0.55, 0.55) == pytest.approx(0.45, abs=1e-6)


def test_surface_grid_covers_the_objects_and_ignores_those_off_bounds():
    rng = np.random.default_rng(0)
    xy = rng.uniform([-3.0, 10.0], [4.0, 12.0], (200, 2))
    s = interest_surface(xy, rng.uniform(0, 1, 200), CONFIG)
    xmin, xmax, ymin, ymax = s.extent
    margin = 3 * CONFIG.surface_sigma
    assert xmin <= xy[:, 0].min() - margin + 1e-9 and xmax >= xy[:, 0].max() + margin - 1e-9
    assert ymin <= xy[:, 1].min() - margin + 1e-9 and ymax >= xy[:, 1].max() + margin - 1e-9
    # an object far outside the given bounds changes nothing inside them
    bounds = (0.0, 1.0, 10.0, 11.0)
    inside = interest_surface(xy[:1] * 0 + [0.5, 10.5], np.array([0.0]), CONFIG, bounds)
    both = interest_surface(
        np.array([[0.5, 10.5], [50.0, 50.0]]), np.array([0.0, 0.0]), CONFIG, bounds
    )
    np.testing.assert_array_equal(inside.values, both.values)


def test_surface_coarsens_instead_of_exceeding_max_cells():
    xy = np.array([[0.0, 0.0], [100.0, 100.0]])
    s = interest_surface(xy, np.array([0.5, 0.5]), CONFIG, max_cells=10_000)
    assert s.values.size <= 10_201 and s.resolution > CONFIG.surface_resolution


def test_surface_in_blocks_equals_the_surface_at_once(monkeypatch):
    """A whole field's surface is blurred a block of lines at a time: cut into blocks of
    a few lines, the same values as one block."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(0.0, [30.0, 4.0], size=(300, 2))
    h = rng.uniform(size=300)
    whole = interest_surface(xy, h, CONFIG)
    monkeypatch.setattr(heuristic, "BLOCK_CELLS", 7 * whole.values.shape[1] // 2)
    blocks = interest_surface(xy, h, CONFIG)
    np.testing.assert_array_equal(blocks.values, whole.values)


def test_surface_bad_requests_name_the_problem():
    with pytest.raises(ValueError, match="no objects"):
        interest_surface(np.empty((0, 2)), np.empty(0), CONFIG)
    with pytest.raises(ValueError, match="empty bounds"):
        interest_surface(np.empty((0, 2)), np.empty(0), CONFIG, bounds=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match=r"3 positions but h of shape \(2,\)"):
        interest_surface(np.zeros((3, 2)), np.zeros(2), CONFIG)
    # no objects but bounds: nothing known anywhere
    s = interest_surface(np.empty((0, 2)), np.empty(0), CONFIG, bounds=(0.0, 1.0, 0.0, 1.0))
    assert np.all(s.values == 1.0)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(1, 40).flatmap(
        lambda k: st.tuples(
            arrays(float, (k, 2), elements=st.floats(-5.0, 5.0)),
            arrays(float, k, elements=st.floats(0.0, 1.0)),
        )
    )
)
def test_surface_stays_in_unit_interval(case):
    xy, h = case
    s = interest_surface(xy, h, CONFIG)
    assert np.all(np.isfinite(s.values)) and np.all((s.values >= 0.0) & (s.values <= 1.0))
