"""Map maintenance (sec. 2.6.3): merge objects closer than d_inter (without a field prior,
only those rarely detected in the same frame: `Merger`), prune objects seen only a few
times whose interest heuristic stays high.

Both look only around what changed: merging checks the objects touched this step,
pruning the young objects whose grace period has just run out.

Young objects are tentative until their sightings confirm them (`Existence`, not in the
paper). A clutter object of a cluttered survey is seen a few times (its gate catches other
clutter), so the paper's rule for objects seen at most twice misses it; but a plant is
detected in most frames that look at it, clutter in few. An object detected in n of the
k frames that had it in view (geometry/view_area.py) is a plant (rate p_d) or clutter
(rate e); p_d, e and the share of clutter are learned from the survey's own objects (hard
EM, e held near `stray_rate_prior` where there is little clutter to learn from).

While tentative, an object's detections say where it is but do not pull the poses: their
factors get d_inter of isotropic noise added (the second sighting of clutter is any point
within the gate). Added, not scaled: the factors keep their shape and the object's gate
stays near d_inter, so it takes no detections of its neighbours. Once the posterior says
it is there, sure to `confirm_p`, it is confirmed, a normal object from then on; once it
says it is not, as sure, it is dropped. In a clean survey a plant is confirmed by its
second sighting; under heavy clutter it takes more. At the end of the survey the objects
still tentative are judged once more with the final trajectory and kept only if more
likely there than not.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

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
# so that three sightings in three frames confirm it (measured: a share of 0.17, two
# sightings, let early clutter bend a survey with 50 % clutter)
PRIOR_P_DETECT = 0.8
PRIOR_CLUTTER_SHARE = 0.5
# the rates are learned from the newest objects in view LEARN_VIEWS times, this many: the
# survey's present light and growth, with an EM that does not grow with the field (issue
# 14: all 100,000 plants' EM every RELEARN_FRAMES frames cost 1 ms of the p95 step; the
# scan that finds them does grow, 0.08 ms at 100,000)
LEARN_RECENT = 5_000


@dataclass(slots=True)
class MaintenanceResult:
    merged: list[tuple[int, int]] = field(default_factory=list)  # (keep, drop)
    pruned: list[int] = field(default_factory=list)


# two near objects seen in one frame in more than this share of the frames that saw the
# less-seen one are two (a split object's parts are seen together only when an outlier or a
# neighbour's detection goes to one of them)
TOGETHER_SHARE = 0.1
# frames the least seen object of a crowd must have before its company is judged (a
# landmark's object in the arena has hundreds; a crowd's ghost lives on tens)
CROWD_MIN_FRAMES = 20


class Merger:
    """Finds the objects to merge (sec. 2.6.3): closer than d_inter, and not often detected
    in the same frame (issue 11, ambiguous neighbours): two landmarks a range sigma apart
    are detected together in nearly every frame that sees them, one object split in two
    hardly ever. A field prior's plant spacing rules out two plants that near: with one, the
    test is off (`spare_together`).

    Between two landmarks a third object can live on their detections, each frame's
    ambiguous one going to it: it is detected with each of the two often, never with both
    (one object too many for the frames' detections). Three landmarks' detections can feed
    six objects the same way. Such a crowd's least seen object, detected with its
    neighbours often but never with all at once, is merged too, until the crowd is no
    larger than what its frames detect together."""

    def __init__(self) -> None:
        # per object, the sets of other objects detected near it in one frame -> frames
        self._company: dict[int, dict[frozenset[int], int]] = {}
        self.spare_together = False

    def saw(self, object_ids: np.ndarray, xy: np.ndarray, radius: float) -> None:
        """A frame's detections: their objects and map positions; each object counts one
        frame with the set of objects whose detections lie within `radius` of its own."""
        if len(object_ids) < 2 or not self.spare_together:
            return
        near = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2) < radius
        np.fill_diagonal(near, False)
        for i in np.flatnonzero(near.any(axis=1)).tolist():
            company = self._company.setdefault(int(object_ids[i]), {})
            others = frozenset(object_ids[near[i]].tolist())
            company[others] = company.get(others, 0) + 1

    def merged(self, keep: int, drop: int) -> None:
        """`drop` joined `keep`: its frames count as `keep`'s (as its frames do in the
        object table), and its neighbours' frames with it as frames with `keep`."""
        moved = self._company.pop(drop, {})
        for obj in {keep}.union(*moved):
            company = self._company.get(obj)
            if company is None:
                continue
            renamed: dict[frozenset[int], int] = {}
            for others, n in [*company.items(), *(moved.items() if obj == keep else ())]:
                others = others | {keep} if drop in others else others
                others = others - {drop, obj}
                if others:
                    renamed[others] = renamed.get(others, 0) + n
            self._company[obj] = renamed

    def together(self, obj: int, others: np.ndarray) -> np.ndarray:
        """(k,) the frames `obj` was detected in together with each of `others`."""
        company = self._company.get(int(obj), {})
        return np.array(
            [sum(n for s, n in company.items() if b in s) for b in np.asarray(others).tolist()],
            dtype=np.int64,
        )

    def surplus(self, crowd: np.ndarray, n_frames: np.ndarray) -> int | None:
        """The object one too many in `crowd` (three or more near objects), if any: the
        least seen, when in most of its frames it was detected with others of the crowd, but
        with all of them in at most TOGETHER_SHARE of those: the crowd has more objects than
        its frames detect at once (a pair and a ghost between them; or three landmarks
        whose detections went to six objects, which the frames never detect more than three
        of). Judged once it has CROWD_MIN_FRAMES frames."""
        if len(crowd) < 3:
            return None
        obj = int(crowd[np.argmin(n_frames[crowd])])
        n = int(n_frames[obj])
        if n < CROWD_MIN_FRAMES:
            return None
        everyone = frozenset(crowd[crowd != obj].tolist())
        company = self._company.get(obj, {})
        with_some = sum(k for s, k in company.items() if s & everyone)
        all_together = sum(k for s, k in company.items() if everyone <= s)
        crowded = with_some >= 0.5 * n
        return obj if crowded and all_together <= TOGETHER_SHARE * with_some else None

    def pairs(
        self,
        touched: np.ndarray,
        index: SpatialIndex,
        positions: Callable[[np.ndarray], np.ndarray],  # ids -> (k, 2) current estimates
        objects: ObjectTable,
        d_inter: float,
    ) -> list[tuple[int, int]]:
        """Pairs (keep, drop) of distinct objects to merge, each object in at most one
        pair; the better-observed object (then the older) is kept."""
        pairs: list[tuple[int, int]] = []
        used: set[int] = set()
        n_meas, n_frames = objects.n_meas, objects.n_frames
        for obj, xy in zip(touched.tolist(), positions(touched), strict=True):
            if obj in used:
                continue
            near = index.query(xy[None, :], d_inter)
            near = near[(near != obj) & ~np.isin(near, list(used))]
            if self.spare_together:
                crowd = np.append(near, obj)
                if (ghost := self.surplus(crowd, n_frames)) is not None:
                    obj, near = ghost, crowd[crowd != ghost]
                    xy = positions(np.array([ghost]))[0]
                else:
                    fewer_frames = np.minimum(n_frames[obj], n_frames[near])
                    near = near[self.together(obj, near) <= TOGETHER_SHARE * fewer_frames]
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


class AfterFold:
    """Objects whose row and merge work a fold's step leaves to the next step (issue 14):
    a fold retires the window's objects, and a row constraint or a merge on one of them
    re-enters it, computing its deferred covariance (10-20 ms) in a step that already
    folds (25-45 ms at 30,000 plants)."""

    def __init__(self) -> None:
        self.waiting = np.empty(0, dtype=np.int64)

    def ready(self, touched: np.ndarray, folded: bool) -> np.ndarray:
        """The objects to work on now: those waiting and `touched`, unless `folded`."""
        ids = np.union1d(self.waiting, touched).astype(np.int64)
        self.waiting, ready = (ids, ids[:0]) if folded else (ids[:0], ids)
        return ready


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
