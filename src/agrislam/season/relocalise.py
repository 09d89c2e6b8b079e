"""Where the robot is in a saved map, from its first frames: their detections, placed by dead
reckoning and clustered into plants, are registered to the saved plants by pairwise-distance
consistency (a RANSAC over SE(2) whose samples are pairs of the same distance).

Each hypothesis is refined on its matches and scored by a Gaussian kernel of the residuals,
the attributes' beliefs a compatibility check. A fix is given only when the best hypothesis
fits as well as a right one would (a chi^2 test against the predicted spread), explains most
plants, and the second-best distinct one scores clearly less: crop rows are periodic, a
shift by one plant or one row is the trap, and a wrong fix merges a survey into the wrong
place."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import chi2

from agrislam.config import SeasonConfig
from agrislam.geometry import se2

PRESCORE_POINTS = 10  # first-frames plants a hypothesis is tried on before it is refined
REFINED = 60  # hypotheses refined and scored on every plant
BASE_PAIRS = 6  # first-frames pairs that vote
BASE_DISTANCE = (1.0, 4.0)  # m: pairs shorter are not distinctive, longer cost too much
DISTANCE_TOL = 0.06  # m: pair distances agree within detection noise and drift
DISTINCT = (0.3, 0.05)  # (m, rad): hypotheses closer than this are the same one
FIT_CONFIDENCE = 0.99  # a right place's residuals pass the chi^2 fit test this often


@dataclass(frozen=True, slots=True)
class Fix:
    """The outcome of a try: `transform` (map <- dead-reckoning frame) when localised,
    else None with `reason` ("not localised yet: ..."); the evidence either way."""

    transform: np.ndarray | None
    reason: str
    n_plants: int
    n_inliers: int = 0
    score: float = 0.0
    second_score: float = 0.0
    cov: np.ndarray | None = None  # 3x3 of the transform (x, y, theta)

    @property
    def localised(self) -> bool:
        return self.transform is not None


def cluster(xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detections closer than `radius` (transitively) are one plant: (k, 2) means, (k,)
    detection counts, (n,) the cluster of each detection."""
    if len(xy) == 0:
        return np.empty((0, 2)), np.empty(0, dtype=int), np.empty(0, dtype=int)
    pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xy),) * 2)
    k, label = connected_components(graph, directed=False)
    counts = np.bincount(label, minlength=k)
    means = np.column_stack([np.bincount(label, xy[:, d], k) for d in (0, 1)]) / counts[:, None]
    return means, counts, label


def detection_spread(xy: np.ndarray, means: np.ndarray, counts: np.ndarray, label) -> float:
    """Per-axis variance of one detection about its plant, pooled over the plants seen
    more than once (each plant's mean costs 2 degrees of freedom); 0 with none."""
    many = counts[label] >= 2
    dof = 2 * (int(many.sum()) - int((counts >= 2).sum()))
    if dof <= 0:
        return 0.0
    return float(np.sum((xy[many] - means[label[many]]) ** 2) / dof)


