"""GrowingRows (growing.py): rows appended one at a time or many at once come back as one
array, in order and unchanged, across the doublings of its capacity."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.growing import GrowingRows, grown


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
