"""What the map looks like at one instant: the read-only view that sinks, the
evaluation and the CLI take from the world model. Plain arrays, one row per object."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agrislam.config import FieldSchema
from agrislam.records import Anchor
from agrislam.semantics.heuristic import InterestSurface

STATUS_ACTIVE = 0
STATUS_MERGED = 1
STATUS_PRUNED = 2
STATUS_GONE = 3  # a saved plant not found where the survey looked


@dataclass(frozen=True, slots=True)
class ObjectMap:
    """The mapped objects (struct of arrays, DESIGN.md "State layout")."""

    ids: np.ndarray  # (k,) int
    xy: np.ndarray  # (k, 2) map frame, m
    cov: np.ndarray  # (k, 2, 2) marginal position covariance
    n_meas: np.ndarray  # (k,) int
    interest: np.ndarray  # (k,) h in [0, 1]
    row: np.ndarray  # (k,) row index, -1 for none
    discrete: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (k, n_values)
    continuous: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # mean, var

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True, slots=True)
class Trajectory:
    robot: str
    t: np.ndarray  # (m,)
    poses: np.ndarray  # (m, 3) x, y, theta


@dataclass(frozen=True, slots=True)
class RowLines:
    """Fitted rows (sec. 2.6.2): row k is the line {p : n . p = offsets[k]}, n = (-sin a, cos a)."""

    angle: float
    offsets: np.ndarray  # (r,)


@dataclass(frozen=True, slots=True)
class MapSnapshot:
    schema: FieldSchema | None
    objects: ObjectMap
    trajectories: dict[str, Trajectory]  # optimised
    dead_reckoning: dict[str, Trajectory]
    anchor: Anchor | None = None
    rows: RowLines | None = None
    interest_surface: InterestSurface | None = None
    step_times: dict[str, np.ndarray] = field(default_factory=dict)  # stage -> s per step

    def step_seconds(self) -> np.ndarray:
        """Each step's whole time (s), its stages summed."""
        if not self.step_times:
            return np.zeros(0)
        return np.sum([np.asarray(t, dtype=float) for t in self.step_times.values()], axis=0)
