"""A robot that comes back to where it mapped long ago closes the loop (not in the paper):
its newest objects, moved far past the gate by its drift, are matched as a constellation
to old objects by a voted rigid motion; each matched new object merges into its old one.
A returning robot's constellation (association/returning.py) is matched the same way as
soon as a few of its objects fit one motion within its drift's reach, however small."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from agrislam.association.gnn import gated_matches
from agrislam.backend import GraphBackend
from agrislam.estimation.point_spacing import PointSpacing
from agrislam.geometry.se2 import compose_points, pair_motions, rotation
from agrislam.mapping.births import Births
from agrislam.mapping.objects import NO_OBJECTS, ObjectTable
from agrislam.snapshot import STATUS_ACTIVE

RECENT_S = 300.0  # objects started this recently may form a robot's constellation
MIN_FRAMES = 3  # frames an object was seen in before it counts (clutter is seen once)
MIN_MATCHES = 5  # matched objects a loop needs
MAX_CONSTELLATION = 20  # the newest objects of a constellation, no more
MAX_CANDIDATES = 60  # the old objects nearest the constellation, no more
FITS = 8  # the best bins fitted and counted
SPACING_SIGMAS = 3.0  # two pairs are as far apart within this many sigmas
CLOSED = (
    "loops closed: a returning robot's new objects merged into old ones "
    "(association/loop_closure.py)"
)


class Rule(NamedTuple):
    """What a motion of a constellation must be to close a loop."""

    matches: int = MIN_MATCHES  # matched objects, at least
    least: float = 0.0  # m the median matched object moves by, more than this
    shift: float = np.inf  # m the constellation's centre moves by, at most
    turn: float = np.inf  # rad it turns by, at most
    # m: a fit putting the constellation this far (median) from the best's is another
    # place; None: one sharing under half of its matches with the best's is
    apart: float | None = None


class _Fit(NamedTuple):
    matched: int
    cost: float
    rows: np.ndarray  # matched objects of the constellation
    cols: np.ndarray  # and their candidates
    moved: np.ndarray  # (r, 2) the constellation under the motion


class LoopCloser:
    """Finds a returning robot's constellation among old objects."""

    def __init__(
        self,
        births: Births,
        issues: Counter[str],
        gate_chi2: float | None = None,
        spacing: PointSpacing | None = None,
    ) -> None:
        self.births, self.issues = births, issues
        self.gate_chi2 = gate_chi2  # the association's gate; None: off
        self.spacing = spacing  # a motion must move the constellation by 2 d_inter at least
        self._checked: dict[int, tuple[int, ...]] = {}  # robot -> constellation last checked

    @property
    def reach(self) -> float:
        """m a motion must move the constellation by, at least: the merger's company."""
        d_inter = self.spacing.d_inter if self.spacing is not None else None
        return 2.0 * d_inter if d_inter is not None else 0.0

    def pairs(
        self,
        robot: int,
        t: float,
        objects: ObjectTable,
        backend: GraphBackend,
        scale: float,
        hidden: np.ndarray = NO_OBJECTS,
    ) -> list[tuple[int, int]]:
        """(old, new) objects to merge: the robot's constellation on old objects, or none;
        `scale` is the calibrated detection variance's factor; `hidden` objects (returning
        robots' constellations) are no candidates."""
        if self.gate_chi2 is None:
            return []
        recent = self._constellation(robot, t, objects)
        if len(recent) < MIN_MATCHES or self._seen_before(robot, recent[-1:]):
            return []
        positions = backend.object_positions
        old = self._candidates(int(recent[0]), objects, positions(recent).mean(axis=0), positions)
        old = old[~np.isin(old, hidden)]
        return self._close(robot, recent, old, Rule(least=self.reach), objects, backend, scale)

    def returned(
        self,
        robot: int,
        own: np.ndarray,
        rule: Rule,
        objects: ObjectTable,
        backend: GraphBackend,
        scale: float,
        hidden: np.ndarray = NO_OBJECTS,
    ) -> list[tuple[int, int]]:
        """(old, new) objects to merge: a returning robot's constellation `own` (the objects
        it started since it left the map) on the map's objects nearest it but `hidden`, by
        a motion within `rule`, or none."""
        if self.gate_chi2 is None:
            return []
        recent = own[objects.n_frames[own] >= MIN_FRAMES][-MAX_CONSTELLATION:]
        if len(recent) < rule.matches or self._seen_before(robot, recent):
            return []
        ok = (objects.status == STATUS_ACTIVE) & (objects.n_frames >= MIN_FRAMES)
        ok[own], ok[hidden] = False, False
        old = np.flatnonzero(ok)
        positions = backend.object_positions
        new_xy, old_xy = positions(recent), positions(old)
        centre = new_xy.mean(axis=0)
        spread = float(np.linalg.norm(new_xy - centre, axis=1).max())
        far = np.linalg.norm(old_xy - centre, axis=1)
        near = np.flatnonzero(far <= rule.shift + spread)
        old = np.sort(old[near[np.argsort(far[near])[:MAX_CANDIDATES]]])
        return self._close(robot, recent, old, rule, objects, backend, scale)

    def _seen_before(self, robot: int, constellation: np.ndarray) -> bool:
        """Whether the robot's constellation was checked as it is (its newest object, or
        all of it), and note it as checked."""
        key = tuple(constellation.tolist())
        if self._checked.get(robot) == key:
            return True
        self._checked[robot] = key
        return False

    def _close(
        self,
        robot: int,
        recent: np.ndarray,
        old: np.ndarray,
        rule: Rule,
        objects: ObjectTable,
        backend: GraphBackend,
        scale: float,
    ) -> list[tuple[int, int]]:
        """(old, new) pairs the constellation `recent` closes on the candidates `old` by."""
        if len(old) < rule.matches:
            return []
        positions = backend.object_positions
        fit = self._fit(
            positions(recent),
            positions(old),
            _variance(recent, objects, scale),
            _variance(old, objects, scale),
            rule,
        )
        if fit is None:
            return []
        self.issues[CLOSED] += 1
        self._checked.pop(robot)
        return [(int(old[c]), int(recent[r])) for r, c in zip(fit.rows, fit.cols, strict=True)]

    def _constellation(self, robot: int, t: float, objects: ObjectTable) -> np.ndarray:
        """Active objects started in the last RECENT_S, seen last by `robot`, in at least
        MIN_FRAMES frames: the newest MAX_CONSTELLATION."""
        first = self.births.below(t - RECENT_S)
        ids = np.arange(first, len(objects))
        n_frames = objects.n_frames[first:]
        ok = (objects.status[first:] == STATUS_ACTIVE) & (n_frames >= MIN_FRAMES)
        ok &= objects.seen_by[first:] == robot
        return ids[ok][-MAX_CONSTELLATION:]

    def _candidates(
        self,
        first: int,
        objects: ObjectTable,
        centre: np.ndarray,
        positions: Callable[[np.ndarray], np.ndarray],
    ) -> np.ndarray:
        """Active objects older than the constellation (whose first is `first`), seen in
        MIN_FRAMES frames and not since it began: the MAX_CANDIDATES nearest `centre`."""
        ok = (objects.status[:first] == STATUS_ACTIVE) & (objects.n_frames[:first] >= MIN_FRAMES)
        ok &= objects.last_update[:first] < self.births.started(first)
        ids = np.flatnonzero(ok)
        if len(ids) <= MAX_CANDIDATES:
            return ids
        far = np.linalg.norm(positions(ids) - centre, axis=1)
        return np.sort(ids[np.argsort(far)[:MAX_CANDIDATES]])

    def _fit(
        self,
        new_xy: np.ndarray,
        old_xy: np.ndarray,
        new_var: np.ndarray,
        old_var: np.ndarray,
        rule: Rule,
    ) -> _Fit | None:
        """The motion of the constellation onto the candidates, if it is clear and within
        `rule`; `new_var` and `old_var` (m^2 per axis) say how sure the objects' places are
        relative to their neighbours."""
        centre = new_xy.mean(axis=0)
        new, old = new_xy - centre, old_xy - centre
        variance = new_var[:, None] + old_var[None, :]  # of each (new, old) offset
        sigma = float(np.sqrt(np.median(variance)))
        motions = pair_motions(new, old, SPACING_SIGMAS * np.sqrt(2.0) * sigma)
        motions = motions[_within(motions, rule)]
        if len(motions) == 0:
            return None
        spread = max(float(np.linalg.norm(new, axis=1).max()), sigma)
        fits = []
        for motion in _top_bins(motions, sigma, sigma / spread, FITS):
            fit = _count(motion, new, old, variance, self.gate_chi2)
            for _ in range(2):  # refit the motion to its matches, count again
                if fit.matched < 2:
                    break
                refit = _procrustes(new[fit.rows], old[fit.cols])
                if not _within(refit[None], rule)[0]:
                    break
                fit = _count(refit, new, old, variance, self.gate_chi2)
            fits.append(fit)
        fits.sort(key=lambda f: (-f.matched, f.cost))
        best = fits[0]
        if best.matched < rule.matches:
            return None
        if np.median(np.linalg.norm(best.moved - new, axis=1)[best.rows]) <= rule.least:
            return None  # near enough for association and the merger
        pairs = set(zip(best.rows.tolist(), best.cols.tolist(), strict=True))
        for other in fits[1:]:
            if rule.apart is not None:
                gap = np.median(np.linalg.norm(other.moved - best.moved, axis=1))
                elsewhere = bool(gap > rule.apart)
            else:
                matches = set(zip(other.rows.tolist(), other.cols.tolist(), strict=True))
                elsewhere = 2 * len(pairs & matches) < other.matched
            if elsewhere and 2 * other.matched > best.matched:
                return None  # another place fits about as well: not sure where it is
        return best


