import numpy as np
import pytest

from agrislam.config import FieldSchema
from agrislam.sim.config import SimConfig
from agrislam.sim.field import bin_length, make_field, value_probabilities


def _field(seed: int = 1, **over):
    cfg = SimConfig.model_validate(over)
    return make_field(cfg, np.random.default_rng(seed)), cfg


def test_default_field_is_the_papers_400_plants_on_rows():
    field, _ = _field()
    assert len(field) == 400
    assert np.bincount(field.row).tolist() == [40] * 10
    s, across = field.to_field(field.xy)
    # rows 1 m apart (jitter 1 cm), plants 0.4-0.5 m apart along each row (sec. 3.1.1)
    assert np.abs(across - field.row * 1.0).max() < 0.06
    for k in range(10):
        gaps = np.diff(np.sort(s[field.row == k]))
        assert gaps.min() >= 0.4 - 1e-9 and gaps.max() <= 0.5 + 1e-9
    assert set(field.discrete) == {"colour", "size"}
    assert not field.is_weed.any()


def test_same_seed_same_field_other_seed_other_field():
    a, _ = _field(3)
    b, _ = _field(3)
    c, _ = _field(4)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.discrete["colour"], b.discrete["colour"])
    assert not np.allclose(a.xy, c.xy)


def test_size_is_the_length_binned_into_equal_cells_of_l_max():
    # App. B: n cells of [0, l_max]; 0.6 m split in three: < 0.2 small, < 0.4 medium, else big
    assert bin_length(np.array([0.0, 0.19, 0.21, 0.39, 0.41, 0.6, 0.7]), 3, 0.6).tolist() == [
        0,
        0,
        1,
        1,
        2,
        2,
        2,
    ]
    field, _ = _field()
    np.testing.assert_array_equal(field.discrete["size"], bin_length(field.length, 3, 0.6))


def test_row_angle_rotates_the_rows():
    field, _ = _field(field={"row_angle_deg": 30.0, "n_plants": 40, "n_rows": 2})
    row0 = field.xy[field.row == 0]
    d = row0[-1] - row0[0]
    assert np.degrees(np.arctan2(d[1], d[0])) == pytest.approx(30.0, abs=0.5)


def test_row_length_fills_rows_instead_of_a_count():
    field, _ = _field(field={"n_plants": None, "row_length": 5.0, "n_rows": 3})
    s, _ = field.to_field(field.xy)
    assert s.max() <= 5.0 + 0.05
    assert 3 * 10 <= len(field) <= 3 * 13  # 5 m / 0.4-0.5 m + the first plant


def test_gaps_doubles_and_off_row_weeds():
    field, _ = _field(
        schema="crops_weeds",
        field={"gap_probability": 0.1, "double_probability": 0.1, "weed_fraction": 0.1},
    )
    n_weed = field.is_weed.sum()
    assert 30 <= n_weed <= 40
    crop_rows = field.row[~field.is_weed]
    assert (field.row[field.is_weed] == -1).all() and (crop_rows >= 0).all()
    # gaps take ~10 % of 400 positions away, doubles add ~10 % back
    assert 380 <= (~field.is_weed).sum() <= 420
    # weeds are typed 'weed', crops 'crop'
    types = np.array(FieldSchema.preset("crops_weeds").discrete["type"].values)
    assert (types[field.discrete["type"][field.is_weed]] == "weed").all()
    assert (types[field.discrete["type"][~field.is_weed]] == "crop").all()
    # weeds stand off the rows and keep the minimum plant distance from every plant
    _, across = field.to_field(field.xy[field.is_weed])
    assert (np.abs(across - np.round(across)) >= 0.25 - 1e-9).all()
    others = field.xy[~field.is_weed]
    d = np.linalg.norm(field.xy[field.is_weed][:, None] - others[None], axis=2)
    assert d.min() >= 0.4
    # some doubled plants stand 5-15 cm from their twin
    from scipy.spatial import cKDTree

    nn = cKDTree(others).query(others, k=2)[0][:, 1]
    assert ((nn >= 0.05 - 1e-9) & (nn <= 0.15 + 1e-9)).sum() >= 20


def test_value_weights_named_and_rest():
    spec = FieldSchema.preset("intercropping").discrete["type"]
    np.testing.assert_allclose(value_probabilities(spec, {"A": 0.92, "B": 0.08}), [0.92, 0.08])
    colour = FieldSchema.preset("colour_size").discrete["colour"]
    np.testing.assert_allclose(value_probabilities(colour, {"red": 0.4}), [0.1] * 5 + [0.4, 0.1])
    np.testing.assert_allclose(value_probabilities(colour, None), np.full(7, 1 / 7))


def test_growth_follows_the_app_b_ode():
    field, _ = _field(schema="colour_length")
    later = field.grown(10.0)
    # x(t + dt) = l_max - (l_max - x) exp(-alpha dt)
    expected = 0.6 - (0.6 - field.length) * np.exp(-field.growth_rate * 10.0)
    np.testing.assert_allclose(later.length, expected)
    np.testing.assert_allclose(later.continuous["length"], expected)
    assert (later.length > field.length).all() and (later.length < 0.6).all()
    # alpha = 0.04/day +- 20 %
    assert field.growth_rate.min() >= 0.032 and field.growth_rate.max() <= 0.048
    with pytest.raises(ValueError, match="backwards"):
        field.grown(-1.0)


def test_size_follows_growth():
    field, _ = _field()
    later = field.grown(60.0)
    assert (later.discrete["size"] >= field.discrete["size"]).all()
    assert (later.discrete["size"] > field.discrete["size"]).any()
    np.testing.assert_array_equal(field.discrete["colour"], later.discrete["colour"])


def test_truth_objects_carry_schema_values():
    field, _ = _field()
    truth = list(field.truth_objects())
    assert len(truth) == 400 and truth[0].id == "p0000"
    assert set(truth[5].attributes) == {"colour", "size"}
    assert truth[5].attributes["size"] in ("small", "medium", "big")
    np.testing.assert_array_equal(truth[7].xy, field.xy[7])


def test_layout_rejects_count_and_length_together():
    with pytest.raises(ValueError, match="exactly one"):
        SimConfig.model_validate({"field": {"n_plants": 10, "row_length": 5.0}})
