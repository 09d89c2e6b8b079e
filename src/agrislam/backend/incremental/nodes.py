"""Every node of the incremental back end in one table: the state it is in, and what holds
its value there (backend/incremental/backend.py draws the life cycle).

- NEW: added, no factor has used it yet; its value is the one it was added with.
- LIVE: in iSAM2, or entering it with the pending update; iSAM2 holds its value.
- RETIRED: folded out of iSAM2, held relative to a keyframe (retired.py's arrays).
- FROZEN: a keyframe aged out of iSAM2, held where it stood with its covariance; the
  newest keyframe of an idle robot that drives again thaws, live again.

Keyframes and rows carry a flag, *kept*: a fold leaves them live. The table changes a
node's state only in its transitions below.
"""

from __future__ import annotations

from collections.abc import Callable, Collection

import gtsam
import numpy as np

from agrislam.backend.graph import POSE, key_kind
from agrislam.backend.incremental.retired import (
    Anchored,
    FrozenKeyframes,
    PoseLookup,
    RetiredObjects,
    RetiredPoses,
)
from agrislam.backend.key_table import KeyTable

NEW, LIVE, RETIRED, FROZEN = "new", "live", "retired", "frozen"
STATES = (NEW, LIVE, RETIRED, FROZEN)  # a node's state is stored as its place here
_CODE = {state: code for code, state in enumerate(STATES)}