def _within(motions: np.ndarray, rule: Rule) -> np.ndarray:
    """(h,) which motions (dx, dy, dtheta) about the constellation's centre `rule` allows."""
    shift = np.linalg.norm(motions[:, :2], axis=1)
    return (shift <= rule.shift) & (np.abs(motions[:, 2]) <= rule.turn)


def _variance(ids: np.ndarray, objects: ObjectTable, scale: float) -> np.ndarray:
    """(k,) m^2 per axis: how sure each object's place is among its neighbours, as its
    detections averaged (their noise, `scale` its calibrated factor, over its frames)."""
    detection = np.trace(objects.seen_cov[ids], axis1=1, axis2=2) * scale / 2.0
    return detection / np.maximum(objects.n_frames[ids], 1)


def _top_bins(motions: np.ndarray, step_m: float, step_rad: float, n: int) -> np.ndarray:
    """(<= n, 3) the mean motion of each of the n bins with the most votes."""
    cells = np.floor(motions / np.array([step_m, step_m, step_rad])).astype(np.int64)
    _, which, votes = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    top = np.argsort(-votes, kind="stable")[:n]
    which = which.reshape(-1)
    return np.array([motions[which == k].mean(axis=0) for k in top])


def _count(
    motion: np.ndarray, new: np.ndarray, old: np.ndarray, variance: np.ndarray, gate_chi2: float
) -> _Fit:
    """The new points moved, matched one to one to old points within the gate (each
    offset's `variance` per axis)."""
    moved = compose_points(motion, new)
    cost = ((old[None, :, :] - moved[:, None, :]) ** 2).sum(axis=2) / variance
    rows, cols = gated_matches(cost, gate_chi2)
    return _Fit(len(rows), float(cost[rows, cols].sum()), rows, cols, moved)


def _procrustes(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """(dx, dy, dtheta): the rigid motion that best puts `new` on `old` (least squares)."""
    a, b = new - new.mean(axis=0), old - old.mean(axis=0)
    turn = np.arctan2((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum(), (a * b).sum())
    return np.r_[old.mean(axis=0) - rotation(turn) @ new.mean(axis=0), turn]
