"""iSAM2's bookkeeping in the incremental back end (incremental/live.py), one rule a part:

- `PendingUpdate`: what the next iSAM2 update adds (factors, new nodes with their initial
  values) and removes (factor slots). `flush` hands it to `ISAM2.update` and clears it. A
  node entered since the last update is only here: its estimate is its initial value.
- `SlotTable`: what each live iSAM2 factor slot holds (a factor of the record, a retired
  object's anchor, or history folded onto keyframes and rows) and the keys it touches.

What iSAM2 lets go of is held in backend/incremental/retired.py.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TypeVar

import gtsam
import numpy as np

from agrislam.backend.graph import key_kind
from agrislam.backend.incremental.retired import Anchored
from agrislam.backend.values import insert_value, value_array
from agrislam.config import SlamConfig

Serialisable = TypeVar("Serialisable", gtsam.NonlinearFactorGraph, gtsam.Values)


@dataclass(frozen=True, slots=True)
class Entry:
    """What a factor slot holds: the `keys` it touches, and where it came from: factor `fid`
    of the record, the `anchor` of a retired object come back (keys: its keyframe, the
    object), or neither (history folded onto keyframes and rows)."""

    keys: tuple[int, ...]
    fid: int | None = None
    anchor: Anchored | None = None


class PendingUpdate:
    """The next iSAM2 update: factors to add (in order), new nodes and their initial values,
    slots to remove. Filled between updates, emptied by `flush`."""

    def __init__(self) -> None:
        self._clear()

    def _clear(self) -> None:
        self._factors: list[tuple[gtsam.NonlinearFactor, Entry] | None] = []  # None: dropped
        self._at: dict[int, int] = {}  # fid -> its place in _factors
        self._values = gtsam.Values()
        self._guess: dict[int, np.ndarray] = {}  # the same values, as arrays
        self._removals: list[int] = []

    def __getstate__(self) -> dict:
        """To pickle: the factors in GTSAM's serialisation (None where dropped), the new
        values only as arrays (`_guess` holds the same)."""
        state = self.__dict__.copy()
        kept = [n for n, p in enumerate(self._factors) if p is not None]
        graph = gtsam.NonlinearFactorGraph()
        for n in kept:
            graph.push_back(self._factors[n][0])
        entries = [self._factors[n][1] for n in kept]
        state["_factors"] = (graph.serialize(), kept, entries, len(self._factors))
        del state["_values"]
        return state

    def __setstate__(self, state: dict) -> None:
        text, kept, entries, n = state.pop("_factors")
        self.__dict__.update(state)
        graph = deserialised(gtsam.NonlinearFactorGraph(), text)
        self._factors = [None] * n
        for i, (at, entry) in enumerate(zip(kept, entries, strict=True)):
            self._factors[at] = (graph.at(i), entry)
        self._values = gtsam.Values()
        for key, value in self._guess.items():
            insert_value(self._values, key, value)

    # ------------------------------------------------------------------- nodes
    def enter(self, key: int, value: np.ndarray) -> None:
        """A node new to iSAM2, at `value`."""
        insert_value(self._values, key, value)
        self._guess[key] = value

    def reenter(self, isam: gtsam.ISAM2, values: dict[int, np.ndarray]) -> None:
        """Those of the nodes `values` holds that iSAM2 lacks, entered again at them (an
        iSAM2 rebuilt of the live factors lacks a node an update took all of those of)."""
        for key, value in values.items():
            if not isam.valueExists(key) and key not in self._guess:
                self.enter(key, value)

    def guess(self, key: int) -> np.ndarray | None:
        """The initial value of a node entered since the last update, else None."""
        return self._guess.get(key)

    def entered(self, kind: str) -> list[int]:
        """The nodes of `kind` (graph.POSE, ...) entered since the last update."""
        return [key for key in self._guess if key_kind(key) == kind]

    def has_nodes(self) -> bool:
        return bool(self._guess)

    def factor_keys(self) -> set[int]:
        """The nodes the pending factors touch."""
        return {key for p in self._factors if p is not None for key in p[0].keys()}  # noqa: SIM118

    def drop_node(self, key: int) -> None:
        if self._values.exists(key):
            self._values.erase(key)
        self._guess.pop(key, None)

    # ----------------------------------------------------------------- factors
    def add(self, factor: gtsam.NonlinearFactor, entry: Entry) -> None:
        if entry.fid is not None:
            self._at[entry.fid] = len(self._factors)
        self._factors.append((factor, entry))

    def has_factor(self, fid: int) -> bool:
        return fid in self._at

    def drop_factor(self, fid: int) -> bool:
        """Take record factor `fid` back out; False if it is not pending."""
        at = self._at.pop(fid, None)
        if at is None:
            return False
        self._factors[at] = None
        return True

    def drop_anchors_of(self, key: int) -> list[Anchored]:
        """Take the pending anchors of object `key` back out; returns them."""
        anchors = []
        for n, pending in enumerate(self._factors):
            entry = None if pending is None else pending[1]
            if entry is not None and entry.anchor is not None and entry.keys[-1] == key:
                self._factors[n] = None
                anchors.append(entry.anchor)
        return anchors

    def remove(self, slots: Iterable[int]) -> None:
        """Factor slots of iSAM2 to remove at the next update."""
        self._removals.extend(slots)

    def renumber(self, slots: dict[int, int]) -> None:
        """iSAM2 was rebuilt with its live slots numbered afresh (old -> new); removals
        of slots that it no longer holds are done."""
        self._removals = [slots[s] for s in self._removals if s in slots]

    # ------------------------------------------------------------------- flush
    def flush(
        self, isam: gtsam.ISAM2, extra: gtsam.NonlinearFactorGraph | None = None
    ) -> list[tuple[int, Entry]] | None:
        """One `ISAM2.update` with everything pending (and the factors of `extra`, which
        hold no record factor or anchor); then empty. Returns the slot each new factor
        got with its entry, or None when there was nothing to do."""
        entries = [p for p in self._factors if p is not None]
        new = gtsam.NonlinearFactorGraph()
        for factor, _ in entries:
            new.push_back(factor)
        filled = [entry for _, entry in entries]
        if extra is not None:
            new.push_back(extra)
            filled.extend(Entry(tuple(extra.at(n).keys())) for n in range(extra.size()))
        if new.size() == 0 and not self._removals:
            return None
        result = isam.update(new, self._values, self._removals)
        slots = list(result.getNewFactorsIndices())
        self._clear()
        return list(zip(slots, filled, strict=True))


class SlotTable:
    """The live factor slots of iSAM2 and what each holds (in the order they were filled),
    with record factor id -> slot for the record's factors among them, and node -> its
    slots, so that finding a node's factors costs its degree, not the live graph's size."""

    def __init__(self) -> None:
        self._entries: dict[int, Entry] = {}
        self._slot_of: dict[int, int] = {}  # fid -> slot
        self._of_key: dict[int, set[int]] = {}  # node key -> its live slots

    def fill(self, filled: Iterable[tuple[int, Entry]]) -> None:
        for slot, entry in filled:
            self._entries[slot] = entry
            if entry.fid is not None:
                self._slot_of[entry.fid] = slot
            for key in entry.keys:
                self._of_key.setdefault(key, set()).add(slot)

    def reset(self, entries: Iterable[Entry]) -> None:
        """A new iSAM2 was given these factors in this order: slots 0, 1, ..."""
        self._entries.clear()
        self._slot_of.clear()
        self._of_key.clear()
        self.fill(enumerate(entries))

    def has_factor(self, fid: int) -> bool:
        return fid in self._slot_of

    def pop_factor(self, fid: int) -> int | None:
        """The slot of record factor `fid`, no longer live; None if it has none."""
        slot = self._slot_of.pop(fid, None)
        if slot is not None and slot in self._entries:
            self._unlink(slot, self._entries.pop(slot))
        return slot

    def keys(self, slot: int) -> tuple[int, ...]:
        return self._entries[slot].keys

    def touching(self, keys: set[int]) -> list[int]:
        """The slots with any of `keys`, in slot order."""
        return sorted({slot for key in keys for slot in self._of_key.get(key, ())})

    def inside(self, keys: set[int]) -> list[int]:
        """The slots with only `keys`, in slot order."""
        return [s for s in self.touching(keys) if keys.issuperset(self._entries[s].keys)]

    def drop(self, slots: Iterable[int]) -> list[Entry]:
        """The slots are no longer live; returns what they held."""
        slots = list(slots)
        dropped = [self._entries.pop(s) for s in slots]
        for slot, entry in zip(slots, dropped, strict=True):
            if entry.fid is not None:
                self._slot_of.pop(entry.fid, None)
            self._unlink(slot, entry)
        return dropped

    def _unlink(self, slot: int, entry: Entry) -> None:
        for key in entry.keys:
            held = self._of_key.get(key)
            if held is not None:
                held.discard(slot)
                if not held:
                    del self._of_key[key]

    def ordered(self) -> list[tuple[int, Entry]]:
        """Every live slot and its entry, by slot."""
        return sorted(self._entries.items())

    def __len__(self) -> int:
        return len(self._entries)


def per_distinct(keys: np.ndarray, f: Callable[[int], np.ndarray]) -> list[np.ndarray]:
    """f(key) for each of `keys`, called once per distinct key (a keyframe's pose or
    marginal, shared by the many nodes retired onto it)."""
    listed = keys.tolist()
    once = {k: f(k) for k in dict.fromkeys(listed)}
    return [once[k] for k in listed]


def deserialised(into: Serialisable, text: str) -> Serialisable:
    """`into` filled from GTSAM's serialisation `text` (what `.serialize()` gave)."""
    into.deserialize(text)
    return into


