"""A robot's first frames by dead reckoning, what registers it in a map (relocalise.py): its
detections placed from its odometry alone, its first pose at the origin, with their times
and attribute distributions. A survey continuing a saved map registers each robot in it
(run/season.py); a robot without a start pose registers in the map being built
(newcomers.py). A fix becomes the robot's start prior."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from agrislam.config import FieldSchema, SeasonConfig
from agrislam.geometry import se2
from agrislam.records import Detections, DiscreteMeasurement, Measurement, Odometry, RobotStart
from agrislam.season.relocalise import Fix, Relocaliser, cluster, detection_spread
from agrislam.semantics.beliefs import BeliefTable

# m, m, rad: what dead reckoning may have drifted between the start and the frames of the
# fix; the plants seen again then hold the trajectory
START_SIGMA_FLOOR = np.array([0.1, 0.1, 0.03])

# (first-frames plants' attribute distributions by name, map rows they may be) -> (k,) bool
Check = Callable[[dict[str, np.ndarray], np.ndarray], np.ndarray]


@dataclass
class FirstFrames:
    """One robot's frames by dead reckoning: detection positions, their times and the
    distributions of their discrete attributes; its tries and its fix."""

    pose: np.ndarray = field(default_factory=lambda: np.zeros(3))
    xy: list[np.ndarray] = field(default_factory=list)
    t: list[float] = field(default_factory=list)  # time of each detection
    dists: dict[str, list[np.ndarray]] = field(default_factory=dict)
    t0: float | None = None
    last_try: float = -np.inf  # s of driving at the latest try
    fix: Fix | None = None  # once localised
    after: float | None = None  # s of driving until the fix

    def add(self, record: Odometry | Detections, schema: FieldSchema | None) -> None:
        """An odometry record moves the dead-reckoned pose; a frame's detections are placed
        from it."""
        if self.t0 is None:
            self.t0 = record.t
        if isinstance(record, Odometry):
            if record.delta is not None:
                self.pose = se2.compose(self.pose, record.delta)
            return
        if not record.objects:
            return
        self.t.extend([record.t] * len(record.objects))
        robot_xy = np.stack([det.position() for det in record.objects])
        self.xy.extend(robot_xy @ se2.rotation(self.pose[2]).T + self.pose[:2])
        for det in record.objects:
            for name, dist in distributions(det.attributes, schema).items():
                self.dists.setdefault(name, []).append(dist)

    def due(self, t: float, every: float) -> bool:
        """Whether a try is due at t, `every` s of driving after the previous one."""
        driven = t - (self.t0 if self.t0 is not None else t)
        if driven - self.last_try < every:
            return False
        self.last_try = driven
        return True

    def locate(
        self,
        relocaliser: Relocaliser,
        cfg: SeasonConfig,
        since: float,
        until: float = np.inf,
        check: Check | None = None,
    ) -> Fix:
        """Register the detections of [since, until] (s) in the relocaliser's map; `check`
        tells which map plants their attributes allow (None: any)."""
        keep, xy, (local, counts, label) = self.plants(cfg, since, until)
        if check is not None and self.dists:
            means = {
                name: _cluster_mean(np.array(d)[keep], label, len(local))
                for name, d in self.dists.items()
            }
            relocaliser.compatible = lambda rows, j: check(
                {name: m[rows] for name, m in means.items()}, j
            )
        try:
            return relocaliser.locate(local, counts, detection_spread(xy, local, counts, label))
        finally:
            relocaliser.compatible = None  # the check reads this try's frames only

    def plants(
        self, cfg: SeasonConfig, since: float = -np.inf, until: float = np.inf
    ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The detections of [since, until] (s): which they are, where, and the plants they
        make (`relocalise.cluster`: means, detections each, the plant of each)."""
        times = np.asarray(self.t)
        keep = (times >= since) & (times <= until)
        xy = np.array(self.xy).reshape(-1, 2)[keep]
        return keep, xy, cluster(xy, cfg.cluster_radius)

    def localised(self, fix: Fix, t: float) -> None:
        """Take `fix`, found at t."""
        self.fix, self.after = fix, t - (self.t0 if self.t0 is not None else t)

    def start(self) -> RobotStart:
        """The start prior the fix gives: its own uncertainty widened and floored, a prior
        and not a clamp."""
        assert self.fix is not None and self.fix.transform is not None
        assert self.fix.cov is not None
        sigma = np.maximum(3.0 * np.sqrt(np.diag(self.fix.cov)), START_SIGMA_FLOOR)
        return RobotStart(pose=self.fix.transform, sigma=sigma)


def distributions(
    attributes: Mapping[str, Measurement], schema: FieldSchema | None
) -> dict[str, np.ndarray]:
    """Each discrete measurement as the distribution of Assumption 1 (p on the value, the
    rest spread uniformly); uniform where the attribute is not measured."""
    out = {}
    if schema is None:
        return out
    for name, spec in schema.discrete.items():
        m = attributes.get(name)
        n = len(spec.values)
        dist = np.full(n, 1.0 / n)
        if isinstance(m, DiscreteMeasurement) and m.value in spec.values and m.p >= 1.0 / n:
            dist = np.full(n, (1.0 - m.p) / max(n - 1, 1))
            dist[spec.values.index(m.value)] = m.p
        out[name] = dist
    return out


def compatibility(beliefs: BeliefTable, t: float, floor: float = 0.5):
    """`compatible(p_local, map_ids)`: whether measured attribute distributions (dict
    name -> (m, n)) agree with the map plants' beliefs at t: for every discrete attribute,
    sum_k p_local p_map >= floor / n (half of what two uniform ones give)."""

    def compatible(local: dict[str, np.ndarray], map_ids: np.ndarray) -> np.ndarray:
        ok = np.ones(len(map_ids), dtype=bool)
        for name, p_local in local.items():
            p_map = beliefs.probabilities(name, map_ids, t)
            ok &= (p_local * p_map).sum(axis=1) >= floor / p_map.shape[1]
        return ok

    return compatible


def _cluster_mean(values: np.ndarray, label: np.ndarray, k: int) -> np.ndarray:
    """(k, n) mean of the per-detection rows `values` (m, n) over each cluster."""
    out = np.zeros((k, values.shape[1]))
    np.add.at(out, label[: len(values)], values)
    return out / np.maximum(np.bincount(label[: len(values)], minlength=k), 1)[:, None]
