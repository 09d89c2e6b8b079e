"""What every back end shares: checking the inputs, recording the graph (graph.SurveyGraph),
merges and rows. A solver subclass says how factors reach GTSAM and how it solves."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from agrislam.backend.graph import (
    DETECTION,
    GNSS,
    ODOMETRY,
    PRIOR_POINT,
    PRIOR_POSE,
    ROW_ANCHOR,
    ROW_MEMBER,
    ROW_SPACING,
    Factor,
    RowNode,
    SurveyGraph,
    key_indices,
    row_key,
)
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.noise import (
    Measurement,
    RangeBearing,
    RelativePosition,
    check_covariance,
    relative_to_range_bearing,
)
from agrislam.geometry.se2 import compose

# start prior of a robot that anchors the map frame (given start pose without sigma, or the
# first robot without a start pose: the map frame is where it starts)
ANCHOR_SIGMA = np.array([1e-3, 1e-3, 1e-4])
# start prior of a further robot without a start pose: shared objects place it
FREE_START_SIGMA = np.array([1e3, 1e3, math.pi])
# where along its line a row node sits is a gauge freedom; this prior only fixes it
ROW_ALONG_SIGMA = 1.0


def detection_record(measurement: Measurement, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(bearing, range) and its 2x2 covariance from either measurement type."""
    if isinstance(measurement, RelativePosition):
        xy = np.asarray(measurement.xy, dtype=float)
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"{where}: xy must be 2 finite numbers, got {measurement.xy!r}")
        cov = check_covariance(measurement.cov, 2, where)
        bearing, rng, cov_br = relative_to_range_bearing(xy, cov)
        return np.array([bearing, rng]), cov_br
    if isinstance(measurement, RangeBearing):
        values = (
            measurement.range,
            measurement.bearing,
            measurement.sigma_range,
            measurement.sigma_bearing,
        )
        if not all(math.isfinite(v) for v in values) or measurement.range <= 0:
            raise ValueError(f"{where}: range must be > 0 and all values finite, got {measurement}")
        if measurement.sigma_range <= 0 or measurement.sigma_bearing <= 0:
            raise ValueError(f"{where}: sigmas must be > 0, got {measurement}")
        cov = np.diag([measurement.sigma_bearing**2, measurement.sigma_range**2])
        return np.array([math.remainder(measurement.bearing, math.tau), measurement.range]), cov
    raise TypeError(f"{where}: expected RelativePosition or RangeBearing, got {type(measurement)}")


