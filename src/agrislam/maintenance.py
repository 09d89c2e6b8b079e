"""Map maintenance (sec. 2.6.3): merge objects closer than d_inter, prune objects seen
only a few times whose interest heuristic stays high.

Both look only around what changed: merging checks the objects touched this step,
pruning the few young objects whose grace period has just run out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agrislam.association import SpatialIndex
from agrislam.config import MaintenanceConfig
from agrislam.semantics.beliefs import BeliefTable


@dataclass(slots=True)
class MaintenanceResult:
    merged: list[tuple[int, int]] = field(default_factory=list)  # (keep, drop)
    pruned: list[int] = field(default_factory=list)


def merge_pairs(
    touched: np.ndarray,
    touched_xy: np.ndarray,
    index: SpatialIndex,
    positions: Callable[[np.ndarray], np.ndarray],  # ids -> (k, 2) current estimates
    n_meas: np.ndarray,
    d_inter: float,
) -> list[tuple[int, int]]:
    """Pairs (keep, drop) of distinct objects closer than d_inter, each object in at most
    one pair; the better-observed object (then the older) is kept."""
    pairs: list[tuple[int, int]] = []
    used: set[int] = set()
    for obj, xy in zip(touched.tolist(), touched_xy, strict=True):
        if obj in used:
            continue
        near = index.query(xy[None, :], d_inter)
        near = near[(near != obj) & ~np.isin(near, list(used))]
        if len(near) == 0:
            continue
        d = np.linalg.norm(positions(near) - xy, axis=1)
        if d.min() >= d_inter:
            continue
        other = int(near[int(np.argmin(d))])
        keep, drop = sorted((obj, other), key=lambda i: (-n_meas[i], i))
        pairs.append((keep, drop))
        used.update((keep, drop))
    return pairs


class Pruner:
    """Remembers objects seen at most `prune_max_meas` times; once unseen for the grace
    period, an object whose interest heuristic is still high is pruned."""

    def __init__(self, config: MaintenanceConfig) -> None:
        self.config = config
        self._young: dict[int, None] = {}  # insertion-ordered set

    def watch(self, ids: np.ndarray) -> None:
        for i in ids.tolist():
            self._young[i] = None

    def forget(self, ids: list[int]) -> None:
        for i in ids:
            self._young.pop(i, None)

    def due(self, beliefs: BeliefTable, t: float, grace: float | None = None) -> list[int]:
        """Objects to prune now; objects that grew out of youth are dropped from watch.
        `grace` overrides the configured grace period (0 at the end of a survey)."""
        grace = self.config.prune_grace_s if grace is None else grace
        if not self._young:
            return []
        ids = np.fromiter(self._young, dtype=int, count=len(self._young))
        n_meas = beliefs.n_meas[ids]
        grown = ids[n_meas > self.config.prune_max_meas]
        expired = ids[
            (n_meas <= self.config.prune_max_meas) & (beliefs.last_update[ids] <= t - grace)
        ]
        self.forget(grown.tolist())
        if len(expired) == 0:
            return []
        self.forget(expired.tolist())
        h = beliefs.interest(expired, t)
        return expired[h >= self.config.prune_min_interest].tolist()
