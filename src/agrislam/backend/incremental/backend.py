"""Incremental back end: iSAM2 with keyframes, so that a step costs about the same on a
large field as on a small one (sec. 2.6; DESIGN.md "Geometry back end").

Plain iSAM2 (`slam.window = 0`) re-eliminates, every step, the part of the Bayes tree
between the plants seen again and the root: on a lawnmower survey about one pass of the
field, so a step costs more as the rows get longer (benchmarks/bench_geometry.py). With a
window, every `window` steps the recent part of the graph is folded away:

- each robot's latest pose becomes a *keyframe*; keyframes and row nodes stay in the
  graph (past its share of `slam.keyframes_kept`, a keyframe is folded away too and held
  where it stands: `FrozenKeyframes`);
- every other pose and object of the window is marginalised out of the window's
  factors, exactly at the current linearisation point: what they said about the
  keyframes and rows they touched becomes one dense factor between those;
- an object keeps its position relative to a keyframe (with the marginal covariance of
  that relative position); its estimate moves with the keyframe, so a loop closure
  corrects the whole map the live keyframes hold. Seen again, it comes back into the
  graph tied to that keyframe (on a frozen one: a prior where it stands) and gets its new
  measurements;
- a pose keeps its place relative to both keyframes of its window and moves with each by
  its share of the distance driven between them (`RetiredPoses`).

`refine()` solves the whole recorded graph (the paper's batch solve, warm-started) and
carries on from that solution; call it at the end of a survey, or when time allows.
"""

from __future__ import annotations

import functools
import math

import gtsam
import numpy as np

from agrislam.backend.base import BackendBase
from agrislam.backend.batch import solve
from agrislam.backend.graph import (
    POSE,
    ROW,
    SurveyGraph,
    key_index,
    key_indices,
    key_kind,
    make_factor,
)
from agrislam.backend.incremental.conditioning import (
    components,
    covariances_given,
    indeterminate_key,
    marginalised,
    shared_copy,
    weakly_held,
)
from agrislam.backend.incremental.isam_state import (
    Entry,
    PendingUpdate,
    SlotTable,
    isam2,
    per_distinct,
    rebuilt_isam2,
    restore_isam2,
    serialised_isam2,
)
from agrislam.backend.incremental.marginal_cache import MarginalCache
from agrislam.backend.incremental.refold import refold
from agrislam.backend.incremental.retired import (
    Anchored,
    FrozenKeyframes,
    RetiredObjects,
    RetiredPoses,
)
from agrislam.backend.incremental.sparsify import sparsified
from agrislam.backend.key_table import KeyTable
from agrislam.backend.values import insert_value, pose_array, value_array, values_at
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.drift import adjoint
from agrislam.geometry.se2 import between, compose, pose_uncertainty_at, rotation, to_robot_frame

FOLD_ITERATIONS = 2  # Gauss-Newton iterations on the window before it is folded away
SLOTS_SLACK, SLOTS_FLOOR = 8, 8000  # iSAM2 rebuilt when its slots pass slack x live + floor
# a refine during the survey whose history would fold into a dense factor over more keys,
# or with several robots (the fold ties all their keyframes together), relinearises the
# keyframe graph instead: iSAM2 re-eliminated that factor at every step after (issue 11:
# five robots sharing landmarks, 367 keyframes, 600 ms steps)
REFOLD_MAX_KEYS = 100
NEWEST_EXACT = 3  # per robot, see `_newest`
AGED_PER_FOLD = 2  # per robot: one that joins shrinks the others' share over folds, not in one


