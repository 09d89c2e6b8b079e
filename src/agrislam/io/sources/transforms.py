"""Rigid transforms of ROS messages: a geometry_msgs pose as a 4x4 matrix, its planar part,
and the tree of tf/tf_static frames the bag reader looks camera frames up in."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agrislam.io.perception.camera import rigid_transform, rotation_from_quaternion


def pose_matrix(pose: Any) -> np.ndarray:
    """geometry_msgs/Pose (or Transform) as a 4x4 transform."""
    p = getattr(pose, "position", None) or pose.translation
    q = getattr(pose, "orientation", None) or pose.rotation
    return rigid_transform(rotation_from_quaternion((q.x, q.y, q.z, q.w)), (p.x, p.y, p.z))


def planar(T: np.ndarray) -> np.ndarray:
    """x, y, yaw of a 4x4 transform."""
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])


class TransformTree:
    """The latest transform of every frame to its parent (tf/tf_static)."""

    def __init__(self) -> None:
        self.parent: dict[str, tuple[str, np.ndarray]] = {}

    def set(self, parent: str, child: str, T: np.ndarray) -> None:
        self.parent[child.lstrip("/")] = (parent.lstrip("/"), T)

    def _to_root(self, frame: str) -> tuple[str, np.ndarray]:
        T = np.eye(4)
        seen = {frame}
        while frame in self.parent:
            frame, T_parent = self.parent[frame][0], self.parent[frame][1] @ T
            T = T_parent
            if frame in seen:
                raise ValueError(f"tf has a cycle through {frame!r}")
            seen.add(frame)
        return frame, T

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """T_target_source (maps points in `source` to `target`), None if not connected."""
        root_s, T_rs = self._to_root(source.lstrip("/"))
        root_t, T_rt = self._to_root(target.lstrip("/"))
        if root_s != root_t:
            return None
        return np.linalg.solve(T_rt, T_rs)
