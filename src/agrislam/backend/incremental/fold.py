"""The fold (part of `IncrementalBackend`, backend.py): every `slam.window` steps each
robot's latest pose becomes a keyframe, keyframes past the kept share are frozen, and the
rest of the window is marginalised out of iSAM2 onto the keyframes and rows it touched;
what it held stays, retired, relative to a keyframe."""

from __future__ import annotations

import functools
from collections import Counter
from collections.abc import Collection

import gtsam
import numpy as np

from agrislam.backend.graph import POSE, SurveyGraph, key_kind
from agrislam.backend.incremental.conditioning import (
    components,
    covariances_given,
    marginalised,
    shared_copy,
)
from agrislam.backend.incremental.isam_state import PendingUpdate, SlotTable
from agrislam.backend.incremental.marginal_cache import MarginalCache
from agrislam.backend.incremental.nodes import FROZEN, NodeTable
from agrislam.backend.incremental.sparsify import sparsified
from agrislam.backend.values import insert_value, value_array
from agrislam.config import SlamConfig
from agrislam.geometry.se2 import to_robot_frame

# per robot: the newest keyframes whose joint a fold's marginal keeps exact (sparsify.py);
# the current poses and objects hang from them
NEWEST_EXACT = 3
AGED_PER_FOLD = 2  # per robot: one that joins shrinks the others' share over folds, not in one


class Folding:
    """Keyframing, freezing and retiring: the window folded away."""

    slam: SlamConfig
    graph: SurveyGraph
    issues: Counter[str]
    _nodes: NodeTable
    rolls: int
    _isam: gtsam.ISAM2
    _pending: PendingUpdate
    _slots: SlotTable
    _marginals: MarginalCache
    _step: int
    _window_start: int
    _folded_heading: dict[int, float]

    def _fold(self) -> None:
        """Keyframe each robot's latest pose; marginalise the rest of the window out (and
        the keyframes beyond `keyframes_kept`, frozen where they stand)."""
        starts = {}  # robot -> the keyframe its window starts at
        for robot, chain in self.graph.robots.items():
            latest = chain.keys[-1]
            if not self._nodes.is_kept(latest) and self._nodes.state(latest) != FROZEN:
                starts[robot] = self._nodes.keyframes(robot)[-1]
                self._nodes.add_keyframe(robot, latest)
        aged = self._aged_keyframes(starts)
        window = self._nodes.window(aged)
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
            newest = self._nodes.newest_keyframes(NEWEST_EXACT)
            marginal = sparsified(marginal, point, newest, self.issues)
            for key in marginal.keyVector():
                if key_kind(key) == POSE and key not in self._folded_heading:
                    self._folded_heading[key] = point.atPose2(key).theta()
            self._slots.drop(slots)
            self._pending.remove(slots)
            self._nodes.left(window)
            for key in window:  # a live node's alone (it grew with the field)
                self._marginals.drop(key)
            self._solve_pending(marginal)
        self._window_start = self._step
        self.rolls += 1

    def _aged_keyframes(self, drove: Collection[str]) -> set[int]:
        """Keyframes past each robot's newest share of `keyframes_kept`, at most
        `keyframes_per_robot` (the first stays), no longer kept; and those of the idle
        robots (`_idle`). Shared: a fold ties the keyframes of robots that saw one landmark
        into one Bayes tree. Capped: a keyframe's marginal read costs more the more
        keyframes a robot keeps."""
        if not (kept := self.slam.keyframes_kept):
            return set()
        holding = self._nodes.holding()
        idle = self._idle(holding, drove, kept)
        kept = max(min(kept // max(len(holding), 1), self.slam.keyframes_per_robot), 1)
        return self._nodes.age(kept, AGED_PER_FOLD, idle)

    def _idle(self, holding: list[str], drove: Collection[str], kept: int) -> set[str]:
        """The robots that give up all their keyframes: each robot holds its first and its
        newest at least, so with more robots than half of `kept` holding keyframes, those
        that did not drive since the last fold, the longest idle first, as many as are too
        many. One that drives again takes up its newest keyframe again (`_enter`): the
        graph, and a step's cost, follow the robots that drive, not all that ever did."""
        excess = len(holding) - kept // 2
        if excess <= 0:
            return set()
        idle = [robot for robot in holding if robot not in drove]
        last_drove = [self.graph.robot(robot).times[-1] for robot in idle]
        order = np.argsort(np.nan_to_num(last_drove, nan=-np.inf), kind="stable")
        return {idle[k] for k in order[:excess]}

    def _freeze(self, aged: set[int]) -> None:
        """Aged keyframes are held where they stand, with their marginal covariance: what
        hangs on them stays there (moved onto a newer keyframe, a far plant would swing
        with its heading)."""
        for keyframe in aged:
            cov = self._isam.marginalCovariance(keyframe)
            self._nodes.freeze(keyframe, self.estimate(keyframe), cov)
            self._folded_heading.pop(keyframe, None)

    def _reached(
        self, key: int, graph: gtsam.NonlinearFactorGraph, point: gtsam.Values, window: set[int]
    ) -> int:
        """A keyframe in `point` to retire object `key` on when the robot that saw it last
        has none there (merged while retired, it came back on its anchors, which tie it to
        an older keyframe): the newest keyframe its factors touch, else the point's newest,
        else any pose of the point outside the window."""
        touched = {
            k for i in range(graph.size()) if key in (keys := graph.at(i).keys()) for k in keys
        }
        outside = [k for k in point.keys() if key_kind(k) == POSE and k not in window]  # noqa: SIM118
        for poses in ([k for k in outside if k in touched], outside):
            if kept := [k for k in poses if self._nodes.is_kept(k)]:
                return max(kept)
        return max(outside)

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
            if self._nodes.state(key) == FROZEN:
                continue
            if key_kind(key) == POSE:
                driven.setdefault(self.graph.robot_of(key), []).append(key)
                continue
            pose, step = self._nodes.last_seen(key)
            step = self._step if step is None else step
            robot = self.graph.robot_of(pose) if pose else next(iter(self.graph.robots))
            frames = self._nodes.keyframes(robot)  # none: an idle robot gave them up
            newest = frames[-1] if frames else None
            keyframe = frames[-2] if step < half and len(frames) > 1 else newest
            if keyframe is None or not point.exists(keyframe):
                keyframe = newest
            # merged while retired (back on its anchors alone), or seen last by an idle robot
            if keyframe is None or not point.exists(keyframe):
                keyframe = self._reached(key, graph, point, window)
            anchored.setdefault(keyframe, []).append(key)
        for robot, keys in driven.items():
            end = self._nodes.keyframes(robot)[-1]
            start = starts.get(robot, end)
            keys.sort()  # a robot's pose keys count up in the order driven
            self._nodes.retire_poses(keys, start, end, point)
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
                self._nodes.retire_object(key, keyframe, z)
            # the covariances (most of a fold's work) are computed in the steps after
            given = functools.partial(
                covariances_given, keyframe, keys, parts, point, blanket, self.issues
            )
            self._nodes.defer(keys, given)