class IncrementalBackend(BackendBase):
    """iSAM2 with keyframes every `slam.window` steps; `window = 0` is plain iSAM2.

    Every node is in one place at a time: `_guess` (added, no factor uses it yet), live
    (in iSAM2, or entering it with the `_pending` update), or retired (`_retired_poses`,
    `_retired_objects`: held relative to a keyframe). Keyframes and rows stay live
    (`_permanent`); `_slots` says what each live factor slot of iSAM2 holds."""

    def __init__(self, slam: SlamConfig, rows: RowsConfig) -> None:
        super().__init__(slam, rows)
        self.window = slam.window
        self._isam = isam2(slam)
        self._live: set[int] = set()  # keys in the iSAM2 graph (solved or pending)
        self._permanent: set[int] = set()  # keyframes and row nodes
        self._pending = PendingUpdate()
        self._slots = SlotTable()
        self._guess: dict[int, np.ndarray] = {}  # nodes no factor has used yet
        self._retired_objects = RetiredObjects()
        self._retired_poses = RetiredPoses()  # each pose between its window's keyframes
        self._keyframes: dict[str, list[int]] = {}  # robot -> its keyframes, oldest first
        self._last_seen = KeyTable()  # object key -> the pose it was last seen from
        self._seen_step = KeyTable()  # object key -> the step it was last seen at
        self._marginals = MarginalCache()
        self._step = 0
        self._window_start = 0
        self._folded_heading: dict[int, float] = {}  # keyframe -> heading when folded onto
        self._frozen = FrozenKeyframes()  # aged past `keyframes_kept`
        self._increments: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # latest odometry
        self.rolls = 0

    # -------------------------------------------------------- pickle (checkpoints)
    def __getstate__(self) -> dict:
        """The state to pickle: iSAM2 itself cannot be, so the pending update is solved
        first and iSAM2 is kept as its live factors (in slot order) and linearisation
        point, in GTSAM's own serialisation (exact to the last bit)."""
        self._solve_pending()
        self._retired_objects.settle()
        state = self.__dict__.copy()
        state["_isam"] = serialised_isam2(self._isam, [s for s, _ in self._slots.ordered()])
        return state

    def __setstate__(self, state: dict) -> None:
        """A new iSAM2 of the saved factors at the saved linearisation point; the slots
        are numbered afresh in the saved order."""
        saved = state.pop("_isam")
        self.__dict__.update(state)
        self._isam = isam2(self.slam)
        restore_isam2(self._isam, saved)
        self._slots.reset(entry for _, entry in self._slots.ordered())

    # ------------------------------------------------------------ solver hooks
    def _insert(self, key: int, value: np.ndarray) -> None:
        self._guess[key] = np.asarray(value, dtype=float)
        if key_kind(key) == ROW:
            self._permanent.add(key)  # rows span the field: never folded away

    def add_robot(self, robot: str, start_pose=None, start_sigma=None, t=None) -> None:
        super().add_robot(robot, start_pose, start_sigma, t)
        first = self.graph.robot(robot).keys[0]
        self._permanent.add(first)
        self._keyframes[robot] = [first]

    def load(self, graph: SurveyGraph, values: dict[int, np.ndarray]) -> None:
        super().load(graph, values)
        for robot, chain in graph.robots.items():
            self._permanent.add(chain.keys[0])
            self._keyframes[robot] = [chain.keys[0]]

    def _enter(self, key: int) -> None:
        """Bring a node into the iSAM2 graph: new, or retired and tied to its keyframe."""
        if key in self._live:
            return
        if key in self._guess:
            value = self._guess.pop(key)
        elif (anchor := self._retired_objects.pop(key)) is not None:
            value = compose(self.estimate(anchor.keyframe), np.r_[anchor.z, 0.0])[:2]
            self._push_anchor(key, anchor)
        else:
            raise KeyError(f"node {gtsam.DefaultKeyFormatter(key)} has no estimate to enter with")
        self._pending.enter(key, value)
        self._live.add(key)

    def _push_anchor(self, key: int, anchor: Anchored) -> None:
        factor = self._frozen.anchor_factor(anchor, key)
        self._pending.add(factor, Entry(tuple(factor.keys()), anchor=anchor))

    def _add(self, fid: int) -> None:
        factor = self.graph.factors[fid]
        for key in factor.keys:
            self._enter(key)
        if factor.keys and key_kind(factor.keys[0]) == POSE and len(factor.keys) == 2:
            obj = factor.keys[1]
            if key_kind(obj) != POSE:
                self._last_seen[obj], self._seen_step[obj] = factor.keys[0], self._step
                self._marginals.sighted(obj)
        self._pending.add(make_factor(factor, self.slam), Entry(factor.keys, fid))

    def _remove(self, fid: int) -> None:
        if not self._pending.drop_factor(fid) and (slot := self._slots.pop_factor(fid)) is not None:
            self._pending.remove([slot])

    def _replace(self, old: int, new: int | None) -> None:
        live = self._pending.has_factor(old) or self._slots.has_factor(old)
        self._remove(old)
        if new is not None and live:
            self._add(new)

    def _forget(self, key: int, into: int | None) -> None:
        """Drop a node; merged into `into`, its anchors (or retired position) go along."""
        slots = self._slots.touching({key})
        self._pending.remove(slots)
        anchors = [e.anchor for e in self._slots.drop(slots) if e.anchor is not None]
        anchors += self._pending.drop_anchors_of(key)
        if into is None:
            self._retired_objects.remove(key)  # nothing to carry: its covariance is not needed
        else:
            if (retired := self._retired_objects.pop(key)) is not None:
                anchors.append(retired)
            self._enter(into)
            for anchor in anchors:
                self._push_anchor(into, anchor)
        self._pending.drop_node(key)
        for table in (self._guess, self._last_seen, self._seen_step):
            table.pop(key, None)
        self._marginals.forget(key)
        self._live.discard(key)
        self._permanent.discard(key)

    def estimate(self, key: int) -> np.ndarray:
        guess = self._pending.guess(key)
        if guess is not None:
            return guess
        if key in self._live:
            if key_kind(key) == POSE:
                return pose_array(self._isam.calculateEstimatePose2(key))
            return np.asarray(self._isam.calculateEstimatePoint2(key), dtype=float).ravel()
        if (frozen := self._frozen.pose(key)) is not None:
            return frozen
        for retired in (self._retired_objects, self._retired_poses):
            if (row := retired.row(key)) is not None:
                return retired.placed(np.array([row]), self._frames)[0]
        if key in self._guess:
            return self._guess[key]
        raise KeyError(f"node {gtsam.DefaultKeyFormatter(key)} is not in the graph")

    # ------------------------------------------------------------------ solving
    def update(self) -> bool:
        """One iSAM2 step with this step's factors; every `window` steps, a keyframe (True)."""
        poses = self._pending.entered(POSE)
        self._solve_pending()
        for key in poses:  # read while at the Bayes tree's top (its robot's next frame
            self._marginal_covariance(key)  # carries it, `current_pose_covariance`)
        self._step += 1
        since = self._step - self._window_start
        if not self.window or since < self.window:
            self._retired_objects.pace()  # a fold's deferred covariances, a part a step
            if since == self.window // 2 and self._slots_piled_up():  # half way between folds
                self._rebuild()
            return False
        self._fold()
        if self.slam.refine_turn_deg and self._turned() > math.radians(self.slam.refine_turn_deg):
            alone = len(self._keyframes) == 1  # else its refold ties every robot's keyframes
            self.refine(self.slam.turn_refine_max_factors if alone else 0, REFOLD_MAX_KEYS)
        return True

    def _turned(self) -> float:
        """Largest heading change of a keyframe since history was folded onto it: the
        folded factors are linear in it, so past a few degrees they no longer hold."""
        keys = np.fromiter(self._folded_heading, dtype=np.uint64)
        headings = values_at(self._isam.calculateEstimate(), keys, 3)[:, 2]  # all at once
        folded = np.fromiter(self._folded_heading.values(), dtype=float)
        turned = np.remainder(headings - folded + np.pi, math.tau) - np.pi
        return float(np.max(np.abs(turned), initial=0.0))

    def _solve_pending(self, extra: gtsam.NonlinearFactorGraph | None = None) -> None:
        """One iSAM2 update with what is pending (and `extra`'s factors)."""
        try:
            filled = self._pending.flush(self._isam, extra)
        except RuntimeError as err:
            filled = self._isolate(err, extra)
        if filled is not None:
            self._slots.fill(filled)
            for _, entry in filled:  # what the update measured is read again
                self._marginals.measured(entry.keys)

    def _isolate(
        self, err: RuntimeError, extra: gtsam.NonlinearFactorGraph | None, fold: bool = True
    ) -> list[tuple[int, Entry]] | None:
        """Indeterminate near a node (a row without members): iSAM2 rebuilt, the node weakly held,
        the update again (issue 12); failing again, a fold's marginal gives way to weak priors."""
        key = indeterminate_key(err)
        if key is None or key not in self._live:  # (entered nodes are live already)
            raise err
        keys = {key} | self._pending.factor_keys() | set(extra.keyVector() if extra else [])
        known = {k: self.estimate(k) for k in keys}  # read before the rebuild drops any
        self._rebuild()
        self._pending.reenter(self._isam, known)
        held = weakly_held({key: known[key]})
        held.push_back(extra if extra is not None else gtsam.NonlinearFactorGraph())
        kind = {POSE: "pose", ROW: "row"}.get(key_kind(key), "object")
        self.issues[f"{kind} held by a weak prior: indeterminate in an iSAM2 update"] += 1
        try:
            return self._pending.flush(self._isam, held)
        except RuntimeError as again:
            if extra is None or not fold:
                raise
            self.issues["a fold's marginal given up: indeterminate in an iSAM2 update"] += 1
            instead = weakly_held({k: known[k] for k in extra.keyVector()})
            return self._isolate(again, instead, fold=False)

    def _slots_piled_up(self) -> bool:
        """iSAM2 keeps a slot for every factor it ever held (issue 14): past slack x live
        + floor, a rebuild lets them go."""
        return self._isam.getFactorsUnsafe().size() > SLOTS_SLACK * len(self._slots) + SLOTS_FLOOR

    def _rebuild(self) -> None:
        """A fresh iSAM2 of the live factors at the same linearisation point."""
        self._isam = rebuilt_isam2(self._isam, self._slots, self._pending, isam2(self.slam))
        self._marginals.clear()

    def _fold(self) -> None:
        """Keyframe each robot's latest pose; marginalise the rest of the window out (and
        the keyframes beyond `keyframes_kept`, frozen where they stand)."""
        starts = {}  # robot -> the keyframe its window starts at
        for robot, chain in self.graph.robots.items():
            latest = chain.keys[-1]
            if latest not in self._permanent:
                starts[robot] = self._keyframes[robot][-1]
                self._permanent.add(latest)
                self._keyframes[robot].append(latest)
        aged = self._aged_keyframes()
        window = (self._live - self._permanent) | aged
        if window:
            self._converge()
            self._freeze(aged)
            slots = self._slots.touching(window)
            factors = self._isam.getFactorsUnsafe()
            graph, point = gtsam.NonlinearFactorGraph(), gtsam.Values()
            for slot in slots:
                graph.push_back(factors.at(slot))
                for key in self._slots.keys(slot):
                    if not point.exists(key):
                        insert_value(point, key, self.estimate(key))
            self._retire(window, graph, point, starts)
            marginal = marginalised(graph, point, window, self.issues)
            marginal = sparsified(marginal, point, self._newest(), self.issues)
            for key in marginal.keyVector():
                if key_kind(key) == POSE and key not in self._folded_heading:
                    self._folded_heading[key] = point.atPose2(key).theta()
            self._slots.drop(slots)
            self._pending.remove(slots)
            self._live -= window
            for key in window:  # a live node's alone (it grew with the field)
                self._marginals.drop(key)
            self._solve_pending(marginal)
        self._window_start = self._step
        self.rolls += 1

    def _newest(self) -> set[int]:
        """Each robot's NEWEST_EXACT newest keyframes: a fold's marginal keeps their joint
        exact (backend/incremental/sparsify.py); the current poses and objects hang from them."""
        return {k for frames in self._keyframes.values() for k in frames[-NEWEST_EXACT:]}

    def _aged_keyframes(self) -> set[int]:
        """Keyframes past each robot's newest share of `keyframes_kept`, at most
        `keyframes_per_robot` (the first stays), out of the permanent set and the robot's
        list. Shared: a fold ties the keyframes of robots that saw one landmark; five
        keeping 100 each grew one Bayes tree (issue 11). Capped: with a lone robot's 100, a
        keyframe's marginal read cost ten times, an object's four times what it does with
        30 at 10,000 plants (issue 14)."""
        aged: set[int] = set()
        if not (kept := self.slam.keyframes_kept):
            return aged
        kept = max(min(kept // max(len(self._keyframes), 1), self.slam.keyframes_per_robot), 1)
        for robot, frames in self._keyframes.items():
            old = frames[1:-kept][:AGED_PER_FOLD] if len(frames) > kept + 1 else []
            self._keyframes[robot] = frames[:1] + frames[len(old) + 1 :]
            aged.update(old)
        self._permanent -= aged
        return aged

    def _freeze(self, aged: set[int]) -> None:
        """Aged keyframes are held where they stand, with their marginal covariance: what
        hangs on them stays there (moved onto a newer keyframe, a far plant would swing
        with its heading)."""
        for keyframe in aged:
            cov = self._isam.marginalCovariance(keyframe)
            self._frozen.freeze(keyframe, self.estimate(keyframe), cov)
            self._folded_heading.pop(keyframe, None)

    def _converge(self) -> None:
        """Gauss-Newton iterations relinearising everything that moved more than the
        threshold: what is folded away keeps the linearisation it has then."""
        params = gtsam.ISAM2UpdateParams()
        params.force_relinearize = True
        for _ in range(FOLD_ITERATIONS):
            self._isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), params)

    def _retire(
        self,
        window: set[int],
        graph: gtsam.NonlinearFactorGraph,
        point: gtsam.Values,
        starts: dict[str, int],
    ) -> None:
        """Every window node keeps its place relative to keyframes of its robot: poses
        their relative poses to both ends of their window (`starts` to the newest), objects
        their relative position and its covariance given the keyframe (from the window's
        factors and those among the nodes they touch)."""
        half = (self._window_start + self._step) / 2
        anchored: dict[int, list[int]] = {}
        driven: dict[str, list[int]] = {}
        for key in window:
            if key in self._frozen:
                continue
            if key_kind(key) == POSE:
                driven.setdefault(self.graph.robot_of(key), []).append(key)
                continue
            pose, step = self._last_seen.get(key), self._seen_step.get(key, self._step)
            frames = self._keyframes[
                self.graph.robot_of(pose) if pose else next(iter(self._keyframes))
            ]
            keyframe = frames[-2] if step < half and len(frames) > 1 else frames[-1]
            if not point.exists(keyframe):
                keyframe = frames[-1]
            anchored.setdefault(keyframe, []).append(key)
        for robot, keys in driven.items():
            end = self._keyframes[robot][-1]
            start = starts.get(robot, end)
            keys.sort()  # a robot's pose keys count up in the order driven
            self._retired_poses.put_window(keys, start, end, point)
        blanket = [k for k in point.keys() if k not in window]  # noqa: SIM118
        # with the factors already among the blanket's nodes (odometry between keyframes,
        # row spacing): an object seen from two keyframes is known given either
        around = shared_copy(graph)
        factors = self._isam.getFactorsUnsafe()
        for slot in self._slots.inside(set(blanket)):
            around.push_back(factors.at(slot))
        parts = functools.cache(lambda: components(around))
        for keyframe, keys in anchored.items():
            kf_pose = value_array(point, keyframe)
            for key in keys:
                z = to_robot_frame(kf_pose, value_array(point, key))
                self._retired_objects.put(key, keyframe, z, cov=np.full((2, 2), np.nan))
            # the covariances (most of a fold's work) are computed a step later (issue 14)
            given = functools.partial(
                covariances_given, keyframe, keys, parts, point, blanket, self.issues
            )
            self._retired_objects.defer(keys, given)

    def refine(self, max_factors: int | None = None, max_keys: int = 0) -> None:
        """Solve the whole recorded graph (batch, warm-started from the current estimates)
        and carry on from that solution: with keyframes, the whole history is folded onto
        them again, exactly at the solution; with more than `max_factors` factors
        (`slam.refine_max_factors` by default), or a history that would fold into a factor
        over more than `max_keys` (if given), only the keyframe graph is relinearised."""
        self._solve_pending()
        if self.window:
            self._fold()  # the current window retires too: only keyframes and rows live
            limit = self.slam.refine_max_factors if max_factors is None else max_factors
            if len(self.graph.factors) > limit:
                self._refine_folded()
                return
        graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for factor in self.graph.factors.values():
            graph.push_back(make_factor(factor, self.slam))
            for key in factor.keys:
                if not initial.exists(key):
                    insert_value(initial, key, self.estimate(key))
        try:
            solution = solve(graph, initial, self.slam)
            fresh = isam2(self.slam)
            if not self.window:
                fresh.update(graph, solution)
            elif not self._refold(solution, fresh, graph, max_keys):
                self._refine_folded()
                return
        except RuntimeError as err:  # degenerate: carry on from the incremental estimate
            self.issues[f"refine skipped: {str(err).strip().splitlines()[0]}"] += 1
            return
        self._isam = fresh
        self._marginals.clear()
        self.refines += 1
        self.whole_refine = self.refines
        if not self.window:
            self._slots.reset(Entry(f.keys, fid) for fid, f in self.graph.factors.items())
            return
        self._retired_poses.relocate_at(solution)
        self._retired_objects.relocate_at(solution)
        self._frozen.moved_to(solution)

    def _refine_folded(self) -> None:
        """A graph too large for one batch: Gauss-Newton on the keyframe graph the history
        is folded onto (bounded by the keyframes, not the plants); the headings the folded
        factors were linearised at are taken as they are now."""
        self._converge()
        self._marginals.clear()
        self._folded_heading = {k: self.estimate(k)[2] for k in self._folded_heading}
        self.refines += 1

    def _refold(
        self,
        solution: gtsam.Values,
        fresh: gtsam.ISAM2,
        graph: gtsam.NonlinearFactorGraph,
        max_keys: int = 0,
    ) -> bool:
        """Live graph (in `fresh`) = keyframes and rows with the whole history folded onto
        them at `solution` (refold.py); `graph` holds the record's factors, built once, in
        its order. False (nothing done) if a folded factor would have over `max_keys` keys."""
        out = refold(self.graph, graph, solution, self._permanent)
        if max_keys and out.widest > max_keys:
            return False
        values = gtsam.Values()
        for key in self._live:
            insert_value(values, key, value_array(solution, key))
        fresh.update(out.graph, values)  # may raise: nothing of this back end has changed yet
        self._slots.reset(Entry(tuple(out.graph.at(n).keys()), f) for n, f in enumerate(out.fids))
        self._folded_heading = {
            k: solution.atPose2(k).theta() for k in out.folded if key_kind(k) == POSE
        }
        return True

    # ---------------------------------------------------------------- queries
    def add_odometry(self, robot: str, t: float, delta: np.ndarray, cov: np.ndarray) -> None:
        super().add_odometry(robot, t, delta, cov)
        self._increments[robot] = (np.asarray(delta, dtype=float), np.asarray(cov, dtype=float))

    def current_pose_covariance(self, robot: str) -> np.ndarray:
        """(3, 3) marginal covariance of the robot's latest pose (x, y, theta, in its own
        frame as GTSAM's). A pose only just added, whose one factor is its odometry, has
        the previous pose's carried through the increment: Ad(d^-1) S Ad(d^-1)^T + Q,
        which spares an iSAM2 update before the frame's own."""
        keys = self.graph.robot(robot).keys
        pending = self._pending.guess
        if len(keys) > 1 and pending(keys[-1]) is not None and pending(keys[-2]) is None:
            delta, cov = self._increments[robot]
            carry = adjoint(between(delta, np.zeros(3)))
            return carry @ self._marginal_covariance(keys[-2]) @ carry.T + cov
        if self._pending.has_nodes():
            self._solve_pending()
        return self._marginal_covariance(keys[-1])

    def _marginal_covariance(self, key: int) -> np.ndarray:
        """A node's marginal covariance, read again from iSAM2 (a Bayes-tree traversal)
        once each robot has taken `slam.covariance_reuse_steps` steps since it was read
        (ten times as many for a pose or an object not seen since; robots share the step
        count: five reading every ten steps would each read every other frame, a cost
        growing with the robots, issue 11) or a new factor touched it (marginal_cache.py)."""
        if (frozen := self._frozen.covariance(key)) is not None:
            return frozen
        return self._marginals.get(key, self._step, self._reuse, self._isam.marginalCovariance)

    @property
    def _reuse(self) -> int:
        return self.slam.covariance_reuse_steps * max(len(self.graph.robots), 1)

    def _frames(self, keyframes: np.ndarray) -> np.ndarray:
        """(k, 3) current pose of each of `keyframes`, each distinct one read once."""
        return np.array(per_distinct(keyframes, self.estimate)).reshape(-1, 3)

    def _split(
        self, keys: list[int], retired: RetiredObjects | RetiredPoses
    ) -> tuple[np.ndarray, list[int]]:
        """The retired row of each node (-1: live) and the keys of the live ones."""
        rows = retired.rows(keys)
        return rows, [k for k, r in zip(keys, rows.tolist(), strict=True) if r < 0]

    def settled_objects(self) -> np.ndarray:
        objects = self._retired_objects
        return key_indices(objects.keys[np.isin(objects.keyframes, self._frozen.keys())])

    def object_positions(self, object_ids: np.ndarray) -> np.ndarray:
        """(k, 2) current estimates; a retired object's is its keyframe's pose (+) z, all
        at once (a snapshot of a large map asks for every object)."""
        return self._placed(self.graph.require_objects(object_ids), self._retired_objects, 2)

    def trajectory(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """Times and (m, 3) poses of the robot; its retired poses placed all at once."""
        chain = self.graph.robot(robot)
        return np.array(chain.times), self._placed(chain.keys, self._retired_poses, 3)

    def _placed(self, keys: list[int], retired: RetiredObjects | RetiredPoses, dim: int):
        """(k, dim) estimates of `keys`: the live ones each, the retired placed at once."""
        rows, live = self._split(keys, retired)
        out = np.empty((len(keys), dim))
        out[rows < 0] = np.array([self.estimate(k) for k in live]).reshape(-1, dim)
        out[rows >= 0] = retired.placed(rows[rows >= 0], self._frames)
        return out

    def object_covariances(self, object_ids: np.ndarray) -> np.ndarray:
        """(k, 2, 2) marginal covariances of the given objects, cached until the next step;
        a retired object's combines its keyframe's and its relative position's."""
        keys = self.graph.require_objects(object_ids)
        if any(self._pending.guess(key) is not None for key in keys):
            self._solve_pending()  # entered since the last update (a merge): solve them now
        rows, live = self._split(keys, self._retired_objects)
        retired, rows = rows >= 0, rows[rows >= 0]
        out = np.empty((len(object_ids), 2, 2))
        if unseen := [key for key in live if key in self._guess]:
            raise ValueError(f"object {key_index(unseen[0])} has no observation yet")
        keyframes = self._retired_objects.keyframes[rows]
        in_isam = [k for k in live + keyframes.tolist() if k not in self._frozen]
        self._marginals.read_jointly(in_isam, self._step, self._reuse, self._isam)
        out[~retired] = np.array([self._marginal_covariance(k) for k in live]).reshape(-1, 2, 2)
        if len(rows):
            objects = self._retired_objects
            z = objects.local[rows]
            frames = self._frames(keyframes)
            cov_k = np.stack(per_distinct(keyframes, self._marginal_covariance))
            rot = rotation(frames[:, 2])  # l = K (+) z: the keyframe's part and z's
            given = rot @ objects.covariances(rows) @ np.swapaxes(rot, 1, 2)
            out[retired] = pose_uncertainty_at(frames, cov_k, z) + given
        return out

    def live_size(self) -> int:
        return len(self._live)
