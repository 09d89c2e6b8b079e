"""backend/key_table.py: an integer per graph node, as a dict would hold it, in arrays."""

import numpy as np
import pytest

from agrislam.backend.graph import object_key, pose_key, row_key
from agrislam.backend.key_table import MISSING, KeyTable


def test_a_key_table_reads_and_writes_as_a_dict_does():
    keys = [pose_key(0, 0), pose_key(0, 5), pose_key(3, 2), object_key(7), row_key(1)]
    table, reference = KeyTable(), {}
    rng = np.random.default_rng(3)
    for step in range(400):
        key = keys[int(rng.integers(len(keys)))]
        if rng.random() < 0.3:
            assert table.pop(key, None) == reference.pop(key, None)
        else:
            table[key] = reference[key] = step
        assert len(table) == len(reference)
        for k in keys:
            assert (k in table) == (k in reference)
            assert table.get(k) == reference.get(k)
    assert dict(table.items()) == reference
    copy = KeyTable()
    for key, value in reference.items():
        copy[key] = value
    assert copy == table and (len(reference) == 0 or copy != KeyTable())
    many = table.get_many(np.array([*keys, object_key(10**6)], dtype=np.uint64))
    assert many.tolist() == [reference.get(k, MISSING) for k in keys] + [MISSING]
    assert table.get_many(keys).tolist() == many[:-1].tolist()  # a few: one by one
    assert table.get_many(keys * 10).tolist() == many[:-1].tolist() * 10  # many: at once


def test_robots_and_kinds_of_the_same_number_are_distinct_nodes():
    table = KeyTable()
    table[pose_key(0, 4)] = 1
    table[pose_key(1, 4)] = 2
    table[object_key(4)] = 3
    assert [table[pose_key(0, 4)], table[pose_key(1, 4)], table[object_key(4)]] == [1, 2, 3]
    with pytest.raises(KeyError):
        table[row_key(4)]
    with pytest.raises(ValueError, match=">= 0"):
        table[row_key(4)] = -1


def test_a_key_table_puts_many_keys_at_once():
    x, y, obj = pose_key(0, 0), pose_key(1, 70), object_key(9)
    table = KeyTable()
    table[x] = 7
    table.put_many(np.array([x, y, obj], dtype=np.uint64), 3)
    assert len(table) == 3 and dict(table.items()) == {x: 3, y: 3, obj: 3}
