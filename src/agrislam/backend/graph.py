"""The whole survey graph as plain records (sec. 2.6): robot chains, objects, rows and every
factor between them. Solvers hold their own GTSAM copies; this record is what merges
rewrite, the global refinement solves and g2o files hold."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import gtsam
import numpy as np

from agrislam.backend.factor_store import Factor, FactorStore
from agrislam.backend.gnss_factor import gnss_factor
from agrislam.backend.key_table import NODE_BITS, KeyTable
from agrislam.backend.object_nodes import ObjectNodes
from agrislam.config import SlamConfig
from agrislam.geometry.noise import gaussian, one_direction, robust, row_direction, row_normal
from agrislam.growing import GrowingRows

# key layout: one symbol letter per node kind; robot r's pose i is x(r * POSES_PER_ROBOT + i)
POSES_PER_ROBOT = 1 << NODE_BITS
INDEX_BITS = 56  # GTSAM's Symbol: the letter in the top byte, the index below it
INDEX_MASK = (1 << INDEX_BITS) - 1
POSE, OBJECT, ROW = "x", "l", "r"

# factor kinds
PRIOR_POSE = "prior_pose"  # keys (pose,), value (3,) pose, cov 3x3
ODOMETRY = "odometry"  # keys (pose_a, pose_b), value (3,) delta in a's frame, cov 3x3
DETECTION = "detection"  # keys (pose, object), value (bearing, range), cov 2x2 of those
ROW_ANCHOR = "row_anchor"  # keys (row,), value (2,) point, cov: along-row sigma (gauge only)
ROW_MEMBER = "row_member"  # keys (row, object), value angle, cov cross-row sigma
ROW_SPACING = "row_spacing"  # keys (row_a, row_b), value (angle, distance), cov sigma
# keys (pose,), value (antenna x, y in the map, lever arm x, y, kernel k, kernel), cov 2x2
GNSS = "gnss"
PRIOR_POINT = "prior_point"  # keys (object,), value (2,) saved position, cov 2x2


def pose_key(robot_index: int, i: int) -> int:
    return gtsam.symbol(POSE, robot_index * POSES_PER_ROBOT + i)


def object_key(object_id: int) -> int:
    return gtsam.symbol(OBJECT, int(object_id))


def object_keys(object_ids: np.ndarray) -> list[int]:
    """`object_key` of many ids at once."""
    ids = np.asarray(object_ids, dtype=np.uint64)
    return ((np.uint64(ord(OBJECT)) << np.uint64(INDEX_BITS)) | ids).tolist()


def key_indices(keys: np.ndarray) -> np.ndarray:
    """`key_index` of many keys at once."""
    return (np.asarray(keys, dtype=np.uint64) & np.uint64(INDEX_MASK)).astype(np.int64)


def row_key(row: int) -> int:
    return gtsam.symbol(ROW, int(row))


def key_kind(key: int) -> str:
    """The node kind's letter (in plain ints: a fold asks this of every node it touches,
    and a gtsam.Symbol is dear)."""
    return chr(int(key) >> INDEX_BITS)


def key_index(key: int) -> int:
    return int(key) & INDEX_MASK


def robot_index_of(pose: int) -> int:
    """The index of the robot whose chain holds pose key `pose` (the key layout above)."""
    return key_index(pose) // POSES_PER_ROBOT


class PoseKeys(Sequence[int]):
    """A robot's pose keys, 0 .. n-1 in the order driven: computed, not stored (the key
    layout above numbers them in a row)."""

    __slots__ = ("_first", "_times")

    def __init__(self, index: int, times: GrowingRows) -> None:
        self._first, self._times = pose_key(index, 0), times

    def __len__(self) -> int:
        return len(self._times)

    @overload
    def __getitem__(self, i: int) -> int: ...
    @overload
    def __getitem__(self, i: slice) -> list[int]: ...
    def __getitem__(self, i: int | slice) -> int | list[int]:
        if isinstance(i, slice):
            return [self._first + n for n in range(len(self))[i]]
        return self._first + range(len(self))[i]

    def __iter__(self) -> Iterator[int]:
        return iter(range(self._first, self._first + len(self)))

    def __contains__(self, key: object) -> bool:
        return isinstance(key, (int, np.integer)) and 0 <= int(key) - self._first < len(self)


class RobotChain:
    """A robot's poses as arrays: pose i has key `keys[i]` and time `times[i]`."""

    __slots__ = ("_times", "index")

    def __init__(self, index: int) -> None:
        self.index = index
        self._times = GrowingRows()

    @property
    def times(self) -> np.ndarray:
        """(n,) the poses' times (a view: copy it to keep it)."""
        return self._times.array

    @property
    def keys(self) -> PoseKeys:
        return PoseKeys(self.index, self._times)

    def add(self, t: float) -> int:
        """The next pose, at time t; its key."""
        self._times.append(float(t))
        return self.keys[-1]

    def clear(self) -> None:
        self._times = GrowingRows()


@dataclass(slots=True)
class RowNode:
    point: np.ndarray
    angle: float


