"""Point landmarks of the arena scenario: single ones and tight clusters (pairs, triples) whose
members stand 0.15-0.2 m from their nearest neighbour, the groups well apart."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist

from agrislam.sim.arena_config import ArenaLayout

MAX_TRIES = 10_000  # draws per group before the layout is declared too crowded


@dataclass(frozen=True, slots=True)
class Landmarks:
    """The arena's landmarks (struct of arrays); `group` numbers the clusters first, then the
    singles, so landmarks sharing a group stand within a cluster spacing of each other."""

    ids: list[str]
    xy: np.ndarray  # (n, 2) map frame
    group: np.ndarray  # (n,) int

    def __len__(self) -> int:
        return len(self.ids)


def cluster_shape(n: int, spacing: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """n points around the origin, each `spacing` (uniform) from a random earlier one and no
    nearer than spacing[0] to any: every point's nearest neighbour lies within the spacing."""
    lo, hi = spacing
    pts = [np.zeros(2)]
    for _ in range(MAX_TRIES):
        anchor = pts[rng.integers(len(pts))]
        angle, dist = rng.uniform(-np.pi, np.pi), rng.uniform(lo, hi)
        p = anchor + dist * np.array([np.cos(angle), np.sin(angle)])
        if np.linalg.norm(np.array(pts) - p, axis=1).min() >= lo:
            pts.append(p)
        if len(pts) == n:
            break
    if len(pts) < n:
        raise ValueError(f"could not place a cluster of {n} at spacing {spacing}")
    shape = np.array(pts)
    return shape - shape.mean(axis=0)


def clustered_landmarks(layout: ArenaLayout, rng: np.random.Generator) -> Landmarks:
    """Clusters, then singles, each group dropped at a uniform place inside the wall margin
    and redrawn while it comes nearer than `separation` to a landmark already placed."""
    sizes = [*layout.clusters, *([1] * layout.single_landmarks)]
    half = np.asarray(layout.size, float) / 2 - layout.wall_margin
    placed: list[np.ndarray] = []
    groups: list[np.ndarray] = []
    for g, n in enumerate(sizes):
        shape = cluster_shape(n, layout.cluster_spacing, rng) if n > 1 else np.zeros((1, 2))
        for _ in range(MAX_TRIES):
            xy = shape + rng.uniform(-half, half)
            inside = (np.abs(xy) <= half).all()
            if inside and (not placed or cdist(xy, np.vstack(placed)).min() >= layout.separation):
                break
        else:
            raise ValueError(
                f"{len(sizes)} landmark groups do not fit {layout.separation} m apart in an "
                f"arena of {layout.size} m"
            )
        placed.append(xy)
        groups.append(np.full(n, g))
    xy = np.vstack(placed)
    return Landmarks([f"L{k + 1:02d}" for k in range(len(xy))], xy, np.concatenate(groups))
