"""Nodes folded out of iSAM2 (incremental/fold.py), as rows of arrays so that many
are placed at once:

- `Retired` / `RetiredObjects` / `RetiredPoses`: each node held relative to a keyframe (a
  pose: to both keyframes of its window); an object's covariance given its keyframe may
  be computed later (`RetiredObjects.defer`).
- `Anchored`: a retired object on its own, as it comes back into iSAM2 (`anchor_factor`).
- `FrozenKeyframes`: keyframes aged out of iSAM2 too, held where they were; what hangs on
  them stays on them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import gtsam
import numpy as np

from agrislam.backend.key_table import KeyTable
from agrislam.backend.values import value_array, values_at
from agrislam.geometry.noise import gaussian, relative_to_range_bearing
from agrislam.geometry.se2 import (
    between,
    compose,
    pose_uncertainty_at,
    to_map_frame,
    wrap_angle,
)
from agrislam.growing import Doubling

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


class FrozenKeyframes:
    """Keyframes aged out of iSAM2 (`slam.keyframes_kept`), each held at the pose and
    marginal covariance it had then. What hangs on one stays on it: a far keyframe of the
    field keeps the plants and poses retired near it, with no lever arm to a newer one."""

    def __init__(self) -> None:
        self._held: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # key -> pose, covariance

    def __contains__(self, key: int) -> bool:
        return key in self._held

    def __len__(self) -> int:
        return len(self._held)

    def freeze(self, key: int, pose: np.ndarray, cov: np.ndarray) -> None:
        self._held[key] = (np.asarray(pose, dtype=float), np.asarray(cov, dtype=float))

    def keys(self) -> np.ndarray:
        return np.fromiter(self._held, dtype=np.uint64, count=len(self._held))

    def pose(self, key: int) -> np.ndarray | None:
        held = self._held.get(key)
        return None if held is None else held[0]

    def covariance(self, key: int) -> np.ndarray | None:
        held = self._held.get(key)
        return None if held is None else held[1]

    def thaw(self, key: int) -> tuple[np.ndarray, gtsam.NonlinearFactor]:
        """Keyframe `key` no longer frozen: its pose, and a prior there as uncertain as it
        was held."""
        pose, cov = self._held.pop(key)
        return pose, gtsam.PriorFactorPose2(key, gtsam.Pose2(*pose), gaussian(cov))

    def moved_to(self, solution: gtsam.Values) -> None:
        """Every frozen keyframe at its pose in `solution` (a refine of the whole record)."""
        for key, (_, cov) in self._held.items():
            self._held[key] = (value_array(solution, key), cov)

    def anchor_factor(self, anchor: Anchored, key: int) -> gtsam.NonlinearFactor:
        """The factor that ties retired object `key` back: to a live keyframe,
        `anchor_factor`; to a frozen one, a prior where it stands, as uncertain as its place
        given the keyframe plus the keyframe's own uncertainty at that lever arm."""
        held = self._held.get(anchor.keyframe)
        if held is None:
            return anchor_factor(anchor, key)
        pose, pose_cov = held
        xy, cov = to_map_frame(pose, anchor.z[None], anchor.cov[None])
        cov = cov[0] + pose_uncertainty_at(pose, pose_cov, anchor.z[None])[0]
        return gtsam.PriorFactorPoint2(key, xy[0], gaussian(cov))


class Retired:
    """Nodes folded out of iSAM2, each kept relative to a keyframe that stays in it: row r
    holds node `keys[r]`, its keyframe `keyframes[r]` and `local[r]`, its place in the
    keyframe's frame ((3,) relative pose, or (2,) relative position). Rows stay dense: a
    node that leaves hands its row to the last one."""

    def __init__(self, dim: int) -> None:
        self.dim = dim
        self._row = KeyTable()  # node key -> its row
        self._n = 0
        self._columns: dict[str, np.ndarray] = {
            "keys": np.zeros(0, dtype=np.uint64),
            "keyframes": np.zeros(0, dtype=np.uint64),
            "local": np.zeros((0, dim)),
        }
        self._doubling = Doubling()

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
        return self._row.get_many(keys)

    def row(self, key: int) -> int | None:
        return self._row.get(key)

    def put(self, key: int, keyframe: int, local: np.ndarray, **more: np.ndarray) -> None:
        """Node `key` retires onto `keyframe` at `local` (and the other columns' values)."""
        row = self._row.get(key)
        if row is None:
            row = self._n
            capacity = len(self._columns["keys"])
            self._columns.update(
                self._doubling.reserve(row + 1, capacity, lambda: self._columns) or {}
            )
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
    not the whole window swung about its newest keyframe."""

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
    fold's work) to be `defer`red: `pace` computes the oldest a step later,
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

    def waiting(self) -> int:
        """Deferred computations not done yet."""
        return len(self._deferred)

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