def rigid_fit(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Least-squares SE(2) (x, y, theta) taking `src` onto `dst` (2-D Kabsch)."""
    w = np.ones(len(src)) if weights is None else weights
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    a, b = src - cs, dst - cd
    cross = w @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    dot = w @ (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    theta = np.arctan2(cross, dot)
    c, s = np.cos(theta), np.sin(theta)
    t = cd - np.array([c * cs[0] - s * cs[1], s * cs[0] + c * cs[1]])
    return np.array([t[0], t[1], theta])


def _apply(transforms: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(h, m, 2): each transform (h, 3) applied to the points (m, 2)."""
    c, s = np.cos(transforms[:, 2])[:, None], np.sin(transforms[:, 2])[:, None]
    x = c * xy[None, :, 0] - s * xy[None, :, 1] + transforms[:, 0, None]
    y = s * xy[None, :, 0] + c * xy[None, :, 1] + transforms[:, 1, None]
    return np.stack([x, y], axis=-1)


@dataclass(frozen=True, slots=True)
class _Refined:
    """A refined hypothesis: its transform, the matched plants' residuals (m), and which
    first-frames plants (`local` rows) matched which saved ones (`saved` rows)."""

    transform: np.ndarray
    d: np.ndarray
    local: np.ndarray
    saved: np.ndarray


class Relocaliser:
    """Registration of first-frames plants against the saved map's plants.

    `compatible(local_rows, map_ids)` -> (k,) bool says whether first-frames plant and
    saved plant may be the same by their attributes (None: every pair may); `map_var`
    (k,) the per-axis variance of each saved plant's position (None: exact)."""

    def __init__(
        self,
        map_xy: np.ndarray,
        cfg: SeasonConfig,
        compatible=None,
        map_var: np.ndarray | None = None,
    ) -> None:
        self.map_xy = np.asarray(map_xy, dtype=float).reshape(-1, 2)
        self.map_var = np.zeros(len(self.map_xy)) if map_var is None else np.asarray(map_var)
        self.cfg = cfg
        self.compatible = compatible
        self.tree = cKDTree(self.map_xy)
        pairs = self.tree.query_pairs(BASE_DISTANCE[1] + DISTANCE_TOL, output_type="ndarray")
        d = np.linalg.norm(self.map_xy[pairs[:, 0]] - self.map_xy[pairs[:, 1]], axis=1)
        keep = d >= BASE_DISTANCE[0] - DISTANCE_TOL
        order = np.argsort(d[keep])
        self._pairs, self._pair_d = pairs[keep][order], d[keep][order]

    def locate(self, local_xy: np.ndarray, counts: np.ndarray, spread: float = 0.0) -> Fix:
        """Try to place the first-frames plants (k, 2) (dead-reckoning frame, `counts`
        detections each, `spread` the per-axis variance of one detection about its plant:
        `detection_spread`) in the map."""
        cfg = self.cfg
        keep = counts >= 2  # a plant seen once may be clutter
        local_xy, counts = local_xy[keep], counts[keep]
        local_ids = np.flatnonzero(keep)
        n = len(local_xy)
        if n < cfg.min_landmarks or len(self.map_xy) < cfg.min_landmarks:
            return Fix(None, f"not localised yet: {n} plants seen, {cfg.min_landmarks} needed", n)
        hyps = self._hypotheses(local_xy, counts)
        if len(hyps) == 0:
            return Fix(None, "not localised yet: no saved plants at the first plants' distances", n)
        hyps = self._prescored(hyps, local_xy)
        refined = [self._refine(h, local_xy, local_ids) for h in hyps]
        # the kernel's width is the best fit's own residual: a hypothesis shifted by one
        # plant has residuals of the spacing jitter, the right one of the detection noise
        first = max(range(len(refined)), key=lambda k: _score(refined[k].d, cfg.score_sigma))
        sigma = float(
            np.clip(
                _rms(refined[first].d, cfg.inlier_radius), 0.25 * cfg.score_sigma, cfg.score_sigma
            )
        )
        scores = np.array([_score(h.d, sigma) for h in refined])
        order = np.argsort(-scores)
        top = refined[order[0]]
        best_t, d_best = top.transform, top.d
        best, inliers = float(scores[order[0]]), int((d_best < cfg.inlier_radius).sum())
        second = 0.0
        for i in order[1:]:
            if _distinct(refined[i].transform, best_t, local_xy):
                second = float(scores[i])
                break
        fix = dict(n_plants=n, n_inliers=inliers, score=best, second_score=second)
        # each matched pair differs by the first frames' mean (spread / detections) and
        # the saved plant's error: a right fit's normalised residuals are chi^2, 2 per
        # match less the transform's 3
        inside = d_best < cfg.inlier_radius
        var = spread / counts[top.local[inside]] + self.map_var[top.saved[inside]]
        dof = 2 * int(inside.sum()) - 3
        if dof <= 0 or np.sum(d_best[inside] ** 2 / np.maximum(var, 1e-12)) > chi2.ppf(
            FIT_CONFIDENCE, dof
        ):
            rms = _rms(d_best, cfg.inlier_radius)
            expected = np.sqrt(2.0 * np.mean(var)) if len(var) else np.nan  # nan: no match
            why = f"the best place fits only to {rms:.3f} m ({expected:.3f} m expected)"
            return Fix(None, f"not localised yet: {why}", **fix)
        if inliers < cfg.min_landmarks or inliers < cfg.min_inlier_fraction * n:
            why = f"{inliers} of {n} plants match the best place"
            return Fix(None, f"not localised yet: {why}", **fix)
        if second > cfg.max_ambiguity * best:
            why = f"two places fit (scores {best:.1f} and {second:.1f})"
            return Fix(None, f"not localised yet: {why}", **fix)
        spread = np.mean(np.sum((local_xy - local_xy.mean(axis=0)) ** 2, axis=1))
        cov = np.diag([sigma**2 / inliers] * 2 + [sigma**2 / (inliers * max(spread, 1e-6))])
        return Fix(best_t, "localised", cov=cov, **fix)

    # ------------------------------------------------------------------ the steps
    def _hypotheses(self, local_xy: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """(h, 3) transforms voted by the base pairs through saved pairs of their length."""
        out = []
        for i, j in _base_pairs(local_xy, counts):
            d = np.linalg.norm(local_xy[j] - local_xy[i])
            lo, hi = np.searchsorted(self._pair_d, [d - DISTANCE_TOL, d + DISTANCE_TOL])
            pairs = self._pairs[lo:hi]
            if not len(pairs):
                continue
            both = np.vstack([pairs, pairs[:, ::-1]])  # a saved pair matches either way round
            a, b = self.map_xy[both[:, 0]], self.map_xy[both[:, 1]]
            local_angle = np.arctan2(*(local_xy[j] - local_xy[i])[::-1])
            theta = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0]) - local_angle
            mid_local = 0.5 * (local_xy[i] + local_xy[j])
            c, s = np.cos(theta), np.sin(theta)
            rotated = np.column_stack(
                [c * mid_local[0] - s * mid_local[1], s * mid_local[0] + c * mid_local[1]]
            )
            out.append(np.column_stack([0.5 * (a + b) - rotated, theta]))
        return np.vstack(out) if out else np.empty((0, 3))

    def _prescored(self, hyps: np.ndarray, local_xy: np.ndarray) -> np.ndarray:
        """The hypotheses whose matches among a few spread plants are most."""
        probe = local_xy[np.linspace(0, len(local_xy) - 1, PRESCORE_POINTS).astype(int)]
        moved = _apply(hyps, probe)
        d, _ = self.tree.query(moved.reshape(-1, 2), distance_upper_bound=self.cfg.inlier_radius)
        hits = np.isfinite(d).reshape(len(hyps), -1).sum(axis=1)
        return hyps[np.argsort(-hits, kind="stable")[:REFINED]]

    def _refine(
        self, transform: np.ndarray, local_xy: np.ndarray, local_ids: np.ndarray
    ) -> _Refined:
        """Two rounds of matching and refitting; the matched plants' residuals (m)."""
        cfg = self.cfg
        none = np.empty(0, dtype=np.int64)
        for _ in range(2):
            moved = _apply(transform[None], local_xy)[0]
            d, j = self.tree.query(moved, distance_upper_bound=2.0 * cfg.inlier_radius)
            match = np.isfinite(d)
            if self.compatible is not None and match.any():
                ok = self.compatible(local_ids[match], j[match])
                match[np.flatnonzero(match)[~ok]] = False
            if match.sum() < 3:
                return _Refined(transform, np.empty(0), none, none)
            transform = rigid_fit(local_xy[match], self.map_xy[j[match]])
        moved = _apply(transform[None], local_xy)[0]
        d = np.linalg.norm(moved[match] - self.map_xy[j[match]], axis=1)
        return _Refined(transform, d, np.flatnonzero(match), j[match])


