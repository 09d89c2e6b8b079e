"""The incremental back end's state (geometry/incremental.py), in parts with one rule each:

- `PendingUpdate`: what the next iSAM2 update adds (factors, new nodes with their initial
  values) and removes (factor slots). `flush` hands it to `ISAM2.update` and clears it. A
  node entered since the last update is only here: its estimate is its initial value.
- `SlotTable`: what each live iSAM2 factor slot holds (a factor of the record, a retired
  object's anchor, or history folded onto keyframes and rows) and the keys it touches.
- `Retired` / `RetiredObjects` / `RetiredPoses`: nodes folded out of iSAM2, each held
  relative to a keyframe that stays in it (a pose: to both keyframes of its window), as
  rows of arrays, so that many are placed at once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TypeVar

import gtsam
import numpy as np

from agrislam.config import SlamConfig
from agrislam.geometry.batch import insert_value, value_array
from agrislam.geometry.graph import POSE
from agrislam.geometry.noise import gaussian, relative_to_range_bearing
from agrislam.geometry.se2 import between, compose, rotation, wrap_angle

Serialisable = TypeVar("Serialisable", gtsam.NonlinearFactorGraph, gtsam.Values)
PoseLookup = Callable[[np.ndarray], np.ndarray]  # keyframe keys (k,) -> their poses (k, 3)


@dataclass(slots=True)
class Anchored:
    """A retired object: at `z` in keyframe `keyframe`'s frame, `cov` the 2x2 marginal
    covariance of z (from the joint marginal of keyframe and object)."""

    keyframe: int
    z: np.ndarray
    cov: np.ndarray


def anchor_factor(anchor: Anchored, key: int) -> gtsam.NonlinearFactor:
    """The retired object's relative position as a factor between its keyframe and it."""
    bearing, rng, cov_br = relative_to_range_bearing(anchor.z, anchor.cov)
    return gtsam.BearingRangeFactor2D(
        anchor.keyframe, key, gtsam.Rot2(bearing), rng, gaussian(cov_br)
    )


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

    def guess(self, key: int) -> np.ndarray | None:
        """The initial value of a node entered since the last update, else None."""
        return self._guess.get(key)

    def has_nodes(self) -> bool:
        return bool(self._guess)

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
            if entry is not None and entry.anchor is not None and entry.keys[1] == key:
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


class Retired:
    """Nodes folded out of iSAM2, each kept relative to a keyframe that stays in it: row r
    holds node `keys[r]`, its keyframe `keyframes[r]` and `local[r]`, its place in the
    keyframe's frame ((3,) relative pose, or (2,) relative position). Rows stay dense: a
    node that leaves hands its row to the last one."""

    def __init__(self, dim: int) -> None:
        self.dim = dim
        self._row: dict[int, int] = {}
        self._n = 0
        self._columns: dict[str, np.ndarray] = {
            "keys": np.zeros(0, dtype=np.uint64),
            "keyframes": np.zeros(0, dtype=np.uint64),
            "local": np.zeros((0, dim)),
        }

    def __len__(self) -> int:
        return self._n

    def __contains__(self, key: int) -> bool:
        return key in self._row

    def _column(self, name: str) -> np.ndarray:
        return self._columns[name][: self._n]

    @property
    def keys(self) -> np.ndarray:
        return self._column("keys")

    @property
    def keyframes(self) -> np.ndarray:
        return self._column("keyframes")

    @property
    def local(self) -> np.ndarray:
        return self._column("local")

    def rows(self, keys: Iterable[int]) -> np.ndarray:
        """The row of each key, -1 for a node not retired."""
        return np.fromiter((self._row.get(k, -1) for k in keys), dtype=np.intp)

    def row(self, key: int) -> int | None:
        return self._row.get(key)

    def put(self, key: int, keyframe: int, local: np.ndarray, **more: np.ndarray) -> None:
        """Node `key` retires onto `keyframe` at `local` (and the other columns' values)."""
        row = self._row.get(key)
        if row is None:
            row = self._n
            if row == len(self._columns["keys"]):
                for name, column in self._columns.items():
                    grown = np.zeros((max(16, 2 * row), *column.shape[1:]), column.dtype)
                    grown[:row] = column
                    self._columns[name] = grown
            self._row[key] = row
            self._n += 1
        for name, value in {"keys": key, "keyframes": keyframe, "local": local, **more}.items():
            self._columns[name][row] = value

    def remove(self, key: int) -> bool:
        """Node `key` is no longer retired (back in iSAM2, or gone)."""
        row = self._row.pop(key, None)
        if row is None:
            return False
        last = self._n - 1
        if row != last:
            for column in self._columns.values():
                column[row] = column[last]
            self._row[int(self._columns["keys"][row])] = row
        self._n = last
        return True

    def rebase(self, keyframe: int, onto: int, relative: np.ndarray) -> None:
        """Every row on `keyframe` moves onto keyframe `onto`, where `keyframe` stands at
        pose `relative`: its place becomes relative (+) local (a covariance turns along)."""
        rows = self._move_anchor("keyframes", "local", keyframe, onto, relative)
        if "cov" in self._columns:
            turn = rotation(relative[2])
            self._columns["cov"][rows] = turn @ self._columns["cov"][rows] @ turn.T

    def _move_anchor(
        self, anchors: str, places: str, keyframe: int, onto: int, relative: np.ndarray
    ) -> np.ndarray:
        """The rows whose column `anchors` is `keyframe` move onto `onto` (their `places`
        composed onto `relative`); returns those rows."""
        rows = np.flatnonzero(self._column(anchors) == np.uint64(keyframe))
        if len(rows):
            local = self._as_pose(self._columns[places][rows])
            self._columns[places][rows] = compose(relative, local)[: self.dim].T
        self._columns[anchors][rows] = onto
        return rows

    def relocate(self, local: np.ndarray) -> None:
        """Every row's new place relative to its keyframe (rows in order)."""
        self._columns["local"][: self._n] = local

    def _as_pose(self, places: np.ndarray) -> np.ndarray:
        """(3, k) places as poses (a position gets heading 0)."""
        return places.T if self.dim == 3 else np.vstack([places.T, np.zeros(len(places))])

    def _on(self, anchors: np.ndarray, places: np.ndarray, frame: PoseLookup) -> np.ndarray:
        """(k, 3) map-frame poses of `places` on keyframes `anchors`."""
        return compose(frame(anchors).T, self._as_pose(places)).T

    def placed(self, rows: np.ndarray, frame: PoseLookup) -> np.ndarray:
        """(k, dim) map-frame estimates of `rows`, `frame(keyframes)` giving the keyframes'
        poses: keyframe (+) local, at once."""
        return self._on(self.keyframes[rows], self.local[rows], frame)[:, : self.dim]

    def _local_at(self, anchors: np.ndarray, solution: gtsam.Values) -> np.ndarray:
        """(n, dim) every row's place relative to keyframes `anchors`, from `solution`."""
        nodes = self._as_pose(values_at(solution, self.keys, self.dim))
        return between(values_at(solution, anchors, 3).T, nodes)[: self.dim].T

    def relocate_at(self, solution: gtsam.Values) -> None:
        """Every row's place relative to its keyframe, taken from `solution`."""
        self.relocate(self._local_at(self.keyframes, solution))


