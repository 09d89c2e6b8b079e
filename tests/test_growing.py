"""GrowingRows (growing.py): rows appended one at a time or many at once come back as one
array, in order and unchanged, across the doublings of its capacity."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.growing import AHEAD, Doubling, GrowingRows, grown


def test_rows_come_back_in_order_across_growth():
    poses = GrowingRows((3,))
    expected = np.arange(100 * 3, dtype=float).reshape(100, 3) / 7.0
    for row in expected[:40]:
        poses.append(row)
    poses.extend(expected[40:])
    assert len(poses) == 100 and np.array_equal(poses.array, expected)


def test_scalars_of_a_dtype():
    ids = GrowingRows(dtype=np.int32)
    assert ids.array.shape == (0,)
    ids.extend([3, -1, 7])
    ids.append(9)
    assert ids.array.dtype == np.int32 and ids.array.tolist() == [3, -1, 7, 9]


@pytest.mark.parametrize(
    ("fill", "dtype"), [(0, np.float64), (np.nan, np.float64), (-1, np.int64), (False, bool)]
)
def test_grown_keeps_the_rows_and_fills_the_new_ones(fill, dtype):
    """`grown` (every table's doubling): the old rows as they were, the new ones `fill`
    (zeros from calloc, any other fill written)."""
    old = np.arange(12).reshape(4, 3).astype(dtype)
    new = grown(old, 9, fill)
    assert new.shape == (9, 3) and new.dtype == old.dtype
    np.testing.assert_array_equal(new[:4], old)
    np.testing.assert_array_equal(new[4:], np.full((5, 3), fill, dtype=dtype))


def _table(capacity: int) -> dict[str, np.ndarray]:
    return {"ids": np.full((capacity, 2), -1, dtype=np.int64), "xy": np.zeros(capacity)}


def test_doubling_keeps_every_row_written_before_it():
    """A table grown a row at a time (Doubling, every table's growth): the rows as last
    written, including those rewritten while the doubled columns were being made, and the
    rows not used yet at their fill."""
    doubling = Doubling({"ids": -1, "xy": 0})
    table, capacity = _table(16), 16
    for row in range(1000):
        doubled = doubling.reserve(row + 1, capacity, lambda table=table: table)
        if doubled:
            table, capacity = doubled, len(doubled["ids"])
        table["ids"][row] = (row, 2 * row)
        table["xy"][row] = row / 3
        table["xy"][row // 2] = -row  # an older row changes as the table grows
    expected_xy = np.arange(1000) / 3
    for row in range(1000):
        expected_xy[row // 2] = -row
    assert capacity == 1024
    np.testing.assert_array_equal(table["ids"][:1000], np.c_[np.arange(1000), 2 * np.arange(1000)])
    np.testing.assert_array_equal(table["xy"][:1000], expected_xy)
    np.testing.assert_array_equal(table["ids"][1000:], -1)
    np.testing.assert_array_equal(table["xy"][1000:], 0)


def test_doubled_columns_are_made_before_the_row_that_fills_the_table():
    """The fill and the pages of the doubled columns are written over the last 1/AHEAD of
    the capacity, a slice a row, so the doubling itself only copies."""
    doubling, table = Doubling({"ids": -1, "xy": 0}), _table(1024)
    made = []
    for n in range(1, 1025):
        assert doubling.reserve(n, 1024, lambda: table) is None
        made.append(doubling.made)
    window = 1024 // AHEAD
    assert max(made[: 1024 - window]) == 0  # nothing allocated before the window
    assert np.all(np.diff(made[1024 - window :]) > 0) and made[-1] == 2048
    doubled = doubling.reserve(1025, 1024, lambda: table)
    assert doubled is not None and len(doubled["xy"]) == 2048 and doubling.made == 0


def test_a_bulk_reserve_grows_at_once():
    doubling, table = Doubling({"ids": -1, "xy": 0}), _table(8)
    table["xy"][:] = 5
    doubled = doubling.reserve(100, 8, lambda: table)
    assert len(doubled["ids"]) == 100
    np.testing.assert_array_equal(doubled["xy"], np.r_[np.full(8, 5.0), np.zeros(92)])
    np.testing.assert_array_equal(doubled["ids"], -1)
