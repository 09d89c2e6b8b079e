"""The survey graph's object nodes as arrays: the same answers as the dict they replace."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.backend.object_nodes import ObjectNodes


def test_behaves_as_the_dict_it_replaces_through_adds_removals_and_compaction():
    rng = np.random.default_rng(3)
    nodes, reference = ObjectNodes(), {}
    for step in range(3000):
        object_id = int(rng.integers(0, 400))
        if object_id in reference and rng.random() < 0.6:
            del nodes[object_id], reference[object_id]
        else:
            xy = rng.normal(size=2)  # a present id keeps its place, as in a dict
            nodes[object_id], reference[object_id] = xy, xy.copy()
        if step % 97 == 0:
            assert list(nodes) == list(reference) and len(nodes) == len(reference)
    assert nodes.ids().tolist() == list(reference)
    assert nodes.keys() == reference.keys()
    for object_id, xy in reference.items():
        np.testing.assert_array_equal(nodes[object_id], xy)
    absent = [i for i in range(-2, 1000) if i not in reference]
    assert not any(i in nodes for i in absent) and "7" not in nodes
    wanted = [*list(reference)[:5], *absent[:3]]
    assert nodes.missing(wanted).tolist() == absent[:3]
    with pytest.raises(KeyError):
        nodes[absent[-1]]
    with pytest.raises(KeyError):
        del nodes[absent[-1]]
    with pytest.raises(ValueError, match="non-negative"):
        nodes[-1] = (0.0, 0.0)


def test_empty_and_a_copy_of_the_position_is_kept():
    nodes = ObjectNodes()
    assert not nodes and list(nodes) == [] and len(nodes.ids()) == 0
    xy = np.array([1.0, 2.0])
    nodes[5] = xy
    xy[0] = 9.0
    assert nodes and 5 in nodes and nodes[5].tolist() == [1.0, 2.0]
