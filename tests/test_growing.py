"""GrowingRows (growing.py): rows appended one at a time or many at once come back as one
array, in order and unchanged, across the doublings of its capacity."""

from __future__ import annotations

import numpy as np

from agrislam.growing import GrowingRows


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