class NodeTable:
    """key -> state, with the values of the new nodes, the retired and frozen stores, each
    robot's keyframes (oldest first) and where each object was last seen from."""

    def __init__(self) -> None:
        self._state = KeyTable()  # key -> its state's code
        # the live and the kept keys are sets too: a fold walks the live graph, not the field
        self._live: set[int] = set()
        self._kept: set[int] = set()
        self._guess: dict[int, np.ndarray] = {}  # new nodes' values
        self.retired_objects = RetiredObjects()
        self.retired_poses = RetiredPoses()  # each pose between its window's keyframes
        self.frozen = FrozenKeyframes()
        self._keyframes: dict[str, list[int]] = {}  # robot -> its kept keyframes
        self._last_seen = KeyTable()  # object key -> the pose it was last seen from
        self._seen_step = KeyTable()  # object key -> the step it was last seen at

    # ------------------------------------------------------------------- reads
    def state(self, key: int) -> str | None:
        """NEW, LIVE, RETIRED or FROZEN; None for a node the back end does not hold."""
        code = self._state.get(key)
        return None if code is None else STATES[code]

    def keys(self, state: str) -> np.ndarray:
        """(k,) the keys of the nodes in `state`."""
        if state == NEW:
            return np.fromiter(self._guess, dtype=np.uint64, count=len(self._guess))
        if state == LIVE:
            return np.fromiter(self._live, dtype=np.uint64, count=len(self._live))
        if state == RETIRED:
            return np.concatenate([self.retired_objects.keys, self.retired_poses.keys])
        return self.frozen.keys()

    def live(self) -> set[int]:
        """The live keys (read only)."""
        return self._live

    def kept(self) -> set[int]:
        """The keyframes and rows (read only): a fold leaves them live."""
        return self._kept

    def is_kept(self, key: int) -> bool:
        return key in self._kept

    def guess(self, key: int) -> np.ndarray:
        """The value a new node was added with."""
        return self._guess[key]

    def keyframes(self, robot: str) -> list[int]:
        """The robot's kept keyframes, oldest first (read only)."""
        return self._keyframes[robot]

    def holding(self) -> list[str]:
        """The robots that hold keyframes (an idle one gives them all up, `age`)."""
        return [robot for robot, frames in self._keyframes.items() if frames]

    def newest_keyframes(self, count: int) -> set[int]:
        """Each robot's `count` newest keyframes."""
        return {k for frames in self._keyframes.values() for k in frames[-count:]}

    def last_seen(self, key: int) -> tuple[int | None, int | None]:
        """The pose object `key` was last seen from and the step then (None: never)."""
        return self._last_seen.get(key), self._seen_step.get(key)

    def placed(self, key: int, frames: PoseLookup) -> np.ndarray:
        """A retired node's estimate: its keyframes' poses (`frames`) and its place on them."""
        retired = self.retired_poses if key_kind(key) == POSE else self.retired_objects
        return retired.placed(np.array([retired.row(key)]), frames)[0]

    def anchor_keyframes(self) -> np.ndarray:
        """(k,) the keyframe each retired node is held relative to."""
        return np.concatenate([self.retired_objects.keyframes, self.retired_poses.keyframes])

    # ------------------------------------------------------------- transitions
    def add(self, key: int, value: np.ndarray, kept: bool = False) -> None:
        """A node, new, at `value`; `kept`: a row."""
        self._guess[key] = np.asarray(value, dtype=float)
        self._state[key] = _CODE[NEW]
        if kept:
            self._kept.add(key)

    def add_keyframe(self, robot: str, key: int) -> None:
        """The robot's pose `key` becomes its newest keyframe: kept."""
        self._kept.add(key)
        self._keyframes.setdefault(robot, []).append(key)

    def sighted(self, key: int, pose: int, step: int) -> None:
        """Object `key` seen from `pose` at `step`."""
        self._last_seen[key], self._seen_step[key] = pose, step

    def enter(self, key: int) -> np.ndarray | Anchored | None:
        """Node `key` becomes live. Returns what held it: a new node's value or a retired
        object's anchor (None: live already)."""
        state = self.state(key)
        if state == LIVE:
            return None
        held: np.ndarray | Anchored | None = None
        if state == NEW:
            held = self._guess.pop(key)
        elif state == RETIRED:
            held = self.retired_objects.pop(key)
        if held is None:
            raise KeyError(f"node {gtsam.DefaultKeyFormatter(key)} has no estimate to enter with")
        self._state[key] = _CODE[LIVE]
        self._live.add(key)
        return held

    def age(self, kept: int, per_fold: int, idle: Collection[str] = ()) -> set[int]:
        """Each robot's keyframes past its newest `kept`, at most `per_fold` of them (the
        first keyframe stays); an `idle` robot's oldest `per_fold`, the first and the newest
        in their turn: no longer kept, nor listed. Returns them."""
        aged: set[int] = set()
        for robot, frames in self._keyframes.items():
            if robot in idle:
                old, self._keyframes[robot] = frames[:per_fold], frames[per_fold:]
            else:
                old = frames[1:-kept][:per_fold] if len(frames) > kept + 1 else []
                self._keyframes[robot] = frames[:1] + frames[len(old) + 1 :]
            aged.update(old)
        self._kept -= aged
        return aged

    def window(self, aged: set[int]) -> set[int]:
        """What a fold takes out of iSAM2: the live nodes but the kept ones, and `aged`."""
        return (self._live - self._kept) | aged

    def freeze(self, key: int, pose: np.ndarray, cov: np.ndarray) -> None:
        """Aged keyframe `key` is held at `pose` with marginal covariance `cov` (`left`
        follows)."""
        self.frozen.freeze(key, pose, cov)
        self._state[key] = _CODE[FROZEN]

    def thaw(self, key: int, robot: str) -> tuple[np.ndarray, gtsam.NonlinearFactor]:
        """Frozen keyframe `key`, the newest of an idle robot that drives again, is live and
        kept again, its robot's keyframe. Returns its pose and the prior that holds it where
        it stood (what hangs on it follows it from now on)."""
        pose, prior = self.frozen.thaw(key)
        self._state[key] = _CODE[LIVE]
        self._live.add(key)
        self.add_keyframe(robot, key)
        return pose, prior

    def retire_object(self, key: int, keyframe: int, z: np.ndarray) -> None:
        """Object `key` of the window is held at `z` in `keyframe`'s frame (its covariance
        to come, `defer`; `left` follows)."""
        self.retired_objects.put(key, keyframe, z, cov=np.full((2, 2), np.nan))
        self._state[key] = _CODE[RETIRED]

    def defer(self, keys: list[int], compute: Callable[[], list[np.ndarray]]) -> None:
        """Retired objects `keys` get their covariances given their keyframe from
        `compute()`, later."""
        self.retired_objects.defer(keys, compute)

    def retire_poses(self, keys: list[int], start: int, end: int, point: gtsam.Values) -> None:
        """A window's poses `keys`, in the order driven, held between keyframes `start`
        and `end` (retired.RetiredPoses.put_window; `left` follows)."""
        self.retired_poses.put_window(keys, start, end, point)
        self._state.put_many(np.array(keys, dtype=np.uint64), _CODE[RETIRED])

    def left(self, window: set[int]) -> None:
        """The fold's `window` has left iSAM2, each node retired or frozen by now. The live
        set loses them in one operation: the order a set is walked in depends on how it
        was changed, and a fold's arithmetic follows that order."""
        self._live -= window

    def take_anchor(self, key: int) -> Anchored | None:
        """A retired object merged into another: its anchor, to carry over (None: not
        retired). `forget` follows."""
        return self.retired_objects.pop(key)

    def forget(self, key: int) -> None:
        """Node `key` is gone (merged, pruned, a row removed)."""
        self.retired_objects.remove(key)
        for table in (self._guess, self._last_seen, self._seen_step):
            table.pop(key, None)
        self._live.discard(key)
        self._kept.discard(key)
        self._state.pop(key, None)

    def moved_to(self, solution: gtsam.Values) -> None:
        """A refine's `solution`: every retired node's place on its keyframes, and every
        frozen keyframe's pose, taken from it."""
        self.retired_poses.relocate_at(solution)
        self.retired_objects.relocate_at(solution)
        self.frozen.moved_to(solution)
