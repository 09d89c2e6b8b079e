"""A simulated GNSS receiver: fixes of the antenna at the robot's true pose,
with fix types in runs (RTK fixed, float, ...), outages of minutes, and multipath jumps of
metres that the receiver does not admit in its covariance."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from agrislam.geometry.geodesy import MapFrame
from agrislam.geometry.se2 import compose
from agrislam.records import Anchor, Detections, GnssFix, Record
from agrislam.sim.gnss_config import GnssSimConfig


def outage_mask(t: np.ndarray, cfg: GnssSimConfig, rng: np.random.Generator) -> np.ndarray:
    """(m,) True where t falls in an outage: `outage_fraction` of the span of t in outages
    of about `outage_s` each, at random places between its start and end."""
    if cfg.outage_fraction <= 0.0 or len(t) < 2:
        return np.zeros(len(t), dtype=bool)
    span = float(t[-1] - t[0])
    total = cfg.outage_fraction * span
    n = max(1, round(total / cfg.outage_s))
    gaps = rng.dirichlet(np.ones(n + 1)) * (span - total)  # the fix time around the outages
    starts = t[0] + np.cumsum(gaps[:-1]) + np.arange(n) * total / n
    inside = (t[:, None] >= starts) & (t[:, None] < starts + total / n)
    return inside.any(axis=1)


def fix_types(t: np.ndarray, cfg: GnssSimConfig, rng: np.random.Generator) -> np.ndarray:
    """(m,) fix type of each time: one drawn by `fraction` for every run of `run_s`."""
    names = list(cfg.fraction)
    share = np.array([cfg.fraction[n] for n in names], dtype=float)
    run = ((t - t[0]) // cfg.run_s).astype(int)
    drawn = rng.choice(len(names), size=run[-1] + 1, p=share / share.sum())
    return np.array(names, dtype=object)[drawn[run]]


def robot_fixes(
    robot: str,
    t: np.ndarray,
    poses: np.ndarray,
    frame: MapFrame,
    cfg: GnssSimConfig,
    rng: np.random.Generator,
) -> list[GnssFix]:
    """The fixes of one robot following true map-frame `poses` (m, 3) at times t."""
    keep = ~outage_mask(t, cfg, rng)
    kinds = fix_types(t, cfg, rng)
    sigma = np.array([cfg.sigma[k] for k in kinds])
    lever = np.array([cfg.antenna[0], cfg.antenna[1], 0.0])
    antenna = compose(poses.T, lever[:, None]).T[:, :2]
    noisy = antenna + rng.normal(0.0, 1.0, antenna.shape) * sigma[:, None]
    up = cfg.antenna[2] + rng.normal(0.0, 1.0, len(t)) * 2.0 * sigma
    jump = rng.random(len(t)) < cfg.multipath_fraction
    size = rng.uniform(*cfg.multipath_m, size=len(t))
    angle = rng.uniform(-np.pi, np.pi, size=len(t))
    noisy[jump] += (size * np.column_stack([np.cos(angle), np.sin(angle)]).T).T[jump]
    lla = frame.to_wgs84(noisy, up)
    fixes = []
    for k in np.flatnonzero(keep).tolist():
        s2 = float(sigma[k]) ** 2
        fixes.append(
            GnssFix(
                t=float(t[k]),
                robot=robot,
                lat=float(lla[k, 1]),
                lon=float(lla[k, 0]),
                alt=float(lla[k, 2]),
                fix=str(kinds[k]),
                cov=np.diag([s2, s2, 4.0 * s2]),
                antenna=np.array(cfg.antenna, dtype=float),
            )
        )
    return fixes


def every_nth(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the times of t (sorted) nearest to a grid at `rate_hz`, each once."""
    grid = np.arange(t[0], t[-1] + 1e-9, 1.0 / rate_hz)
    idx = np.clip(np.searchsorted(t, grid), 0, len(t) - 1)
    return np.unique(idx)


def with_fixes(
    records: Iterable[Record], fixes: list[GnssFix], robots: list[str]
) -> Iterator[Record]:
    """The records with the fixes in the order a bag's reader gives them: by time, then
    robot (in `robots` order), a fix after its robot's odometry and before its frame."""
    rank = {name: k for k, name in enumerate(robots)}
    fixes = sorted(fixes, key=lambda f: (f.t, rank[f.robot]))
    k = 0
    for rec in records:
        t = getattr(rec, "t", None)
        if t is not None:
            while k < len(fixes) and _before(fixes[k], rec, t, rank):
                yield fixes[k]
                k += 1
        yield rec
    yield from fixes[k:]


def _before(fix: GnssFix, rec: Record, t: float, rank: dict[str, int]) -> bool:
    if fix.t != t:
        return fix.t < t
    mine, theirs = rank[fix.robot], rank.get(getattr(rec, "robot", ""), -1)
    return theirs > mine or (theirs == mine and isinstance(rec, Detections))


def survey_anchor(anchor: Anchor | None) -> Anchor:
    """Where the simulated field lies: the survey's anchor, or the default one."""
    return anchor if anchor is not None else Anchor(51.4488, 5.4905, 20.0, 0.0)