class SurveyGraph:
    """Records of nodes and factors; factor ids are stable, removed ones are gone."""

    def __init__(self, issues: Counter[str] | None = None) -> None:
        self.robots: dict[str, RobotChain] = {}
        self.objects = ObjectNodes()  # id -> initial map-frame position, as arrays
        self.rows: dict[int, RowNode] = {}
        # factor id -> Factor, as rows of arrays; what it cannot spill to disk is an issue
        self.factors = FactorStore(issues=issues)
        self.row_of = KeyTable()  # object id -> row id of its row constraint

    # ---------------------------------------------------------------- nodes
    def robot(self, robot: str) -> RobotChain:
        try:
            return self.robots[robot]
        except KeyError:
            raise KeyError(f"robot {robot!r} was never added (add_robot first)") from None

    def robot_of(self, pose: int) -> str:
        """The name of the robot whose chain holds pose key `pose`."""
        index = robot_index_of(pose)
        return next(name for name, chain in self.robots.items() if chain.index == index)

    def add_robot(self, robot: str, t: float) -> RobotChain:
        if robot in self.robots:
            raise ValueError(f"robot {robot!r} is already in the graph")
        chain = RobotChain(index=len(self.robots))
        self.robots[robot] = chain
        self.add_pose(chain, t)
        return chain

    def add_pose(self, chain: RobotChain, t: float) -> int:
        return chain.add(t)

    def add_object(self, object_id: int, xy: np.ndarray) -> int:
        if object_id in self.objects:
            raise ValueError(f"object {object_id} already exists")
        if object_id < 0:
            raise ValueError(f"object id must be non-negative, got {object_id}")
        self.objects[object_id] = np.asarray(xy, dtype=float).copy()
        return object_key(object_id)

    def require_object(self, object_id: int) -> int:
        if object_id not in self.objects:
            raise KeyError(f"object {object_id} is not in the graph")
        return object_key(object_id)

    def require_objects(self, object_ids: np.ndarray) -> list[int]:
        """`require_object` of many ids at once."""
        missing = self.objects.missing(object_ids)
        if len(missing):
            raise KeyError(f"object {missing[0]} is not in the graph")
        return object_keys(object_ids)

    def require_row(self, row: int) -> int:
        if row not in self.rows:
            raise KeyError(f"row {row} is not in the graph")
        return row_key(row)

    # -------------------------------------------------------------- factors
    def add_factor(self, factor: Factor) -> int:
        fid = self.factors.append(factor)
        if factor.kind == ROW_MEMBER:
            self.row_of[key_index(factor.keys[1])] = key_index(factor.keys[0])
        return fid

    def remove_factor(self, fid: int) -> Factor:
        factor = self.factors.pop(fid)
        if factor.kind == ROW_MEMBER:
            self.row_of.pop(key_index(factor.keys[1]), None)
        return factor

    def factor_ids(self, key: int) -> list[int]:
        return self.factors.ids_of(key)

    def forget_node(self, key: int) -> None:
        """Node `key` is gone from the graph (its factors already removed)."""
        self.factors.forget(key)

    def row_member_factor(self, object_id: int) -> int | None:
        if object_id not in self.row_of:
            return None
        okey = object_key(object_id)
        return next(f for f in self.factor_ids(okey) if self.factors.kind(f) == ROW_MEMBER)

    def remove_object(self, object_id: int) -> list[int]:
        """Drop an object and its factors; returns the removed factor ids."""
        okey = self.require_object(object_id)
        fids = self.factor_ids(okey)
        for fid in fids:
            self.remove_factor(fid)
        del self.objects[object_id]
        self.forget_node(okey)
        return fids

    @staticmethod
    def rekey(factor: Factor, old: int, new: int) -> Factor:
        keys = tuple(new if k == old else k for k in factor.keys)
        return Factor(factor.kind, keys, factor.value, factor.cov)

    def all_keys(self) -> Iterable[int]:
        for chain in self.robots.values():
            yield from chain.keys
        yield from (object_key(i) for i in self.objects)
        yield from (row_key(r) for r in self.rows)


def make_factor(factor: Factor, slam: SlamConfig) -> gtsam.NonlinearFactor:
    """The GTSAM factor of a record."""
    kind, keys, value, cov = factor.kind, factor.keys, factor.value, factor.cov
    if kind == ODOMETRY:
        return gtsam.BetweenFactorPose2(keys[0], keys[1], gtsam.Pose2(*value), gaussian(cov))
    if kind == DETECTION:
        # relative position as bearing-range: sec. 2.6, covariance along/across the ray
        return gtsam.BearingRangeFactor2D(
            keys[0], keys[1], gtsam.Rot2(value[0]), value[1], robust(slam, gaussian(cov))
        )
    if kind == PRIOR_POSE:
        return gtsam.PriorFactorPose2(keys[0], gtsam.Pose2(*value), gaussian(cov))
    if kind == PRIOR_POINT:
        # a plant of a saved map: its saved position with its saved covariance
        return gtsam.PriorFactorPoint2(keys[0], np.asarray(value, dtype=float), gaussian(cov))
    if kind == ROW_MEMBER:
        # sec. 2.6.2: plant to row node, across the row only
        noise = one_direction(row_normal(float(value[0])), float(cov))
        return gtsam.BetweenFactorPoint2(keys[0], keys[1], np.zeros(2), noise)
    if kind == ROW_SPACING:
        # sec. 2.6.2: neighbouring row nodes are `distance` apart across the rows
        normal = row_normal(float(value[0]))
        noise = one_direction(normal, float(cov))
        return gtsam.BetweenFactorPoint2(keys[0], keys[1], value[1] * normal, noise)
    if kind == ROW_ANCHOR:
        # fixes where along its line a row node sits (gauge only, no effect on plants)
        along = row_direction(float(value[2]))
        return gtsam.PriorFactorPoint2(keys[0], value[:2].copy(), one_direction(along, float(cov)))
    if kind == GNSS:
        return gnss_factor(keys[0], value, cov)  # the antenna at t + R l
    raise ValueError(f"unknown factor kind {kind!r}")
