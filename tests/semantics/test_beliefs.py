"""The belief table: updates, lazy time update, fusion, bad input, growth, persistence."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agrislam.config import SECONDS_PER_DAY, FieldSchema, SemanticsConfig
from agrislam.records import ContinuousMeasurement as Cm
from agrislam.records import DiscreteMeasurement as Dm
from agrislam.semantics import BeliefInputError, BeliefTable
from agrislam.semantics.growth import transition_matrix

CONFIG = SemanticsConfig()
DAY = SECONDS_PER_DAY

GROWING = FieldSchema.model_validate(
    {
        "attributes": {
            "type": {"kind": "discrete", "values": ["crop", "weed"]},
            "size": {
                "kind": "discrete",
                "values": ["small", "medium", "big"],
                "time_model": {"rate_per_day": 0.04, "l_max": 0.6, "process_noise": 0.01},
            },
            "length": {
                "kind": "continuous",
                "min": 0.0,
                "max": 0.6,
                "prior_mean": 0.1,
                "prior_var": 0.01,
                "time_model": {"rate_per_day": 0.04, "l_max": 0.6, "variance_per_day": 1e-4},
            },
        }
    }
)


def _state_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_new_objects_start_uniform_at_the_prior_and_unmeasured():
    schema = FieldSchema.model_validate(
        {
            "attributes": {
                "type": {"kind": "discrete", "values": ["crop", "weed"], "prior": [0.9, 0.1]},
                "size": {"kind": "discrete", "values": ["s", "m", "b"]},
                "length": {"kind": "continuous", "min": 0.0, "max": 0.6},
            }
        }
    )
    table = BeliefTable(schema, CONFIG)
    ids = table.add(3, t=5.0)
    assert ids.tolist() == [0, 1, 2] and len(table) == 3
    np.testing.assert_allclose(table.probabilities("type", ids), [[0.9, 0.1]] * 3)
    np.testing.assert_allclose(table.probabilities("size", ids), np.full((3, 3), 1 / 3))
    mean, var = table.gaussian("length", ids)
    # no prior given: mid-range, variance of a uniform over [0, 0.6] = 0.36 / 12
    np.testing.assert_allclose(mean, 0.3)
    np.testing.assert_allclose(var, 0.03)
    assert table.n_meas.tolist() == [0, 0, 0] and table.last_update.tolist() == [5.0] * 3
    np.testing.assert_allclose(table.interest(), 1.0)


def test_paper_inconsistent_measurements_of_a_small_healthy_weed():
    """Sec. 3.2.2: type measured crop (p 0.7), weed (0.8), weed (0.6); size and health right
    each time (small p 0.9, healthy p 0.95).

    type:   (0.5, 0.5) -> (0.7, 0.3) -> (7/19, 12/19) -> (0.28, 0.72);  D_KLN = 0.1445492
    size:   0.9^3 / (0.9^3 + 2 * 0.05^3) = 0.729 / 0.72925 = 0.9996572;  D_KLN = 0.9969821
    health: 0.95^3 / (0.95^3 + 0.05^3) = 0.857375 / 0.8575 = 0.9998542; D_KLN = 0.9979320
    h = 1 - 3/4 * (0.1445492 + 0.9969821 + 0.9979320) / 3 = 0.4651342
    """
    table = BeliefTable(FieldSchema.preset("crops_weeds"), CONFIG)
    (weed,) = table.add(1, t=0.0)
    seen = [("crop", 0.7), ("weed", 0.8), ("weed", 0.6)]
    expected_type = [[0.7, 0.3], [7 / 19, 12 / 19], [0.28, 0.72]]
    for k, ((value, p), want) in enumerate(zip(seen, expected_type, strict=True)):
        report = table.update(
            [weed],
            [{"type": Dm(value, p), "size": Dm("small", 0.9), "health": Dm("healthy", 0.95)}],
            t=float(k),
        )
        assert report.applied == {"type": 1, "size": 1, "health": 1}
        np.testing.assert_allclose(table.probabilities("type", [weed])[0], want)
    np.testing.assert_allclose(table.probabilities("size", [weed])[0, 0], 0.729 / 0.72925)
    np.testing.assert_allclose(table.probabilities("health", [weed])[0, 0], 0.857375 / 0.8575)
    assert table.n_meas[weed] == 3 and table.last_update[weed] == 2.0
    assert table.interest([weed])[0] == pytest.approx(0.4651342, abs=1e-7)


def test_kalman_update_in_the_table():
    table = BeliefTable(FieldSchema.preset("colour_length"), CONFIG)
    ids = table.add(2, t=0.0)
    # prior (0.3, 0.03); measurement (0.5, 0.01): K = 0.75 -> mean 0.45, var 0.0075
    table.update(ids, [{"length": Cm(0.5, 0.01)}, {}], t=0.0)
    mean, var = table.gaussian("length", ids)
    np.testing.assert_allclose(mean, [0.45, 0.3])
    np.testing.assert_allclose(var, [0.0075, 0.03])
    assert table.n_meas.tolist() == [1, 1]  # an empty mapping still counts the detection


def test_zero_variance_measurement_keeps_a_positive_variance():
    table = BeliefTable(FieldSchema.preset("colour_length"), CONFIG)
    ids = table.add(1, t=0.0)
    table.update(ids, [{"length": Cm(0.2, 0.0)}], t=0.0)
    table.update(ids, [{"length": Cm(0.4, 0.0)}], t=0.0)
    mean, var = table.gaussian("length", ids)
    assert np.isfinite(mean[0]) and var[0] > 0.0 and 0.2 <= mean[0] <= 0.4


def test_ignored_measurements_are_counted_and_change_nothing():
    table = BeliefTable(FieldSchema.preset("colour_size"), CONFIG)
    ids = table.add(2, t=0.0)
    # 1/3 for size and 1/7 for colour: 0.3 < 1/3 ignored, 0.3 > 1/7 used
    report = table.update(ids, [{"size": Dm("big", 0.3), "colour": Dm("red", 0.3)}, {}], t=1.0)
    assert report.ignored == {"size": 1, "colour": 0}
    assert report.applied == {"size": 0, "colour": 1}
    assert table.n_ignored == {"colour": 0, "size": 1}
    np.testing.assert_allclose(table.probabilities("size", ids), np.full((2, 3), 1 / 3))
    assert table.n_meas.tolist() == [1, 1]


def test_same_object_twice_in_one_call_gets_both_updates():
    one = BeliefTable(FieldSchema.preset("crops_weeds"), CONFIG)
    two = BeliefTable(FieldSchema.preset("crops_weeds"), CONFIG)
    for table in (one, two):
        table.add(3, t=0.0)
    m1 = {"type": Dm("weed", 0.8), "size": Dm("big", 0.6)}
    m2 = {"type": Dm("crop", 0.7), "size": Dm("big", 0.9), "health": Dm("diseased", 0.7)}
    one.update([1, 2, 1], [m1, {"type": Dm("crop", 0.9)}, m2], t=1.0)
    two.update([1, 2], [m1, {"type": Dm("crop", 0.9)}], t=1.0)
    two.update([1], [m2], t=1.0)
    assert _state_equal(one.state(), two.state())
    assert one.n_meas.tolist() == [0, 2, 1]


def test_same_continuous_object_twice_in_one_call():
    table = BeliefTable(FieldSchema.preset("colour_length"), CONFIG)
    ids = table.add(1, t=0.0)
    # prior info 1/0.03 + 1/0.01 + 1/0.06 = 150: mean (10 + 50 + 3.333) / 150
    table.update([0, 0], [{"length": Cm(0.5, 0.01)}, {"length": Cm(0.2, 0.06)}], t=0.0)
    mean, var = table.gaussian("length", ids)
    np.testing.assert_allclose(var, [1 / 150])
    np.testing.assert_allclose(mean, [63.333333333 / 150])


def test_time_update_is_lazy_and_reading_does_not_change_the_belief():
    table = BeliefTable(GROWING, CONFIG)
    ids = table.add(3, t=0.0)
    table.update(ids, [{"size": Dm("small", 0.9)}] * 3, t=0.0)
    before = table.state()
    # reading 30 days later returns A(30 d) applied to the stored belief ...
    A = transition_matrix(3, GROWING.attributes["size"].time_model, 30 * DAY)
    later = table.probabilities("size", ids[:1], t=30 * DAY)
    np.testing.assert_allclose(later[0], A @ before["p/size"][0])
    mean, var = table.gaussian("length", ids[:1], t=30 * DAY)
    # mean 0.6 - (0.6 - 0.1) e^{-1.2}; var 0.01 e^{-2.4} + 1e-4 (1 - e^{-2.4}) / 0.08
    assert mean[0] == pytest.approx(0.6 - 0.5 * math.exp(-1.2))
    assert var[0] == pytest.approx(0.01 * math.exp(-2.4) + 1e-4 * (1 - math.exp(-2.4)) / 0.08)
    # ... without storing it
    assert _state_equal(table.state(), before)
    # an update brings only the touched object forward
    table.update(ids[1:2], [{}], t=30 * DAY)
    assert table.belief_time.tolist() == [0.0, 30 * DAY, 0.0]
    np.testing.assert_allclose(table.probabilities("size", ids[1:2])[0], later[0])
    np.testing.assert_array_equal(table.state()["p/size"][[0, 2]], before["p/size"][[0, 2]])
    # an update earlier than the belief's time does not move it backwards
    table.update(ids[1:2], [{}], t=10 * DAY)
    assert table.belief_time[1] == 30 * DAY and table.last_update[1] == 30 * DAY


def test_reading_in_between_does_not_change_what_an_update_gives():
    a, b = BeliefTable(GROWING, CONFIG), BeliefTable(GROWING, CONFIG)
    for table in (a, b):
        table.add(1, t=0.0)
        table.update([0], [{"size": Dm("small", 0.8), "length": Cm(0.1, 1e-3)}], t=0.0)
    for day in (3.0, 7.5, 12.0):
        b.probabilities("size", [0], t=day * DAY)
        b.interest(t=day * DAY)
    for table in (a, b):
        table.update([0], [{"size": Dm("medium", 0.7)}], t=20 * DAY)
    assert _state_equal(a.state(), b.state())


@pytest.mark.parametrize(
    ("measurement", "message"),
    [
        ({"type": Dm("weed", 1.2)}, r"'type'.*p = 1\.2"),
        ({"type": Dm("weed", -0.1)}, r"'type'.*p = -0\.1"),
        ({"type": Dm("weed", float("nan"))}, r"'type'.*p = nan"),
        ({"type": Dm("tree", 0.9)}, r"'type'.*value 'tree' not in \['crop', 'weed'\]"),
        ({"colour": Dm("red", 0.9)}, r"'colour'.*unknown attribute"),
        ({"length": Cm(0.2, -1e-4)}, r"'length'.*variance -0\.0001"),
        ({"length": Cm(float("nan"), 1e-4)}, r"'length'.*value nan"),
        ({"length": Cm(0.2, float("inf"))}, r"'length'.*variance inf"),
        ({"type": Cm(0.2, 0.1)}, r"'type'.*expected a discrete measurement"),
        ({"length": Dm("crop", 0.9)}, r"'length'.*expected a continuous measurement"),
    ],
)
def test_bad_input_names_attribute_and_value_and_changes_nothing(measurement, message):
    table = BeliefTable(GROWING, CONFIG)
    ids = table.add(3, t=0.0)
    table.update(ids, [{"type": Dm("crop", 0.8)}] * 3, t=1.0)
    before = table.state()
    good = {"type": Dm("weed", 0.9), "length": Cm(0.3, 1e-3)}
    with pytest.raises(BeliefInputError, match=message):
        # the bad one comes last: the good ones before it must not have been applied
        table.update(ids, [good, good, measurement], t=2 * DAY)
    assert _state_equal(table.state(), before)


def test_bad_ids_and_shapes_are_refused():
    table = BeliefTable(GROWING, CONFIG)
    table.add(2, t=0.0)
    with pytest.raises(BeliefInputError, match=r"\[2\] not in the table"):
        table.update([0, 2], [{}, {}], t=1.0)
    with pytest.raises(BeliefInputError, match="2 object ids but 1"):
        table.update([0, 1], [{}], t=1.0)
    with pytest.raises(BeliefInputError, match="not finite"):
        table.update([0], [{}], t=float("nan"))
    with pytest.raises(BeliefInputError, match="not a discrete attribute"):
        table.probabilities("length", [0])
    with pytest.raises(BeliefInputError, match="not a continuous attribute"):
        table.gaussian("size", [0])
    with pytest.raises(BeliefInputError, match="integer"):
        table.probabilities("size", np.array([0.5]))
    with pytest.raises(BeliefInputError, match="itself"):
        table.fuse(1, 1)


def test_schema_less_table_counts_detections_only():
    table = BeliefTable(None, CONFIG)
    ids = table.add(2, t=0.0)
    table.update(ids, [{}, {}], t=1.0)
    np.testing.assert_allclose(table.interest(), [0.5, 0.5])  # 1 - 1/2
    assert table.discrete_beliefs() == {} and table.continuous_beliefs() == {}
    with pytest.raises(BeliefInputError, match=r"unknown attribute.*none"):
        table.update([0], [{"type": Dm("crop", 0.9)}], t=1.0)


def test_fuse_equals_all_measurements_on_one_object():
    fused, single = BeliefTable(GROWING, CONFIG), BeliefTable(GROWING, CONFIG)
    fused.add(2, t=0.0)
    single.add(1, t=0.0)
    first = {"type": Dm("weed", 0.8), "size": Dm("small", 0.7), "length": Cm(0.12, 4e-4)}
    second = {"type": Dm("weed", 0.6), "size": Dm("medium", 0.5), "length": Cm(0.15, 9e-4)}
    fused.update([0, 1], [first, second], t=0.0)
    single.update([0, 0], [first, second], t=0.0)
    fused.fuse(0, 1)
    for name in ("type", "size"):
        np.testing.assert_allclose(fused.probabilities(name, [0]), single.probabilities(name, [0]))
    np.testing.assert_allclose(fused.gaussian("length", [0]), single.gaussian("length", [0]))
    assert fused.n_meas.tolist() == [2, 1]


def test_fuse_brings_both_to_the_later_time():
    table = BeliefTable(GROWING, CONFIG)
    table.add(2, t=0.0)
    table.update([0], [{"size": Dm("small", 0.9)}], t=0.0)
    table.update([1], [{"size": Dm("small", 0.9)}], t=40 * DAY)
    table.fuse(1, 0)
    assert table.belief_time[1] == 40 * DAY and table.last_update[1] == 40 * DAY
    assert table.n_meas.tolist() == [1, 2]


def test_growth_is_amortised_and_keeps_rows():
    table = BeliefTable(GROWING, CONFIG, capacity=1)
    capacities = set()
    for k in range(3000):
        (row,) = table.add(1, t=float(k))
        if k % 100 == 0:
            table.update([row], [{"type": Dm("weed", 0.9)}], t=float(k))
        capacities.add(table.capacity)
    assert len(table) == 3000 and table.capacity >= 3000
    assert len(capacities) <= math.ceil(math.log2(3000)) + 1  # doubling: 1, 2, 4, ... 4096
    weed = table.probabilities("type", np.arange(0, 3000, 100))[:, 1]
    np.testing.assert_allclose(weed, 0.9)
    assert table.last_update[2999] == 2999.0 and table.n_meas.sum() == 30


def test_exposed_arrays_are_read_only():
    table = BeliefTable(GROWING, CONFIG)
    table.add(2, t=0.0)
    for array in (table.n_meas, table.last_update, table.belief_time):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 5
    # what reads return is a copy: changing it does not touch the table
    table.probabilities("type", [0])[0, 0] = 99.0
    table.discrete_beliefs()["type"][:] = 99.0
    table.continuous_beliefs()["length"][0][:] = 99.0
    np.testing.assert_allclose(table.probabilities("type", [0, 1]), 0.5)
    np.testing.assert_allclose(table.gaussian("length", [0, 1])[0], 0.1)


def test_state_round_trip():
    table = BeliefTable(GROWING, CONFIG)
    table.add(4, t=0.0)
    table.update([0, 3], [{"size": Dm("big", 0.2), "length": Cm(0.3, 1e-3)}, {}], t=2.0)
    restored = BeliefTable.from_state(GROWING, CONFIG, table.state())
    assert _state_equal(restored.state(), table.state()) and restored.n_ignored == {
        "type": 0,
        "size": 1,
    }
    np.testing.assert_allclose(restored.interest(t=5 * DAY), table.interest(t=5 * DAY))
    broken = table.state()
    broken["p/size"] = broken["p/size"][:, :2]
    with pytest.raises(BeliefInputError, match=r"'p/size'.*shape"):
        BeliefTable.from_state(GROWING, CONFIG, broken)


# --------------------------------------------------------------- property tests

_discrete_meas = st.tuples(
    st.sampled_from(["type", "size"]), st.floats(0.0, 1.0), st.integers(0, 2)
)
_continuous_meas = st.tuples(st.floats(-1.0, 2.0), st.floats(0.0, 1.0))
_step = st.tuples(
    st.lists(st.integers(0, 4), min_size=1, max_size=6),  # ids, repeats allowed
    st.lists(
        st.tuples(st.lists(_discrete_meas, max_size=2), st.none() | _continuous_meas),
        min_size=6,
        max_size=6,
    ),
    st.floats(0.0, 60.0),  # days since the previous step
)


@settings(max_examples=60, deadline=None)
@given(st.lists(_step, min_size=1, max_size=8))
def test_beliefs_stay_normalised_and_finite_under_any_valid_updates(steps):
    table = BeliefTable(GROWING, CONFIG)
    table.add(5, t=0.0)
    t = 0.0
    for ids, per_object, days in steps:
        t += days * DAY
        measurements = []
        for (discrete, cont), _ in zip(per_object, ids, strict=False):
            m = {}
            for name, p, v in discrete:
                values = GROWING.attributes[name].values
                m[name] = Dm(values[v % len(values)], p)
            if cont is not None:
                m["length"] = Cm(*cont)
            measurements.append(m)
        table.update(ids, measurements, t)
        for when in (None, t, t + 30 * DAY):
            for belief in table.discrete_beliefs(t=when).values():
                assert np.all(np.isfinite(belief)) and np.all(belief >= 0.0)
                np.testing.assert_allclose(belief.sum(axis=1), 1.0, atol=1e-12)
            mean, var = table.gaussian("length", np.arange(5), t=when)
            assert np.all(np.isfinite(mean)) and np.all((var > 0.0) & np.isfinite(var))
            h = table.interest(t=when)
            assert np.all((h >= 0.0) & (h <= 1.0))


_bad = st.sampled_from(
    [
        {"type": Dm("crop", 1.0001)},
        {"size": Dm("huge", 0.9)},
        {"length": Cm(0.1, -1.0)},
        {"length": Cm(float("inf"), 0.1)},
        {"height": Cm(0.1, 0.1)},
        {"size": Dm("small", float("nan"))},
    ]
)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 5), _bad, st.floats(0.0, 10.0))
def test_bad_input_anywhere_leaves_the_table_unchanged(position, bad, days):
    table = BeliefTable(GROWING, CONFIG)
    table.add(6, t=0.0)
    table.update([1, 2], [{"size": Dm("small", 0.8)}, {"length": Cm(0.2, 1e-3)}], t=0.0)
    before, ignored = table.state(), dict(table.n_ignored)
    measurements = [{"type": Dm("weed", 0.9), "size": Dm("big", 0.1)}] * 6
    measurements[position] = bad
    with pytest.raises(BeliefInputError):
        table.update(np.arange(6), measurements, t=days * DAY)
    assert _state_equal(table.state(), before) and table.n_ignored == ignored
