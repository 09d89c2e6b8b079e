"""Random drives in the arena: straight legs to random waypoints that keep off the walls and
the landmarks, gentle corners rounded, sharp ones turned on the spot, each segment at its
own speed. As MRCLAM's robots did: "robots move to random waypoints"."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrislam.sim.arena_config import ArenaDriving
from agrislam.sim.path import SurveyPath, rounded_polyline

CANDIDATES = 64  # waypoints drawn at once; the first acceptable one is taken
MAX_ROUNDS = 1_000


@dataclass(frozen=True, slots=True)
class TimedPath:
    """A path driven at a speed of its own on each segment."""

    path: SurveyPath
    t_end: np.ndarray  # (k,) time at the end of each segment, s

    @property
    def duration(self) -> float:
        return float(self.t_end[-1])

    def sample(self, t: np.ndarray) -> np.ndarray:
        """Poses (m, 3) at times t (s from the start), vectorised."""
        d_end = np.cumsum(self.path.seg_length)
        return self.path.at_distance(np.interp(t, np.r_[0.0, self.t_end], np.r_[0.0, d_end]))


def segment_distance(a: np.ndarray, b: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(m, n) distance from each segment a[i] -> b[i] (m, 2) to each point (n, 2)."""
    ab = (b - a)[:, None, :]
    ap = points[None, :, :] - a[:, None, :]
    length2 = np.maximum(np.sum(ab * ab, axis=2), 1e-12)
    u = np.clip(np.sum(ap * ab, axis=2) / length2, 0.0, 1.0)
    return np.linalg.norm(ap - u[:, :, None] * ab, axis=2)


def random_waypoints(
    cfg: ArenaDriving,
    size: tuple[float, float],
    obstacles: np.ndarray,
    length: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Waypoints inside the wall margin whose legs are at least `min_leg` long and keep
    `landmark_clearance` from every obstacle, until the legs add up to `length` metres."""
    half = np.asarray(size, float) / 2 - cfg.wall_margin
    obstacles = np.asarray(obstacles, float).reshape(-1, 2)
    points: list[np.ndarray] = []
    total, fails = 0.0, 0
    while not points or total < length:
        cand = rng.uniform(-half, half, (CANDIDATES, 2))
        here = points[-1] if points else cand  # the start: a point clear of the landmarks
        ok = np.linalg.norm(cand - here, axis=1) >= (cfg.min_leg if points else 0.0)
        if len(obstacles):
            start = np.broadcast_to(here, cand.shape)
            ok &= segment_distance(start, cand, obstacles).min(axis=1) >= cfg.landmark_clearance
        good = np.flatnonzero(ok)
        if len(good) == 0:
            fails += 1
            if fails > MAX_ROUNDS:
                raise ValueError("no room for a random drive: lower the clearance or margin")
            continue
        fails = 0
        nxt = cand[good[0]]
        total += float(np.linalg.norm(nxt - points[-1])) if points else 0.0
        points.append(nxt)
    return np.array(points)


def random_drive(
    cfg: ArenaDriving,
    size: tuple[float, float],
    obstacles: np.ndarray,
    duration: float,
    rng: np.random.Generator,
) -> TimedPath:
    """A drive lasting at least `duration` seconds: random waypoints, corners sharper than
    `spin_turn_deg` turned on the spot, a uniform speed per segment."""
    # at the top speed the legs last length / v_max; rounded corners shorten them a little
    need = duration * cfg.speed[1] + cfg.min_leg
    while True:
        points = random_waypoints(cfg, size, obstacles, need, rng)
        path = rounded_polyline(points, cfg.turn_radius, np.deg2rad(cfg.spin_turn_deg))
        speed = rng.uniform(*cfg.speed, len(path.seg_length))
        timed = TimedPath(path, np.cumsum(path.seg_length / speed))
        if timed.duration >= duration:
            return timed
        need *= 1.5
