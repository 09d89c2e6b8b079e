r"""Incremental back end: iSAM2 with keyframes, so that a step costs about the same on a
large field as on a small one (sec. 2.6).

Plain iSAM2 (`slam.window = 0`) re-eliminates, every step, the part of the Bayes tree
between the plants seen again and the root: on a lawnmower survey about one pass of the
field. With a window, every `window` steps the recent part of the graph is folded away
(fold.py): each robot's latest pose becomes a keyframe, and every other pose and object of
the window is marginalised out onto the keyframes and rows it touched, exactly at the
current linearisation point. What it held stays relative to a keyframe, so a loop closure
that moves the keyframes moves the map with them.

Every node is in one state at a time (nodes.py holds them all):

                  a factor uses it            fold                    seen again
    add --> new -------------------> live ---------> retired (object) ----------> live
                                      |  \--------> retired (pose): moves with the
                                      |             two keyframes of its window
                                      |  keyframe (kept)   aged past keyframes_kept
                                      \----------------------------------------> frozen

    any node --(merged, pruned, a row removed)--> forgotten

new: its value is the one it was added with. live: in iSAM2 (or entering with the pending
update); keyframes and rows are kept live by every fold. retired: held relative to a
keyframe; an object seen again comes back tied to it (on a frozen keyframe: a prior where
it stands). frozen: an aged keyframe held where it stood, with what hangs on it. With more
robots than half of `slam.keyframes_kept`, an idle robot's keyframes all age; its newest
thaws, live again and held by a prior where it stood, when the robot drives on.

`refine()` solves the whole recorded graph and carries on from that solution (refine.py);
queries.py answers positions and covariances, live.py keeps iSAM2 and what feeds it.
"""

from __future__ import annotations

import gtsam
import numpy as np

from agrislam.backend.base import BackendBase
from agrislam.backend.graph import POSE, ROW, SurveyGraph, key_kind, make_factor
from agrislam.backend.incremental.fold import Folding
from agrislam.backend.incremental.isam_state import (
    Entry,
    PendingUpdate,
    SlotTable,
    isam2,
    restore_isam2,
    serialised_isam2,
)
from agrislam.backend.incremental.live import LiveGraph
from agrislam.backend.incremental.marginal_cache import MarginalCache
from agrislam.backend.incremental.nodes import FROZEN, LIVE, NEW, RETIRED, NodeTable
from agrislam.backend.incremental.queries import Queries
from agrislam.backend.incremental.refine import Refining
from agrislam.backend.incremental.retired import Anchored
from agrislam.backend.values import pose_array
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.se2 import compose


