"""Map maintenance (sec. 2.6.3): merge objects closer than d_inter, prune objects seen
only a few times whose interest heuristic stays high.

Both look only around what changed: merging checks the objects touched this step,
pruning the young objects whose grace period has just run out.

At the end of a survey, `Existence` also prunes what its detections say is not there
(not in the paper): an object detected in n of the k frames that had it in view
(geometry/view_area.py) is a plant (rate p_d) or clutter that caught stray detections
(rate e). A clutter object of a cluttered survey is seen a few times (its gate catches
other clutter), so the paper's rule for objects seen at most twice misses it; but a plant
is detected in most frames that look at it, clutter in few. p_d, e and the share of
clutter are learned from the survey's own objects (hard EM, e held near
`stray_rate_prior` where there is little clutter to learn from).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agrislam.association import SpatialIndex
from agrislam.config import MaintenanceConfig
from agrislam.geometry.view_area import ViewArea, log_odds_absent
from agrislam.objects import ObjectTable

SAMPLE = 20_000  # robot-frame detections the seen area is learned from
EM_ROUNDS = 10


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


class Existence:
    """Learns where the camera looks from the survey's detections; at the end, says which
    objects are not there."""

    def __init__(self, config: MaintenanceConfig) -> None:
        self.config = config
        self._sample: list[np.ndarray] = []
        self._n = 0
        self.stats: dict[str, float] = {}
        self.pruned = 0

    def observe(self, robot_xy: np.ndarray | None) -> None:
        """A frame's detections in the robot frame (the first SAMPLE are kept)."""
        if robot_xy is not None and len(robot_xy) and self._n < SAMPLE:
            self._sample.append(np.asarray(robot_xy, dtype=float)[: SAMPLE - self._n])
            self._n += len(self._sample[-1])

    def absent(
        self,
        ids: np.ndarray,
        positions: Callable[[np.ndarray], np.ndarray],  # ids -> (k, 2) current estimates
        objects: ObjectTable,
        poses: list[np.ndarray],
    ) -> list[int]:
        """Those of the objects `ids` that are more likely not there than there, given
        the frame poses ((m, 3) per robot) of the survey."""
        if not self.config.existence or self._n < 20 or len(ids) == 0 or not poses:
            return []
        area = ViewArea.learned(np.vstack(self._sample), 0.0)
        hits = objects.n_meas[ids].astype(float)
        views = np.maximum(area.views(np.vstack(poses), positions(ids)), hits)
        absent = np.asarray(ids, dtype=np.int64)[self.classify(hits, views)].tolist()
        self.pruned = len(absent)
        return absent

    def report(self) -> dict[str, object]:
        """What the test found, for the summary: the rates it learned, objects pruned."""
        return {"enabled": self.config.existence, "pruned": self.pruned, **self.stats}

    def classify(self, hits: np.ndarray, views: np.ndarray) -> np.ndarray:
        """(k,) whether each object is more likely clutter than a plant: hard EM of the
        two binomial rates and the clutter share; objects never in view are kept."""
        cfg = self.config
        looked = views > 0
        there = looked & (hits >= 0.5 * views)
        log_odds = np.zeros(len(hits))
        for _ in range(EM_ROUNDS):
            p_d = float(np.clip(hits[there].sum() / max(views[there].sum(), 1.0), 0.05, 0.99))
            stray = looked & ~there
            e = (hits[stray].sum() + cfg.stray_prior_views * cfg.stray_rate_prior) / (
                views[stray].sum() + cfg.stray_prior_views
            )
            e = float(min(e, 0.25 * p_d))  # a stray point is hit far less often than a plant
            share = float(np.clip(stray.sum() / max(looked.sum(), 1), 0.01, 0.99))
            log_odds = log_odds_absent(hits, views, p_d, e, share)
            now = looked & (log_odds < 0.0)
            if np.array_equal(now, there):
                break
            there = now
        self.stats = {"p_detect": p_d, "stray_rate": e, "clutter_share": share}
        return looked & (log_odds > 0.0)
