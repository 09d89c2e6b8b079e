"""Map maintenance (sec. 2.6.3): merge objects closer than d_inter, prune objects seen
only a few times whose interest heuristic stays high.

Both look only around what changed: merging checks the objects touched this step,
pruning the young objects whose grace period has just run out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agrislam.association import SpatialIndex
from agrislam.config import MaintenanceConfig
from agrislam.objects import ObjectTable


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


def prune_due(
    objects: ObjectTable, t: float, config: MaintenanceConfig, grace: float | None = None
) -> list[int]:
    """Objects to prune now, among those the pruner watches (`objects.young`): seen at most
    `prune_max_meas` times, unseen for the grace period, and with an interest heuristic
    still at or above `prune_min_interest`. Objects that grew out of youth, and those
    judged now, are no longer watched. `grace` overrides the configured grace period (0
    at the end of a survey)."""
    grace = config.prune_grace_s if grace is None else grace
    young = objects.young
    ids = np.flatnonzero(young)
    if len(ids) == 0:
        return []
    n_meas = objects.n_meas[ids]
    grown = ids[n_meas > config.prune_max_meas]
    expired = ids[(n_meas <= config.prune_max_meas) & (objects.last_update[ids] <= t - grace)]
    young[grown] = False
    if len(expired) == 0:
        return []
    young[expired] = False
    h = objects.beliefs.interest(expired, t)
    return expired[h >= config.prune_min_interest].tolist()