def _base_pairs(local_xy: np.ndarray, counts: np.ndarray) -> list[tuple[int, int]]:
    """Up to BASE_PAIRS pairs of the most-seen plants, distances in BASE_DISTANCE, no plant
    twice (a base plant that is new or gone spoils only its own pairs)."""
    order = np.argsort(-counts, kind="stable")
    used: set[int] = set()
    pairs = []
    for i in order.tolist():
        if i in used:
            continue
        d = np.linalg.norm(local_xy - local_xy[i], axis=1)
        ok = (d >= BASE_DISTANCE[0]) & (d <= BASE_DISTANCE[1])
        for j in order[ok[order]].tolist():
            if j not in used and j != i:
                pairs.append((i, j))
                used.update((i, j))
                break
        if len(pairs) == BASE_PAIRS:
            break
    return pairs


def _distinct(a: np.ndarray, b: np.ndarray, local_xy: np.ndarray) -> bool:
    """Whether two transforms place the first-frames plants differently (at their centre)."""
    centre = local_xy.mean(axis=0)
    shift = np.linalg.norm(
        se2.compose(a, np.r_[centre, 0.0])[:2] - se2.compose(b, np.r_[centre, 0.0])[:2]
    )
    turn = abs(np.remainder(a[2] - b[2] + np.pi, 2 * np.pi) - np.pi)
    return bool(shift > DISTINCT[0] or turn > DISTINCT[1])


def _score(residuals: np.ndarray, sigma: float) -> float:
    """Gaussian kernel score of a hypothesis' residuals."""
    return float(np.exp(-0.5 * (residuals / sigma) ** 2).sum())


def _rms(residuals: np.ndarray, radius: float) -> float:
    """RMS of the residuals within the inlier radius (inf with fewer than 3)."""
    inside = residuals[residuals < radius]
    return float(np.sqrt(np.mean(inside**2))) if len(inside) >= 3 else np.inf
