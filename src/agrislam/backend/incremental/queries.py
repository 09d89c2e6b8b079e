"""Queries (part of `IncrementalBackend`, backend.py): positions, trajectories and marginal
covariances of the graph's nodes (sec. 2.6), whatever state each is in. Retired nodes are
answered many at once from the arrays that hold them (a snapshot asks for every object)."""

from __future__ import annotations

import numpy as np

from agrislam.backend.graph import SurveyGraph, key_index, key_indices
from agrislam.backend.incremental.isam_state import PendingUpdate, per_distinct
from agrislam.backend.incremental.marginal_cache import MarginalCache
from agrislam.backend.incremental.nodes import FROZEN, NEW, NodeTable
from agrislam.backend.incremental.retired import RetiredObjects, RetiredPoses
from agrislam.geometry.drift import adjoint
from agrislam.geometry.se2 import between, pose_uncertainty_at, rotation


class Queries:
    """What the world model reads of the map."""

    graph: SurveyGraph
    _nodes: NodeTable
    _pending: PendingUpdate
    _marginals: MarginalCache
    _step: int
    _increments: dict[str, tuple[np.ndarray, np.ndarray]]

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

    def settled_objects(self) -> np.ndarray:
        """Ids of the objects held on frozen keyframes: they no longer move until a refine."""
        objects = self._nodes.retired_objects
        return key_indices(objects.keys[np.isin(objects.keyframes, self._nodes.frozen.keys())])

    def object_positions(self, object_ids: np.ndarray) -> np.ndarray:
        """(k, 2) current estimates; a retired object's is its keyframe's pose (+) z."""
        keys = self.graph.require_objects(object_ids)
        return self._placed(keys, self._nodes.retired_objects, 2)

    def trajectory(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """Times and (m, 3) poses of the robot; its retired poses placed all at once."""
        chain = self.graph.robot(robot)
        return np.array(chain.times), self._placed(chain.keys, self._nodes.retired_poses, 3)

    def object_covariances(self, object_ids: np.ndarray) -> np.ndarray:
        """(k, 2, 2) marginal covariances of the given objects, cached until the next step;
        a retired object's combines its keyframe's and its relative position's."""
        keys = self.graph.require_objects(object_ids)
        if any(self._pending.guess(key) is not None for key in keys):
            self._solve_pending()  # entered since the last update (a merge): solve them now
        objects = self._nodes.retired_objects
        rows, live = self._split(keys, objects)
        retired, rows = rows >= 0, rows[rows >= 0]
        out = np.empty((len(object_ids), 2, 2))
        if unseen := [key for key in live if self._nodes.state(key) == NEW]:
            raise ValueError(f"object {key_index(unseen[0])} has no observation yet")
        keyframes = objects.keyframes[rows]
        in_isam = [k for k in live + keyframes.tolist() if self._nodes.state(k) != FROZEN]
        self._marginals.read_jointly(in_isam, self._step, self._reuse, self._isam)
        out[~retired] = np.array([self._marginal_covariance(k) for k in live]).reshape(-1, 2, 2)
        if len(rows):
            z = objects.local[rows]
            frames = self._frames(keyframes)
            cov_k = np.stack(per_distinct(keyframes, self._marginal_covariance))
            rot = rotation(frames[:, 2])  # l = K (+) z: the keyframe's part and z's
            given = rot @ objects.covariances(rows) @ np.swapaxes(rot, 1, 2)
            out[retired] = pose_uncertainty_at(frames, cov_k, z) + given
        return out

    def live_size(self) -> int:
        """Nodes in iSAM2."""
        return len(self._nodes.live())

    def _frames(self, keyframes: np.ndarray) -> np.ndarray:
        """(k, 3) current pose of each of `keyframes`, each distinct one read once."""
        return np.array(per_distinct(keyframes, self.estimate)).reshape(-1, 3)

    def _split(
        self, keys: list[int], retired: RetiredObjects | RetiredPoses
    ) -> tuple[np.ndarray, list[int]]:
        """The retired row of each node (-1: not retired) and the keys of the others."""
        rows = retired.rows(keys)
        return rows, [k for k, r in zip(keys, rows.tolist(), strict=True) if r < 0]

    def _placed(self, keys: list[int], retired: RetiredObjects | RetiredPoses, dim: int):
        """(k, dim) estimates of `keys`: the others each, the retired placed at once."""
        rows, live = self._split(keys, retired)
        out = np.empty((len(keys), dim))
        out[rows < 0] = np.array([self.estimate(k) for k in live]).reshape(-1, dim)
        out[rows >= 0] = retired.placed(rows[rows >= 0], self._frames)
        return out