class IncrementalBackend(Folding, Refining, Queries, LiveGraph, BackendBase):
    """iSAM2 with keyframes every `slam.window` steps; `window = 0` is plain iSAM2.

    Here: the state, each node's life cycle (the module docstring) and the step. The parts
    it is made of: the fold (fold.py), refine (refine.py), queries (queries.py) and iSAM2
    with what feeds it (live.py)."""

    def __init__(self, slam: SlamConfig, rows: RowsConfig) -> None:
        super().__init__(slam, rows)
        self.window = slam.window
        self._nodes = NodeTable()
        self._isam = isam2(slam)
        self._pending = PendingUpdate()
        self._slots = SlotTable()  # what each live factor slot of iSAM2 holds
        self._marginals = MarginalCache()
        self._step = 0
        self._window_start = 0
        self._folded_heading: dict[int, float] = {}  # keyframe -> heading when folded onto
        self._increments: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # latest odometry

    # -------------------------------------------------------- pickle (checkpoints)
    def __getstate__(self) -> dict:
        """The state to pickle: iSAM2 itself cannot be, so the pending update is solved
        first and iSAM2 is kept as its live factors (in slot order) and linearisation
        point, in GTSAM's own serialisation (exact to the last bit)."""
        self._solve_pending()
        self._nodes.retired_objects.settle()
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

    # ------------------------------------------------------- node life cycle
    def _insert(self, key: int, value: np.ndarray) -> None:
        self._nodes.add(key, value, kept=key_kind(key) == ROW)  # rows span the field

    def add_robot(self, robot: str, start_pose=None, start_sigma=None, t=None) -> None:
        super().add_robot(robot, start_pose, start_sigma, t)
        self._nodes.add_keyframe(robot, self.graph.robot(robot).keys[0])

    def load(self, graph: SurveyGraph, values: dict[int, np.ndarray]) -> None:
        super().load(graph, values)
        for robot, chain in graph.robots.items():
            self._nodes.add_keyframe(robot, chain.keys[0])

    def add_odometry(self, robot: str, t: float, delta: np.ndarray, cov: np.ndarray) -> None:
        super().add_odometry(robot, t, delta, cov)
        self._increments[robot] = (np.asarray(delta, dtype=float), np.asarray(cov, dtype=float))

    def _enter(self, key: int) -> None:
        """Bring a node into the iSAM2 graph: new, retired and tied to its keyframe, or the
        frozen newest keyframe of an idle robot, held where it stood."""
        if self._nodes.state(key) == FROZEN:
            pose, prior = self._nodes.thaw(key, self.graph.robot_of(key))
            self._pending.enter(key, pose)
            self._pending.add(prior, Entry((key,)))
            return
        held = self._nodes.enter(key)
        if held is None:
            return
        if isinstance(held, Anchored):
            value = compose(self.estimate(held.keyframe), np.r_[held.z, 0.0])[:2]
            self._push_anchor(key, held)
        else:
            value = held
        self._pending.enter(key, value)

    def _push_anchor(self, key: int, anchor: Anchored) -> None:
        factor = self._nodes.frozen.anchor_factor(anchor, key)
        self._pending.add(factor, Entry(tuple(factor.keys()), anchor=anchor))

    def _add(self, fid: int) -> None:
        factor = self.graph.factors[fid]
        for key in factor.keys:
            self._enter(key)
        if factor.keys and key_kind(factor.keys[0]) == POSE and len(factor.keys) == 2:
            obj = factor.keys[1]
            if key_kind(obj) != POSE:
                self._nodes.sighted(obj, factor.keys[0], self._step)
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
        if into is not None:
            if (retired := self._nodes.take_anchor(key)) is not None:
                anchors.append(retired)
            self._enter(into)
            for anchor in anchors:
                self._push_anchor(into, anchor)
        self._pending.drop_node(key)
        self._marginals.forget(key)
        self._nodes.forget(key)

    def estimate(self, key: int) -> np.ndarray:
        state = self._nodes.state(key)
        if state == LIVE:
            guess = self._pending.guess(key)
            if guess is not None:
                return guess
            if key_kind(key) == POSE:
                return pose_array(self._isam.calculateEstimatePose2(key))
            return np.asarray(self._isam.calculateEstimatePoint2(key), dtype=float).ravel()
        if state == FROZEN:
            return self._nodes.frozen.pose(key)
        if state == RETIRED:
            return self._nodes.placed(key, self._frames)
        if state == NEW:
            return self._nodes.guess(key)
        raise KeyError(f"node {gtsam.DefaultKeyFormatter(key)} is not in the graph")

    # ------------------------------------------------------------------ the step
    def update(self) -> bool:
        """One iSAM2 step with this step's factors; every `window` steps, a fold (True)."""
        poses = self._pending.entered(POSE)
        self._solve_pending()
        for key in poses:  # read while at the Bayes tree's top (its robot's next frame
            self._marginal_covariance(key)  # carries it, `current_pose_covariance`)
        self._step += 1
        since = self._step - self._window_start
        if not self.window or since < self.window:
            self._nodes.retired_objects.pace()  # a fold's deferred covariances, a part a step
            if since == self.window // 2 and self._slots_piled_up():  # half way between folds
                self._rebuild()
            return False
        self._fold()
        self._refine_if_turned()
        return True

    # --------------------------------------------------- read-only views (checks)
    def node_state(self, key: int) -> str | None:
        """ "new", "live", "retired" or "frozen" (nodes.py); None: not in the graph."""
        return self._nodes.state(key)

    def node_keys(self, state: str) -> np.ndarray:
        """(k,) the keys of the nodes in `state`."""
        return self._nodes.keys(state)

    def keyframes(self, robot: str) -> list[int]:
        """The robot's kept keyframes, oldest first."""
        return list(self._nodes.keyframes(robot))

    def anchor_keyframes(self) -> np.ndarray:
        """(k,) the keyframe each retired node is held relative to."""
        return self._nodes.anchor_keyframes()

    def anchor_of(self, key: int) -> Anchored | None:
        """A retired object's place on its keyframe and that place's covariance (a copy);
        None if the object is not retired."""
        return self._nodes.retired_objects.anchor(key)

    def marginal_covariance(self, key: int) -> np.ndarray:
        """A live node's marginal covariance as iSAM2 gives it now (frozen: as held)."""
        frozen = self._nodes.frozen.covariance(key)
        return frozen if frozen is not None else self._isam.marginalCovariance(key)

    def kept_covariance(self, key: int) -> tuple[int, np.ndarray] | None:
        """The step a covariance kept for reuse was read at, and it (None: none kept)."""
        return self._marginals.kept(key)

    def deferred_covariances(self) -> int:
        """Computations of retired objects' covariances waiting to be done."""
        return self._nodes.retired_objects.waiting()

    def isam_factors(self) -> gtsam.NonlinearFactorGraph:
        """iSAM2's factor slots (those it let go of empty)."""
        return self._isam.getFactorsUnsafe()

    def live_factor_count(self) -> int:
        """The live factors the back end tracks (iSAM2 should hold as many)."""
        return len(self._slots)