class BackendBase:
    """Records the graph and forwards each change to the solver hooks below."""

    def __init__(self, slam: SlamConfig, rows: RowsConfig) -> None:
        self.slam = slam
        self.rows_config = rows
        # degenerate geometry the solver isolated instead of stopping the run, by reason
        self.issues: Counter[str] = Counter()
        self.graph = SurveyGraph(self.issues)
        self.refines = 0  # whole-graph solves so far: each may move every unsettled estimate
        self.whole_refine = 0  # the last of them that moved settled objects too (a batch)
        self.rolls = 0  # windows folded away (the incremental back end's keyframes)

    # ------------------------------------------------------------ solver hooks
    def _insert(self, key: int, value: np.ndarray) -> None:
        """A new node and its initial guess."""
        raise NotImplementedError

    def _add(self, fid: int) -> None:
        """A new factor of the record to solve with."""
        raise NotImplementedError

    def _remove(self, fid: int) -> None:
        raise NotImplementedError

    def _replace(self, old: int, new: int | None) -> None:
        """A merge moved factor `old` to `new` (None: dropped as a duplicate)."""
        self._remove(old)
        if new is not None:
            self._add(new)

    def _forget(self, key: int, into: int | None) -> None:
        """Node `key` is gone: merged into node `into`, or removed (None)."""
        raise NotImplementedError

    def estimate(self, key: int) -> np.ndarray:
        """Best current estimate of a node: (3,) pose or (2,) point."""
        raise NotImplementedError

    # ------------------------------------------------------------------- robots
    def add_robot(
        self,
        robot: str,
        start_pose: np.ndarray | None = None,
        start_sigma: np.ndarray | None = None,
        t: float | None = None,
    ) -> None:
        """A robot chain starting at `start_pose` (map frame) with a prior of `start_sigma`.
        Without a start pose the first robot defines the map frame and later ones float."""
        anchored = start_pose is not None or not self.graph.robots
        pose = np.zeros(3) if start_pose is None else np.asarray(start_pose, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise ValueError(
                f"robot {robot!r}: start_pose must be 3 finite numbers, got {start_pose!r}"
            )
        if start_sigma is None:
            sigma = ANCHOR_SIGMA if anchored else FREE_START_SIGMA
        else:
            sigma = np.asarray(start_sigma, dtype=float)
            if sigma.shape != (3,) or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
                raise ValueError(
                    f"robot {robot!r}: start_sigma must be 3 numbers > 0, got {start_sigma!r}"
                )
        chain = self.graph.add_robot(robot, math.nan if t is None else t)
        key = chain.keys[0]
        self._insert(key, pose)
        self._add(self.graph.add_factor(Factor(PRIOR_POSE, (key,), pose, np.diag(sigma**2))))

    def add_odometry(self, robot: str, t: float, delta: np.ndarray, cov: np.ndarray) -> None:
        """A new pose after the robot's latest, `delta` in the latest pose's frame."""
        where = f"odometry of robot {robot!r} at t={t}"
        chain = self.graph.robot(robot)
        delta = np.asarray(delta, dtype=float)
        if delta.shape != (3,) or not np.all(np.isfinite(delta)):
            raise ValueError(f"{where}: delta must be 3 finite numbers, got {delta!r}")
        cov = check_covariance(cov, 3, where)
        previous = chain.keys[-1]
        guess = compose(self.estimate(previous), delta)
        key = self.graph.add_pose(chain, t)
        self._insert(key, guess)
        self._add(self.graph.add_factor(Factor(ODOMETRY, (previous, key), delta, cov)))

    def current_pose(self, robot: str) -> np.ndarray:
        return self.estimate(self.graph.robot(robot).keys[-1])

    def add_gnss(self, robot: str, value: np.ndarray, cov: np.ndarray) -> None:
        """A GNSS fix on the robot's latest pose (estimation/gnss.py: value's layout)."""
        where = f"GNSS fix of robot {robot!r}"
        value = np.asarray(value, dtype=float)
        if value.shape != (6,) or not np.all(np.isfinite(value)):
            raise ValueError(f"{where}: value must be 6 finite numbers, got {value!r}")
        cov = check_covariance(cov, 2, where)
        key = self.graph.robot(robot).keys[-1]
        self._add(self.graph.add_factor(Factor(GNSS, (key,), value, cov)))

    # ------------------------------------------------------------------ objects
    def add_object(self, object_id: int, xy: np.ndarray) -> None:
        xy = np.asarray(xy, dtype=float)
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"object {object_id}: xy must be 2 finite numbers, got {xy!r}")
        self._insert(self.graph.add_object(int(object_id), xy), xy)

    def add_object_prior(self, object_id: int, xy: np.ndarray, cov: np.ndarray) -> None:
        """A prior on the object's position: where a saved map has it, with its covariance."""
        okey = self.graph.require_object(int(object_id))
        cov = check_covariance(cov, 2, f"prior of object {object_id}")
        value = np.asarray(xy, dtype=float)
        self._add(self.graph.add_factor(Factor(PRIOR_POINT, (okey,), value, cov)))

    def add_observation(self, robot: str, object_id: int, measurement: Measurement) -> None:
        """A detection of the object from the robot's latest pose (robust kernel, sec. 2.6)."""
        okey = self.graph.require_object(int(object_id))
        pkey = self.graph.robot(robot).keys[-1]
        value, cov = detection_record(
            measurement, f"observation of object {object_id} by {robot!r}"
        )
        self._add(self.graph.add_factor(Factor(DETECTION, (pkey, okey), value, cov)))

    def object_ids(self) -> np.ndarray:
        return self.graph.objects.ids()

    def merge_objects(self, keep: int, drop: int) -> None:
        """All factors of `drop` move to `keep` (sec. 2.6.3); a second row constraint is not
        moved (keep already has one)."""
        if keep == drop:
            raise ValueError(f"cannot merge object {keep} with itself")
        kkey, dkey = self.graph.require_object(keep), self.graph.require_object(drop)
        for fid in self.graph.factor_ids(dkey):
            factor = self.graph.remove_factor(fid)
            if factor.kind == ROW_MEMBER and keep in self.graph.row_of:
                self._replace(fid, None)
                continue
            self._replace(fid, self.graph.add_factor(SurveyGraph.rekey(factor, dkey, kkey)))
        self._forget(dkey, kkey)
        self.graph.remove_object(drop)

    def remove_object(self, object_id: int) -> None:
        okey = self.graph.require_object(int(object_id))
        for fid in self.graph.remove_object(int(object_id)):
            self._remove(fid)
        self._forget(okey, None)

    # --------------------------------------------------------------------- rows
    def add_row(self, row: int, point: np.ndarray, angle: float) -> None:
        """A row node (sec. 2.6.2) at `point` on a row line at `angle` to the x axis."""
        if row in self.graph.rows:
            raise ValueError(f"row {row} already exists")
        point = np.asarray(point, dtype=float)
        self.graph.rows[row] = RowNode(point.copy(), float(angle))
        key = row_key(row)
        self._insert(key, point)
        anchor = np.array([point[0], point[1], angle])
        self._add(self.graph.add_factor(Factor(ROW_ANCHOR, (key,), anchor, ROW_ALONG_SIGMA)))

    def add_row_constraint(self, object_id: int, row: int) -> None:
        """Soft constraint of the object to the row line, across the row only (sec. 2.6.2)."""
        okey = self.graph.require_object(int(object_id))
        rkey = self.graph.require_row(row)
        self.remove_row_constraint(object_id)
        value = np.array([self.graph.rows[row].angle])
        factor = Factor(ROW_MEMBER, (rkey, okey), value, self.rows_config.sigma_cross)
        self._add(self.graph.add_factor(factor))

    def remove_row_constraint(self, object_id: int) -> None:
        fid = self.graph.row_member_factor(int(object_id))
        if fid is not None:
            self.graph.remove_factor(fid)
            self._remove(fid)

    def add_row_spacing(self, row_a: int, row_b: int, distance: float) -> None:
        """Soft constraint n . (p_b - p_a) = distance between two row nodes (sec. 2.6.2)."""
        akey, bkey = self.graph.require_row(row_a), self.graph.require_row(row_b)
        value = np.array([self.graph.rows[row_a].angle, float(distance)])
        factor = Factor(ROW_SPACING, (akey, bkey), value, self.rows_config.sigma_spacing)
        self._add(self.graph.add_factor(factor))

    def set_row_angle(self, row: int, angle: float) -> None:
        """Turn a row: its node's constraints are replaced by ones at `angle` (a refit)."""
        key = self.graph.require_row(row)
        self.graph.rows[row].angle = float(angle)
        for fid in self.graph.factor_ids(key):
            factor = self.graph.remove_factor(fid)
            value = factor.value.copy()
            value[2 if factor.kind == ROW_ANCHOR else 0] = angle
            new = Factor(factor.kind, factor.keys, value, factor.cov)
            self._replace(fid, self.graph.add_factor(new))

    def remove_row(self, row: int) -> None:
        """Drop a row node with all its constraints."""
        key = self.graph.require_row(row)
        for fid in self.graph.factor_ids(key):
            self.graph.remove_factor(fid)
            self._remove(fid)
        del self.graph.rows[row]
        self.graph.forget_node(key)
        self._forget(key, None)

    def row_points(self, rows: np.ndarray) -> np.ndarray:
        return np.array([self.estimate(self.graph.require_row(int(r))) for r in rows]).reshape(
            -1, 2
        )

    def rows_of(self, object_ids: np.ndarray) -> np.ndarray:
        return self.graph.row_of.get_many(np.asarray(object_ids, dtype=np.int64))

    # ------------------------------------------------------------------- common
    def load(self, graph: SurveyGraph, values: dict[int, np.ndarray]) -> None:
        """Start from a recorded graph (a g2o file, say) and its estimates; then `update`."""
        if self.graph.robots or self.graph.objects:
            raise ValueError("load needs an empty back end")
        self.graph = graph
        for key in graph.all_keys():
            self._insert(key, values[key])
        for fid in list(graph.factors):
            self._add(fid)

    def settled_objects(self) -> np.ndarray:
        """Ids of the objects whose estimates no longer move until a `refine` (the
        incremental back end's, held on frozen keyframes); here none."""
        return np.empty(0, dtype=np.int64)

    def object_positions(self, object_ids: np.ndarray) -> np.ndarray:
        """(k, 2) current estimates of the given objects; O(k)."""
        require = self.graph.require_object
        return np.array([self.estimate(require(int(i))) for i in object_ids]).reshape(-1, 2)

    def trajectory(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        chain = self.graph.robot(robot)
        poses = np.array([self.estimate(k) for k in chain.keys]).reshape(-1, 3)
        return np.array(chain.times), poses

    def sightings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every pose of the survey, (m, 3) robot by robot as `trajectory` gives them, and
        each distinct (pose, object) pair a detection factor joins: (k,) the pose's row,
        (k,) the object's id. What was seen from where, at the end of a survey."""
        chains = self.graph.robots
        if not chains:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        poses = np.vstack([self.trajectory(name)[1] for name in chains])
        keys = np.array([k for chain in chains.values() for k in chain.keys], dtype=np.uint64)
        pairs = np.unique(self.graph.factors.keys_of(DETECTION), axis=0)
        order = np.argsort(keys)
        rows = order[np.searchsorted(keys, pairs[:, 0], sorter=order)]
        return poses, rows, key_indices(pairs[:, 1])


__all__ = ["BackendBase", "detection_record"]
