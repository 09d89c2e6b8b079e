"""Young objects are tentative until the frames that had them in view confirm them (not in
the paper). A plant is detected in most frames that look at it, clutter in few: an object
detected in n of the k frames that had it in view is a plant (rate p_d) or clutter (rate
e), with p_d, e and the share of clutter learned from the survey's own objects (hard EM).

While tentative, its detections' factors get d_inter of isotropic noise added, so clutter
cannot pull the poses; once the posterior is sure to `confirm_p` it is confirmed, or
dropped. At the end of the survey the objects still tentative are judged once more."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from agrislam.config import MaintenanceConfig
from agrislam.geometry.view_area import ViewArea, log_odds_absent
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex
from agrislam.snapshot import STATUS_MERGED

SAMPLE = 20_000  # robot-frame detections the seen area is learned from
EM_ROUNDS = 10
RELEARN_FRAMES = 20  # frames between the rates learned again during a survey
LEARN_VIEWS = 3  # frames in view an object's counts need to teach the rates
LEARN_OBJECTS = 10  # such objects before the survey's own rates are used
# the rates before then (the first frames: they are learned every frame until there are
# enough objects): a detector's recall, and a new object as likely clutter as a plant,
# so that three sightings in three frames confirm it (fewer let early clutter bend a
# cluttered survey: docs/decisions.md)
PRIOR_P_DETECT = 0.8
PRIOR_CLUTTER_SHARE = 0.5
# the rates are learned from the newest objects in view LEARN_VIEWS times, this many: the
# survey's present light and growth, with an EM that does not grow with the field
LEARN_RECENT = 5_000


class Existence:
    """Confirms or drops tentative objects from the frames that had them in view; learns
    where the camera looks, and the detection and stray rates, from the survey itself."""

    def __init__(self, config: MaintenanceConfig) -> None:
        self.config = config
        self._sample: list[np.ndarray] = []
        self._n = 0
        self._area: ViewArea | None = None
        self._frames = 0
        self.stats: dict[str, float] = {
            "p_detect": PRIOR_P_DETECT,
            "stray_rate": config.stray_rate_prior,
            "clutter_share": PRIOR_CLUTTER_SHARE,
        }
        self.learned = False  # the rates are the survey's own (else the prior ones)
        self.pruned = 0
        self.confirmed = 0
        self.dropped = 0

    @property
    def enabled(self) -> bool:
        return self.config.existence

    def observe(self, robot_xy: np.ndarray | None) -> None:
        """A frame's detections in the robot frame (the first SAMPLE are kept)."""
        if robot_xy is not None and len(robot_xy) and self._n < SAMPLE:
            self._sample.append(np.asarray(robot_xy, dtype=float)[: SAMPLE - self._n])
            self._n += len(self._sample[-1])

    def area(self) -> ViewArea | None:
        """The camera's seen area learned from the detections so far (None: too few)."""
        if self._n < 20:
            return None
        if self._area is None or (self._frames % RELEARN_FRAMES == 0 and self._n < SAMPLE):
            self._area = ViewArea.learned(np.vstack(self._sample), 0.0)
        return self._area

    def look(
        self,
        pose: np.ndarray,
        index: SpatialIndex,
        seen: np.ndarray,
        objects: ObjectTable,
        first: int = 0,
    ) -> np.ndarray:
        """One frame seen from `pose` (3,): the objects from id `first` on (this survey's)
        that were in view (where `index` last put them), or `seen` in it, count a view; the
        tentative ones among them that their sightings now say are there are confirmed.
        Returns those they say are not there, to be pruned."""
        area = self.area() if self.enabled else None
        if area is None:
            return np.empty(0, dtype=np.int64)
        near = objects.active(index.query(pose[None, :2], area.range[1]))
        near, seen = near[near >= first], seen[seen >= first]
        self._frames += 1
        looked = np.union1d(near[area.in_view(pose, index.position(near))], seen)
        objects.views[looked] += 1
        if not self.learned or self._frames % RELEARN_FRAMES == 0:
            self.learn(objects)
        young = looked[objects.tentative[looked]]
        hits, views = self._counts(young, objects)
        log_odds = self.log_odds(hits, views)
        sure = np.log(self.config.confirm_p / (1.0 - self.config.confirm_p))
        confirmed = young[(log_odds <= -sure) & (hits >= 2)]  # two frames at least agree
        dropped = young[log_odds >= sure]
        objects.tentative[np.r_[confirmed, dropped]] = False  # judged
        self.confirmed += len(confirmed)
        self.dropped += len(dropped)
        return dropped

    def absent(
        self,
        ids: np.ndarray,
        positions: Callable[[np.ndarray], np.ndarray],  # ids -> (k, 2) current estimates
        objects: ObjectTable,
        poses: list[np.ndarray],
    ) -> list[int]:
        """Those of the objects `ids` still tentative that are more likely not there than
        there, given the frame poses ((m, 3) per robot) of the survey; the rates are
        learned from all of `ids`."""
        if not self.enabled or self._n < 20 or len(ids) == 0 or not poses:
            return []
        area = ViewArea.learned(np.vstack(self._sample), 0.0)
        hits = objects.n_meas[ids].astype(float)
        views = np.maximum(area.views(np.vstack(poses), positions(ids)), hits)
        ids = np.asarray(ids, dtype=np.int64)
        absent = ids[self.classify(hits, views) & objects.tentative[ids]].tolist()
        self.pruned = len(absent)
        return absent

    def report(self) -> dict[str, object]:
        """What the test found, for the summary: the rates it learned, objects confirmed
        during the survey, dropped during it, pruned at its end."""
        return {
            "enabled": self.enabled,
            "confirmed": self.confirmed,
            "dropped": self.dropped,
            "pruned": self.pruned,
            **self.stats,
        }

    def learn(self, objects: ObjectTable) -> None:
        """The rates of the survey so far, from the LEARN_RECENT newest objects in view in
        LEARN_VIEWS frames or more, those dropped or pruned since included (clutter leaves
        the map, its counts stay); the prior rates until there are LEARN_OBJECTS such."""
        counted = np.flatnonzero(objects.views >= LEARN_VIEWS)
        # a merged object's counts are in the one it joined
        counted = counted[objects.status[counted] != STATUS_MERGED][-LEARN_RECENT:]
        if len(counted) >= LEARN_OBJECTS:
            self.classify(*self._counts(counted, objects))
            self.learned = True

    @staticmethod
    def _counts(ids: np.ndarray, objects: ObjectTable) -> tuple[np.ndarray, np.ndarray]:
        """(hits, views) of the objects: measurements, and frames in view (at least those)."""
        hits = objects.n_meas[ids].astype(float)
        return hits, np.maximum(objects.views[ids].astype(float), hits)

    def log_odds(self, hits: np.ndarray, views: np.ndarray) -> np.ndarray:
        """log P(not there) - log P(there) with the rates learned last."""
        st = self.stats
        return log_odds_absent(hits, views, st["p_detect"], st["stray_rate"], st["clutter_share"])

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