class RetiredPoses(Retired):
    """Retired poses, each held relative to both keyframes of its window: the one it retired
    onto (`keyframes`, `local`) and the robot's keyframe before it (`starts`, `start_local`),
    and placed between the two by `share`, its share of the distance driven from the start.
    A correction that reaches one end of the window later then moves the poses near that end,
    not the whole window swung about its newest keyframe (issue 13: a rigid tie put the
    window's first poses of an RTK survey 0.044 m off against 0.018 m at the keyframe)."""

    def __init__(self) -> None:
        super().__init__(3)
        self._columns.update(
            starts=np.zeros(0, dtype=np.uint64), start_local=np.zeros((0, 3)), share=np.zeros(0)
        )

    @property
    def starts(self) -> np.ndarray:
        return self._column("starts")

    def put_window(self, keys: list[int], start: int, end: int, point: gtsam.Values) -> None:
        """A window's poses `keys`, in the order driven, between keyframes `start` and `end`
        at the estimates `point` (`start` absent from it: held by `end` alone)."""
        if not point.exists(start):
            start = end
        poses = values_at(point, np.array([start, *keys, end], dtype=np.uint64), 3)
        travelled = np.cumsum(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1))
        if start == end:
            share = np.ones(len(keys))
        elif travelled[-1] > 0.0:
            share = travelled[:-1] / travelled[-1]
        else:  # the robot stood still: by the order of the poses
            share = np.arange(1, len(keys) + 1) / (len(keys) + 1)
        for key, pose, w in zip(keys, poses[1:-1], share.tolist(), strict=True):
            self.put(
                key,
                end,
                between(poses[-1], pose),
                starts=start,
                start_local=between(poses[0], pose),
                share=w,
            )

    def placed(self, rows: np.ndarray, frame: PoseLookup) -> np.ndarray:
        """(k, 3) map-frame poses of `rows`, `frame(keyframes)` giving keyframes' poses:
        positions blended by share, headings turned by share from the start's."""
        share = self._column("share")[rows]
        end = super().placed(rows, frame)
        start = self._on(self.starts[rows], self._column("start_local")[rows], frame)
        xy = share[:, None] * end[:, :2] + (1.0 - share[:, None]) * start[:, :2]
        theta = wrap_angle(start[:, 2] + share * wrap_angle(end[:, 2] - start[:, 2]))
        return np.column_stack([xy, theta])

    def rebase(self, keyframe: int, onto: int, relative: np.ndarray) -> None:
        super().rebase(keyframe, onto, relative)
        self._move_anchor("starts", "start_local", keyframe, onto, relative)

    def relocate_at(self, solution: gtsam.Values) -> None:
        """Every row's places relative to both its keyframes, taken from `solution`."""
        super().relocate_at(solution)
        self._columns["start_local"][: self._n] = self._local_at(self.starts, solution)


