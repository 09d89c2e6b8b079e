"""The cyclic garbage collector off the step path (run/collector.py): what survived is frozen
every so many frames, so a full collection never scans the whole map; the run's end hands
it back, and a cycle that died frozen is collected then."""

from __future__ import annotations

import gc
import platform
import sys
import weakref

import pytest

from agrislam.run import collector
from agrislam.run.collector import PacedCollector, release_free_heap


class Node:
    def __init__(self) -> None:
        self.other: Node | None = None


def cycle() -> weakref.ref:
    a, b = Node(), Node()
    a.other, b.other = b, a
    return weakref.ref(a)


def test_survivors_are_frozen_every_few_frames_and_handed_back_at_the_end():
    with PacedCollector(every=3) as collector:
        assert gc.get_freeze_count() > 0  # the state before the run
        kept = [Node() for _ in range(100)]
        frozen = gc.get_freeze_count()
        collector.frame()
        collector.frame()
        assert gc.get_freeze_count() == frozen  # not yet
        collector.frame()
        assert gc.get_freeze_count() >= frozen + len(kept)
        dead = cycle()
        collector.frame()  # the cycle (still alive) frozen with the third frame after
        collector.frame()
        collector.frame()
        gc.collect()
        assert dead() is not None  # a full collection does not scan the frozen heap
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert dead() is None  # collected once handed back


def test_young_cycles_are_collected_during_the_run():
    with PacedCollector(every=1000) as collector:
        dead = cycle()
        collector.frame()
        gc.collect()
        assert dead() is None


def test_a_run_hands_the_frozen_heap_back_also_when_it_stops(monkeypatch):
    from agrislam.config import AgrislamConfig
    from agrislam.io.sources import open_source
    from agrislam.io.sources.simulated import simulation_uri
    from agrislam.run.pipeline import _run
    from agrislam.world import WorldModel

    config = AgrislamConfig()
    world = WorldModel(config)
    frozen = []
    step = world.step

    def counted(frame):
        frozen.append(gc.get_freeze_count())
        if len(frozen) == 40:
            raise KeyboardInterrupt
        return step(frame)

    monkeypatch.setattr(world, "step", counted)
    result = _run(open_source(simulation_uri(plants=40, seed=1), config), world, None, None)
    assert isinstance(result.error, KeyboardInterrupt) and len(frozen) == 40
    assert min(frozen) > 0 and gc.get_freeze_count() == 0


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
    reason="malloc_trim is glibc's",
)
def test_the_free_heap_is_handed_back_with_glibc_malloc_trim():
    """The C library's own malloc_trim is found and called; how much it hands back of a
    fragmented heap is measured in benchmarks/bench_outputs.py."""
    assert collector._malloc_trim() is not None
    assert release_free_heap()


def test_the_free_heap_is_trimmed_with_each_freeze_and_skipped_without_malloc_trim(monkeypatch):
    trims = []
    monkeypatch.setattr(collector, "_malloc_trim", lambda: trims.append)
    with PacedCollector(every=3) as paced:
        for _ in range(7):
            paced.frame()
    assert trims == [0, 0]  # frames 3 and 6, the whole free heap (no pad kept)
    monkeypatch.setattr(collector, "_malloc_trim", lambda: None)
    assert not release_free_heap()
