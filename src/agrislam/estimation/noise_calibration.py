"""Noise that calibrates itself: the variance factors of the detection, odometry translation
and heading noise, estimated online by Fisher scoring from pairs of sightings of one object
in a robot's dead-reckoning frame, whose difference is detection noise twice plus the
chain's drift between them (geometry/drift.py); outlying pairs are down-weighted by EM.

A factor inflates a covariance at most 30 times and twice an estimate, from the 200th pair
on: a detector that claims a sigma of a micrometre for a plant its re-sightings scatter by
centimetres would map its first frames, and all after, too sure of itself. So the spread
of a robot's re-sightings a frame apart (mostly detection noise twice) is a floor from the
first pairs on: a detection claiming a sigma `CONTRADICTED` times below it is raised to it
(`detection_floor`); before the first pairs, the configured detection noise stands for it
(its first frames' factors stay in the graph: too sure, they bend the chain)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from agrislam.config import CalibrationConfig
from agrislam.geometry import se2

TERMS = ("detection", "translation", "heading")
FISHER_ITERATIONS = 8
PAIRS_A_CALL = 4096  # the pairs a call sums for an estimate under way (`Scoring`)
MAX_STEP = 2.0  # the most one estimate changes a sigma factor by
ANCHOR_SLOTS = 1 << 13  # objects a calibration keeps an anchor sighting of (`Anchors`)
ANCHOR_SPAN = 10.0  # an anchor pairs while the drift since is 1 to this x the detection noise
SPREAD_PAIRS = 256  # the latest pairs a frame apart the spread of re-sightings is taken over
MIN_SPREAD_PAIRS = 30  # before as many, no floor
CONTRADICTED = 10.0  # a detection claiming a sigma this many times below the spread is raised
RAYLEIGH_MEDIAN = 1.1774 * np.sqrt(2.0)  # median distance of two sightings, in their sigma
FLOORED = (
    "detection covariances far below the spread of their re-sightings raised to it "
    "(estimation/noise_calibration.py)"
)


@dataclass
class NoiseScale:
    """Variance factors on the configured noise terms (1: as configured)."""

    variance: np.ndarray  # (3,) detection, translation, heading

    @classmethod
    def configured(cls) -> NoiseScale:
        return cls(np.ones(len(TERMS)))

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(self.variance)

    @property
    def weights(self) -> np.ndarray:
        """(3,) the factor on each odometry part: the correlation scales with both sigmas."""
        v_t, v_h = self.variance[1], self.variance[2]
        return np.array([v_t, v_h, np.sqrt(v_t * v_h)])

    def odometry(self, parts: np.ndarray) -> np.ndarray:
        """(..., 3, 3) the scaled covariance of odometry parts (..., 3, 3, 3)."""
        return np.einsum("p,...pij->...ij", self.weights, parts)

    def detection(self, cov: np.ndarray) -> np.ndarray:
        return self.variance[0] * cov

    def as_dict(self) -> dict[str, float]:
        return {term: float(s) for term, s in zip(TERMS, self.sigma, strict=True)}


@dataclass
class Scoring:
    """An estimate under way (`NoiseCalibration.estimate`): the pairs it is over, the
    factors so far and the inlier share of the EM, after `done` iterations. An iteration
    runs over the pairs `PAIRS_A_CALL` at a time (`advance`): its sums add up over the
    pairs, so one in parts ends where one at once does, and a step pays for a part."""

    d: np.ndarray  # (2, n) the differences' x and y
    entries: np.ndarray  # (3, C, n) each component's xx, xy and yy entry (`entries`)
    start: np.ndarray  # (3,) the factors it started from
    v: np.ndarray  # (C,) the factors so far
    bounds: tuple[float, float]
    outlier_density: float
    inlier_share: float = 0.9
    done: int = 0
    _at: int = 0  # the pairs the iteration under way has summed
    _sums: tuple[float, np.ndarray, np.ndarray] = (0.0, 0.0, 0.0)  # weight, score, information

    @property
    def pairs(self) -> int:
        return self.d.shape[1]

    def advance(self, pairs: int) -> bool:
        """The iteration under way over its next `pairs` pairs: an EM step of their inlier
        weights and their part of the Fisher step; True when that ended the iteration."""
        part = slice(self._at, self._at + pairs)
        entries, d = self.entries[..., part], self.d[:, part]
        x, y = d
        s_a, s_b, s_c = self.v @ entries  # S = sum_c v_c A_c
        det = s_a * s_c - s_b * s_b
        inverse = (s_c / det, -s_b / det, s_a / det)
        quadratic = inverse[0] * x * x + 2 * inverse[1] * x * y + inverse[2] * y * y
        density = np.exp(-0.5 * quadratic) / (2 * np.pi * np.sqrt(det))
        inlier = self.inlier_share * density
        weight = inlier / (inlier + (1.0 - self.inlier_share) * self.outlier_density)
        score, information = fisher_terms(d, entries, inverse, weight)
        sums = (weight.sum(), score, information)
        self._sums = tuple(a + b for a, b in zip(self._sums, sums, strict=True))
        self._at += pairs
        if self._at < self.pairs:
            return False
        weight_sum, score, information = self._sums
        information = information + 1e-9 * np.trace(information) * np.eye(len(self.v))
        self.v = np.clip(self.v + np.linalg.solve(information, score), *self.bounds)
        self.inlier_share = float(weight_sum / self.pairs)
        self._at, self._sums = 0, (0.0, 0.0, 0.0)
        self.done += 1
        return True


class Anchors:
    """Per object, one robot's earlier sighting of it, kept until the robot's drift since
    then outweighs the detection noise (both as scaled so far): paired with the sighting
    that ripens it, it measures that drift. Consecutive sightings, a frame apart, share
    most of their detection error and measure none: on Victoria Park every pair was one of
    those and the heading factor stayed ~1 where the log's heading sigma is ~9x too small.
    A sighting after a long absence, the drift since over ANCHOR_SPAN times the detection
    noise, anchors afresh without a pair: over such a span a real robot's drift is mostly
    bias (a steering offset bends the path, its error growing with the square of the
    distance, not a random walk's root), and a random walk fitted to it takes a larger
    factor the longer the span (Victoria Park's heading: 13.3 with no bound on the span,
    9.4 with 30x, 7.2 with 10x; the hand tuning found 7).
    An object's anchor sits in slot id % slots: memory bounded at any field size, and a
    collision only delays a pair."""

    def __init__(self, slots: int) -> None:
        self.ids = np.full(slots, -1, dtype=np.int64)
        self.robot = np.zeros(slots, dtype=np.int64)
        self.xy = np.zeros((slots, 2))
        self.cov = np.zeros((slots, 2, 2))
        self.drift = np.zeros((slots, 3, 3, 3))

    def pair(
        self,
        ids: np.ndarray,
        robot: int,
        frame: tuple[np.ndarray, np.ndarray, np.ndarray],
        scale: NoiseScale,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sightings of objects `ids` (n,) by `robot` now (`frame`: xy, cov, drift as
        `pair_components` takes them) against their anchors: d, the components and which
        pairs are ripe. The ripe ones and those without an anchor anchor here now."""
        xy, cov, drift = frame
        slot = ids % len(self.ids)
        held = (self.ids[slot] == ids) & (self.robot[slot] == robot)
        d, comps = pair_components(xy, cov, drift, self.xy[slot], self.cov[slot], self.drift[slot])
        traces = np.trace(comps, axis1=2, axis2=3) * scale.variance  # (n, 3) scaled terms
        drifted = traces[:, 1:].sum(axis=1)
        stale = held & (drifted > ANCHOR_SPAN * traces[:, 0])
        ripe = held & (drifted >= traces[:, 0]) & ~stale
        renew = ~held | ripe | stale
        at = slot[renew]
        self.ids[at], self.robot[at], self.drift[at] = ids[renew], robot, drift
        self.xy[at], self.cov[at] = xy[renew], cov[renew]
        return d, comps, ripe


class NoiseCalibration:
    """The running estimate of `NoiseScale` from pairs of sightings (module docstring)."""

    def __init__(self, config: CalibrationConfig, detection_sigma: float = 0.0) -> None:
        """`detection_sigma`: the configured detection noise (its sharpest sigma, m), the
        spread of re-sightings before they show it (`detection_floor`)."""
        self.config = config
        self.detection_sigma = detection_sigma
        self.scale = NoiseScale.configured()
        # the latest `max_pairs` pairs, a ring: row n % max_pairs holds the n-th pair
        self._d = np.empty((config.max_pairs, 2))
        self._components = np.empty((config.max_pairs, len(TERMS), 2, 2))  # R, J dC J^T
        self._new = 0
        self.pairs_seen = 0
        self.pairs_used = 0
        self.updates = 0
        self._scoring: Scoring | None = None  # an estimate under way
        self._anchors = Anchors(ANCHOR_SLOTS)
        self.anchor_pairs = 0  # pairs with an anchor sighting (`Anchors`)
        self._spread: deque[float] = deque(maxlen=SPREAD_PAIRS)  # pairs a frame apart: |d|
        self._spread_sigma: float | None = None  # their spread's sigma, None: to compute

    @property
    def enabled(self) -> bool:
        return self.config.enabled

    def observe(
        self,
        frame: tuple[np.ndarray, np.ndarray, np.ndarray],
        robot: int,
        objects: np.ndarray,
        last: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        chosen: np.ndarray,
        dist: np.ndarray,
    ) -> None:
        """A frame of robot `robot` (index): its detections `frame` (xy, cov, drift:
        `pair_components`'s first arguments) with the k `objects` around them, the
        robot's `last` sightings of those (known, xy, cov, drift as objects.Sightings),
        which object the association `chosen` for each detection ((m, k) bool) and the
        map-frame distances `dist` (m, k) between them.

        A detection pairs with its object's last sighting by the robot where their
        difference is `ratio` times shorter than the distance from the detection to any
        other object around, and with the object's anchor (`Anchors`) where, in the map,
        the detection is `ratio` times nearer its object than any other: two tests free of
        any noise scale (the anchor's by the map, since its difference is mostly drift,
        and a test on it would keep only the pairs the drift left short)."""
        if not self.enabled or len(frame[0]) == 0 or len(objects) == 0:
            return
        i, j = np.nonzero(chosen)
        if len(i) == 0:
            return
        xy, cov, drift = frame[0][i], frame[1][i], frame[2]
        spacing = self.config.ratio * nearest_other(dist)[i, j]
        known, *last_seen = last
        known = known[j]
        seen = [column[j[known]] for column in last_seen]
        d, comps = pair_components(xy[known], cov[known], drift, *seen)
        apart = np.linalg.norm(d, axis=1)
        short = apart <= spacing[known]
        if short.any():
            self._spread.extend(apart[short].tolist())
            self._spread_sigma = None
        d_a, comps_a, ripe = self._anchors.pair(objects[j], robot, (xy, cov, drift), self.scale)
        sure = ripe & (dist[i, j] <= spacing)
        self.anchor_pairs += int(sure.sum())
        self.add_pairs(
            np.concatenate([d[short], d_a[sure]]), np.concatenate([comps[short], comps_a[sure]])
        )

    def add_pairs(self, d: np.ndarray, components: np.ndarray) -> None:
        """Pairs of sightings: differences d (n, 2) and their covariance components
        (n, 3, 2, 2), unscaled; the estimate is renewed every `update_every` pairs, over
        the pairs kept then, one iteration a call, each iteration's factors used at once."""
        if not self.enabled or len(d) == 0:
            return
        keep = self.config.max_pairs
        rows = (self.pairs_seen + np.arange(len(d))[-keep:]) % keep
        self._d[rows], self._components[rows] = d[-keep:], components[-keep:]
        self._new += len(d)
        self.pairs_seen += len(d)
        if self._scoring is None:
            if self.pairs_kept < self.config.min_pairs or self._new < self.config.update_every:
                return
            self._new = 0
            self._scoring = self._start(self.scale.variance)
        # an iteration in parts, a part a call: no step pays for a whole estimate, which
        # ends where one computed at once does
        if not self._scoring.advance(PAIRS_A_CALL):
            return
        self.scale = NoiseScale(self._factors(self._scoring))
        if self._scoring.done == FISHER_ITERATIONS:
            self._scoring = None
            self.updates += 1

    def detection_floor(self, covs: np.ndarray) -> np.ndarray:
        """(m,) the variance (m^2) to raise each detection of configured covariance `covs`
        (m, 2, 2) to: the spread of re-sightings a frame apart (as one sighting's sigma,
        isotropic; before MIN_SPREAD_PAIRS pairs, `detection_sigma`) where the detection's
        largest sigma, as scaled, is CONTRADICTED times below it; 0 elsewhere."""
        if not self.enabled:
            return np.zeros(len(covs))
        sigma = self.detection_sigma
        if len(self._spread) >= MIN_SPREAD_PAIRS:
            if self._spread_sigma is None:
                self._spread_sigma = float(np.median(self._spread)) / RAYLEIGH_MEDIAN
            sigma = self._spread_sigma
        claimed = self.scale.variance[0] * np.linalg.eigvalsh(covs)[:, -1]
        return np.where(claimed * CONTRADICTED**2 < sigma**2, sigma**2, 0.0)

    @property
    def pairs_kept(self) -> int:
        return min(self.pairs_seen, self.config.max_pairs)

    def estimate(self, start: np.ndarray) -> np.ndarray:
        """ML variance factors over the pairs kept, with the pairs that no noise explains
        (a wrong association, a moved object) as a uniform outlier component: EM over
        the pairs' share of each, Fisher scoring of the factors, from `start`."""
        scoring = self._start(start)
        while scoring.done < FISHER_ITERATIONS:
            scoring.advance(PAIRS_A_CALL)
        return self._factors(scoring)

    def _start(self, start: np.ndarray) -> Scoring:
        """An estimate from `start` over (a copy of) the pairs kept now."""
        d, comps = self._d[: self.pairs_kept], self._components[: self.pairs_kept]
        v = start.copy()
        if self.config.tie_odometry:  # one factor on the chain's translation and heading
            comps = np.stack([comps[:, 0], comps[:, 1] + comps[:, 2]], axis=1)
            v = start[:2].copy()
        outlier_density = 1.0 / (np.pi * max(float(np.max(np.sum(d * d, axis=1))), 1e-12))
        bounds = tuple(b**2 for b in self.config.sigma_bounds)
        return Scoring(d.T.copy(), entries(comps), start.copy(), v, bounds, outlier_density)

    def _factors(self, scoring: Scoring) -> np.ndarray:
        """The variance factors (3,) an estimate gives after its iterations so far."""
        v, start = scoring.v, scoring.start
        if self.config.tie_odometry:
            v = np.array([v[0], v[1], v[1]])
        # one estimate moves a sigma by at most MAX_STEP: a burst of odd pairs cannot
        # throw the gates that the next pairs are drawn through
        v = np.clip(v, start / MAX_STEP**2, start * MAX_STEP**2)
        self.pairs_used = round(scoring.inlier_share * scoring.pairs)
        return v

    def report(self) -> dict[str, object]:
        """The estimated sigma factors and what they rest on, for the summary and metrics."""
        return {
            "enabled": self.enabled,
            "sigma_factors": self.scale.as_dict(),
            "pairs_seen": self.pairs_seen,
            "pairs_used": self.pairs_used,
            "updates": self.updates,
            "anchor_pairs": self.anchor_pairs,
        }


def mahalanobis(d: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(...) d^T cov^-1 d of 2-vectors (..., 2) with their 2x2 covariances (closed form)."""
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    x, y = d[..., 0], d[..., 1]
    return (c * x * x - 2 * b * x * y + a * y * y) / (a * c - b * b)


def entries(comps: np.ndarray) -> np.ndarray:
    """(3, C, n) the xx, xy and yy entries of symmetric 2x2 components (n, C, 2, 2), each
    row contiguous: an estimate's arithmetic over `max_pairs` pairs runs along rows."""
    return np.ascontiguousarray(
        np.stack([comps[..., 0, 0], comps[..., 0, 1], comps[..., 1, 1]]).transpose(0, 2, 1)
    )


def fisher_terms(
    d: np.ndarray,
    entries: np.ndarray,
    inverse: tuple[np.ndarray, np.ndarray, np.ndarray],
    weight: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The score and information of a Fisher-scoring step of the variance components v
    of Cov(d) = sum_c v_c A_c over weighted pairs: g_c = 1/2 sum w (d^T S^-1 A_c S^-1 d -
    tr(S^-1 A_c)) and F_cb = 1/2 sum w tr(S^-1 A_c S^-1 A_b), S = sum_c v_c A_c; the
    step is F^-1 g. On the entries of the symmetric 2x2 matrices: `d` (2, n), the A_c's
    `entries` (3, C, n) and S^-1's (xx, xy, yy), each a row of n."""
    a, b, c = entries  # (C, n) each
    p, q, r = inverse
    x0, x1 = p * d[0] + q * d[1], q * d[0] + r * d[1]  # S^-1 d
    quadratic = a * (x0 * x0) + 2 * b * (x0 * x1) + c * (x1 * x1)
    m00, m01, m10, m11 = p * a + q * b, p * b + q * c, q * a + r * b, q * b + r * c  # S^-1 A_c
    score = 0.5 * (quadratic - m00 - m11) @ weight
    information = (weight * m00) @ m00.T + (weight * m01) @ m10.T + (weight * m10) @ m01.T
    return score, 0.5 * (information + (weight * m11) @ m11.T)


def pair_components(
    xy: np.ndarray,
    cov: np.ndarray,
    drift: np.ndarray,
    seen_xy: np.ndarray,
    seen_cov: np.ndarray,
    seen_drift: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of sightings of n objects by one robot: d (n, 2) = p_now - p_then and the
    components (n, 3, 2, 2) of its covariance (module docstring). `xy`, `cov`: the
    detections now in the robot's dead-reckoning frame, configured; `drift`: its chain's
    drift parts now (3, 3, 3); `seen_*`: the same when it saw each object before."""
    jac = se2.point_jacobian(xy)  # (n, 2, 3)
    parts = drift[None, :2] - seen_drift[:, :2]  # (n, 2, 3, 3) translation, heading
    comps = np.empty((len(xy), len(TERMS), 2, 2))
    comps[:, 0] = cov + seen_cov
    comps[:, 1:] = np.einsum("nij,npjk,nlk->npil", jac, parts, jac)
    return xy - seen_xy, comps


def nearest_other(dist: np.ndarray) -> np.ndarray:
    """(m, k): for each entry of the distances `dist` (m, k) from m points to k objects,
    the distance from that point to its nearest object other than that one."""
    order = np.sort(dist, axis=1)
    second = order[:, 1] if dist.shape[1] > 1 else np.full(len(dist), np.inf)
    nearest = dist == order[:, :1]
    return np.where(nearest, second[:, None], order[:, :1])