@dataclass(slots=True, eq=False)  # hashed by identity
class Deferred:
    """The covariances of retired objects `keys`, from `compute()` when first needed."""

    keys: list[int]
    compute: Callable[[], list[np.ndarray]]


class RetiredObjects(Retired):
    """Retired objects: `local` their position z in the keyframe's frame, `cov[r]` the 2x2
    covariance of z given the keyframe.

    A keyframe fold retires objects at once but may leave their covariances (most of a
    fold's work, issue 14) to be `defer`red: `pace` computes the oldest a step later,
    and every read of a covariance settles what it reads first. The result does not
    depend on when it is computed (a deferred computation holds its own graph and values),
    so the map is the same whether it runs at once, later, or before a checkpoint."""

    def __init__(self) -> None:
        super().__init__(2)
        self._columns["cov"] = np.zeros((0, 2, 2))
        self._deferred: list[Deferred] = []
        self._waiting: dict[int, Deferred] = {}  # key -> what gives its covariance
        self._settled = 0  # computations settled since the last `pace`

    def __getstate__(self) -> dict:
        """Deferred computations hold GTSAM graphs: they are settled before a pickle."""
        self.settle()
        return self.__dict__.copy()

    @property
    def cov(self) -> np.ndarray:
        self.settle()
        return self._column("cov")

    def covariances(self, rows: np.ndarray) -> np.ndarray:
        """(k, 2, 2) the covariances of `rows`, what is deferred among them settled."""
        self._settle_for(self.keys[rows].tolist())
        return self._columns["cov"][rows]

    def defer(self, keys: list[int], compute: Callable[[], list[np.ndarray]]) -> None:
        """Retired objects `keys` get their covariances from `compute()`, later."""
        job = Deferred(keys, compute)
        self._deferred.append(job)
        self._waiting.update(dict.fromkeys(keys, job))

    def settle(self, count: int | None = None) -> None:
        """Compute the oldest `count` deferred covariances (all of them by default)."""
        self._settle_jobs(set(self._deferred[:count]))

    def pace(self) -> None:
        """Once a step: the oldest deferred computation, unless a read since the last
        call settled one already (one fold's work spread over the steps after it)."""
        if not self._settled:
            self.settle(1)
        self._settled = 0

    def _settle_for(self, keys: Iterable[int]) -> None:
        """Compute what the covariances of `keys` wait for, if anything."""
        self._settle_jobs({self._waiting[k] for k in keys if k in self._waiting})

    def _settle_jobs(self, jobs: set[Deferred]) -> None:
        for job in [j for j in self._deferred if j in jobs]:  # in the order deferred
            self._deferred.remove(job)
            self._settled += 1
            for key, cov in zip(job.keys, job.compute(), strict=True):
                if self._waiting.pop(key, None) is job and (row := self._row.get(key)) is not None:
                    self._columns["cov"][row] = cov

    def anchor(self, key: int) -> Anchored | None:
        """A copy of the retired object's anchor, or None if it is not retired."""
        row = self._row.get(key)
        if row is None:
            return None
        self._settle_for([key])
        c = self._columns
        return Anchored(int(c["keyframes"][row]), c["local"][row].copy(), c["cov"][row].copy())

    def pop(self, key: int) -> Anchored | None:
        anchor = self.anchor(key)
        self.remove(key)
        return anchor

    def remove(self, key: int) -> bool:
        """As Retired.remove; a deferred computation nobody waits for any more is dropped."""
        job = self._waiting.pop(key, None)
        if job is not None and not any(k in self._waiting for k in job.keys):
            self._deferred.remove(job)
        return super().remove(key)

    def rebase(self, keyframe: int, onto: int, relative: np.ndarray) -> None:
        self.settle()  # a covariance turns along: it must be there
        super().rebase(keyframe, onto, relative)


def values_at(values: gtsam.Values, keys: np.ndarray, dim: int) -> np.ndarray:
    """(k, dim) the values of `keys` at once: poses (dim 3, POSE keys) or points (dim 2)."""
    pose = ord(POSE)
    stored = np.array(values.keys(), dtype=np.uint64)
    stored = stored[(stored >> np.uint64(56) == pose) == (dim == 3)]
    table = (gtsam.utilities.extractPose2 if dim == 3 else gtsam.utilities.extractPoint2)(values)
    return table.reshape(-1, dim)[np.searchsorted(stored, keys)]


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
