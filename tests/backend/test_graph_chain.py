"""backend/graph.py's robot chain: pose times in an array, pose keys computed."""

import numpy as np
import pytest

from agrislam.backend.graph import RobotChain, pose_key


def test_a_chain_numbers_its_pose_keys_in_the_order_driven():
    chain = RobotChain(index=2)
    keys = [chain.add(t) for t in (0.0, 0.5, 1.5)]
    assert keys == [pose_key(2, i) for i in range(3)]
    assert list(chain.keys) == keys and len(chain.keys) == 3
    assert chain.keys[-1] == keys[-1] and chain.keys[0] == keys[0]
    assert chain.keys[1:] == keys[1:]
    assert keys[1] in chain.keys and np.uint64(keys[2]) in chain.keys
    assert pose_key(2, 3) not in chain.keys and pose_key(1, 0) not in chain.keys
    assert chain.times.tolist() == [0.0, 0.5, 1.5]
    with pytest.raises(IndexError):
        chain.keys[3]
    chain.clear()
    assert len(chain.keys) == 0 and chain.add(7.0) == pose_key(2, 0)


def test_key_kind_and_index_read_gtsam_symbols() -> None:
    """key_kind / key_index read a key's bits as gtsam.Symbol does, for plain and numpy ints."""
    import gtsam

    from agrislam.backend.graph import key_index, key_indices, key_kind

    for letter, index in [("x", 0), ("l", 123_456_789), ("r", 5), ("x", 3 * (1 << 40) + 7)]:
        key = gtsam.symbol(letter, index)
        symbol = gtsam.Symbol(key)
        for k in (key, np.uint64(key), int(key)):
            assert key_kind(k) == chr(symbol.chr()) == letter
            assert key_index(k) == symbol.index() == index
        assert key_indices(np.array([key], dtype=np.uint64)).tolist() == [index]
