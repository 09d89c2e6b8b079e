"""The survey graph's factors as rows of arrays (backend/factor_store.py): what goes in
comes out bit for bit, ids are stable, and the factors of a node are found after removals
(merges and prunes) as they were with a set per node."""

from __future__ import annotations

import errno
import os
import pickle
import tempfile
from collections import Counter

import numpy as np
import pytest

from agrislam.backend.factor_store import RESERVED_ROWS, Factor, FactorStore


def odometry(a: int, b: int, dx: float) -> Factor:
    return Factor("odometry", (a, b), np.array([dx, 0.1, -0.2]), np.diag([1e-3, 2e-3, 1e-4]))


def test_factors_come_back_exactly_as_stored():
    store = FactorStore(capacity=1)  # grows
    cov = np.array([[0.04, 0.01], [0.01, 0.09]])
    factors = [
        Factor("prior_pose", (7,), np.array([1.0, 2.0, 0.3]), np.diag([1e-6, 1e-6, 1e-8])),
        odometry(7, 8, 0.5),
        Factor("detection", (8, 2**62 + 5), np.array([0.25, 1.5]), cov),
        Factor("row_member", (2**61, 2**62 + 5), np.array([0.7]), 0.05),
    ]
    ids = [store.append(f) for f in factors]
    assert ids == [0, 1, 2, 3] and len(store) == 4 and list(store) == ids
    for fid, factor in zip(ids, factors, strict=True):
        back = store[fid]
        assert back.kind == factor.kind and back.keys == factor.keys
        assert np.array_equal(back.value, factor.value) and back.value.shape == factor.value.shape
        if isinstance(factor.cov, float):
            assert back.cov == factor.cov
        else:
            assert np.array_equal(back.cov, factor.cov)
    assert store.kind(3) == "row_member"
    assert store.nbytes() < 4 * 200  # a few hundred bytes a factor, not a Python object each


def resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="reads Linux's /proc")
def test_the_reserved_rows_cost_memory_only_when_written():
    """The columns are made for a whole field's factors at once and never double (issue
    14): memory is what the rows written take, and a pickle holds those rows only."""
    before = resident_mb()
    store = FactorStore()
    for n in range(1000):
        store.append(odometry(n, n + 1, 0.5))
    assert len(store._kind) == RESERVED_ROWS and resident_mb() - before < 50
    assert store.nbytes() == 1000 * 28
    back = pickle.loads(data := pickle.dumps(store))
    assert len(data) < 200_000 and len(back._kind) == RESERVED_ROWS
    assert back[999].keys == (999, 1000) and back.append(odometry(5, 6, 0.1)) == 1000


def test_the_factors_of_a_node_after_removals():
    store = FactorStore()
    for n in range(10):
        store.append(odometry(100, 200 + n, float(n)))
    for fid in (0, 4, 9):
        del store[fid]
    assert store.ids_of(100) == [1, 2, 3, 5, 6, 7, 8]
    assert store.ids_of(204) == [] and store.ids_of(205) == [5]
    assert 4 not in store and len(store) == 7
    with pytest.raises(KeyError):
        store[4]
    new = store.append(odometry(100, 204, 1.0))
    assert store.ids_of(100)[-1] == new and store.ids_of(204) == [new]
    assert store.pop(new).keys == (100, 204) and store.ids_of(204) == []
    with pytest.raises(KeyError, match="in order"):
        store[50] = odometry(1, 2, 0.0)


def filled(store: FactorStore, n: int) -> list[Factor]:
    factors = [odometry(n + 1000, k, 0.01 * k) for k in range(n)]
    for factor in factors:
        store.append(factor)
    return factors


def same(a: Factor, b: Factor) -> bool:
    return (
        a.kind == b.kind
        and a.keys == b.keys
        and np.array_equal(a.value, b.value)
        and (np.array_equal(a.cov, b.cov))
    )


def test_full_payload_chunks_go_to_disk_and_come_back_exactly():
    store = FactorStore(capacity=2, chunk_rows=4)
    factors = filled(store, 11)  # two chunks sealed in the file, one open
    assert store._payload._file is not None and not store._payload._held
    assert all(same(store[k], f) for k, f in enumerate(factors))
    back = pickle.loads(pickle.dumps(store))  # a checkpoint: the payloads travel along
    assert all(same(back[k], f) for k, f in enumerate(factors))
    assert back._payload._file is not store._payload._file
    more = odometry(1, 2, 9.0)
    assert back.append(more) == 11 and same(back[11], more)


def test_a_full_disk_keeps_the_record_in_memory_with_an_issue(monkeypatch):
    def no_space(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tempfile, "TemporaryFile", no_space)
    issues: Counter[str] = Counter()
    store = FactorStore(issues=issues, chunk_rows=4)
    factors = filled(store, 10)
    assert all(same(store[k], f) for k, f in enumerate(factors))
    assert issues == {
        "factor record kept in memory: the temporary file failed (No space left on device)": 2
    }
