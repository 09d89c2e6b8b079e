"""A node's value between numpy and GTSAM: a pose as (3,) x, y, theta, a point as (2,) x, y;
which one a key holds its kind says (graph.POSE or not)."""

from __future__ import annotations

import gtsam
import numpy as np

from agrislam.backend.graph import POSE, key_kind


def pose_array(pose: gtsam.Pose2) -> np.ndarray:
    return np.array([pose.x(), pose.y(), pose.theta()])


def value_array(values: gtsam.Values, key: int) -> np.ndarray:
    if key_kind(key) == POSE:
        return pose_array(values.atPose2(key))
    return np.asarray(values.atPoint2(key), dtype=float)


def insert_value(values: gtsam.Values, key: int, value: np.ndarray) -> None:
    if key_kind(key) == POSE:
        values.insert(key, gtsam.Pose2(*value))
    else:
        values.insert(key, np.asarray(value, dtype=float))


def values_at(values: gtsam.Values, keys: np.ndarray, dim: int) -> np.ndarray:
    """(k, dim) the values of `keys` at once: poses (dim 3, POSE keys) or points (dim 2)."""
    pose = ord(POSE)
    stored = np.array(values.keys(), dtype=np.uint64)
    stored = stored[(stored >> np.uint64(56) == pose) == (dim == 3)]
    table = (gtsam.utilities.extractPose2 if dim == 3 else gtsam.utilities.extractPoint2)(values)
    return table.reshape(-1, dim)[np.searchsorted(stored, keys)]