def slot_factors(isam: gtsam.ISAM2, slots: list[int]) -> gtsam.NonlinearFactorGraph:
    """iSAM2's factors in `slots`, in that order."""
    factors, graph = isam.getFactorsUnsafe(), gtsam.NonlinearFactorGraph()
    for slot in slots:
        graph.push_back(factors.at(slot))
    return graph


def serialised_isam2(isam: gtsam.ISAM2, slots: list[int]) -> tuple[str, str]:
    """iSAM2's factors in `slots` (in that order) and its linearisation point, in GTSAM's
    serialisation (17 significant digits: every double comes back to the last bit)."""
    return slot_factors(isam, slots).serialize(), isam.getLinearizationPoint().serialize()


def isam2(slam: SlamConfig) -> gtsam.ISAM2:
    """An empty iSAM2 with the configured relinearisation and factorisation."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(slam.relinearize_threshold)
    params.relinearizeSkip = slam.relinearize_skip
    params.setFactorization(slam.factorization.upper())
    return gtsam.ISAM2(params)


def rebuilt_isam2(
    isam: gtsam.ISAM2, slots: SlotTable, pending: PendingUpdate, fresh: gtsam.ISAM2
) -> gtsam.ISAM2:
    """`fresh` given `isam`'s live factors (they take slots 0, 1, ..., and `slots` and
    `pending` are renumbered) at its linearisation point: what an update that threw left
    half done made whole again, or the slots of the factors it ever held let go."""
    live = slots.ordered()
    graph = slot_factors(isam, [slot for slot, _ in live])
    point, values = isam.getLinearizationPoint(), gtsam.Values()
    for key in graph.keyVector():
        insert_value(values, key, value_array(point, key))
    fresh.update(graph, values)
    pending.renumber({slot: n for n, (slot, _) in enumerate(live)})
    slots.reset(entry for _, entry in live)
    return fresh


def restore_isam2(isam: gtsam.ISAM2, saved: tuple[str, str]) -> None:
    """A new iSAM2 given what `serialised_isam2` kept: its factors take slots 0, 1, ..."""
    factors, point = saved
    isam.update(
        deserialised(gtsam.NonlinearFactorGraph(), factors), deserialised(gtsam.Values(), point)
    )
