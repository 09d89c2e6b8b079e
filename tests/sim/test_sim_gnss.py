"""The simulated GNSS receiver (sim/gnss.py): fix types in runs with their sigmas,
outages of the configured share and length, multipath jumps, and fixes in time order."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.geometry.geodesy import MapFrame
from agrislam.geometry.se2 import compose
from agrislam.records import Anchor, Detections, GnssFix, Odometry
from agrislam.sim.config import SimConfig
from agrislam.sim.gnss import outage_mask, robot_fixes
from agrislam.sim.gnss_config import GnssSimConfig
from agrislam.sim.simulator import Simulator

ANCHOR = Anchor(51.4488, 5.4905, 20.0, 15.0)


def drive(n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * 1.0
    poses = np.column_stack([0.4 * t, np.zeros(n), np.full(n, 0.3)])
    return t, poses


def errors(fixes: list[GnssFix], t: np.ndarray, poses: np.ndarray, antenna) -> np.ndarray:
    frame = MapFrame(ANCHOR)
    at = np.searchsorted(t, [f.t for f in fixes])
    measured = frame.to_map([f.lat for f in fixes], [f.lon for f in fixes], ANCHOR.h)[:, :2]
    lever = np.array([antenna[0], antenna[1], 0.0])
    truth = np.array([compose(p, lever)[:2] for p in poses[at]])
    return np.linalg.norm(measured - truth, axis=1)


def test_fix_types_have_their_sigmas_and_shares() -> None:
    cfg = GnssSimConfig(fraction={"rtk_fixed": 0.7, "rtk_float": 0.3}, run_s=10.0)
    t, poses = drive()
    fixes = robot_fixes("r1", t, poses, MapFrame(ANCHOR), cfg, np.random.default_rng(0))
    assert len(fixes) == len(t)
    kinds = np.array([f.fix for f in fixes])
    assert np.mean(kinds == "rtk_fixed") == pytest.approx(0.7, abs=0.08)
    err = errors(fixes, t, poses, cfg.antenna)
    # horizontal error of a 2D Gaussian of sigma s: RMS s sqrt(2)
    for kind in ("rtk_fixed", "rtk_float"):
        rms = np.sqrt(np.mean(err[kinds == kind] ** 2))
        assert rms == pytest.approx(cfg.sigma[kind] * np.sqrt(2), rel=0.1)
        (cov,) = {f.cov[0, 0] for f in fixes if f.fix == kind}
        assert cov == pytest.approx(cfg.sigma[kind] ** 2)
    runs = np.flatnonzero(kinds[1:] != kinds[:-1]) + 1  # a type holds for whole runs
    assert np.all(t[runs] % cfg.run_s == 0)


def test_outages_take_their_share_in_minutes() -> None:
    cfg = GnssSimConfig(outage_fraction=0.3, outage_s=180.0)
    t, _ = drive(6000)
    mask = outage_mask(t, cfg, np.random.default_rng(1))
    assert mask.mean() == pytest.approx(0.3, abs=0.01)
    starts = np.flatnonzero(mask[1:] & ~mask[:-1])
    assert len(starts) == 10  # 1800 s in outages of 180 s


def test_multipath_jumps_are_metres_and_not_admitted() -> None:
    cfg = GnssSimConfig(fraction={"rtk_fixed": 1.0}, multipath_fraction=0.05)
    t, poses = drive()
    fixes = robot_fixes("r1", t, poses, MapFrame(ANCHOR), cfg, np.random.default_rng(2))
    err = errors(fixes, t, poses, cfg.antenna)
    jumped = err > 1.0
    assert jumped.mean() == pytest.approx(0.05, abs=0.015)
    assert err[jumped].min() >= cfg.multipath_m[0] - 0.1 and err[jumped].max() <= 8.1
    assert all(f.cov[0, 0] == pytest.approx(0.02**2) for f in fixes)


def test_the_simulator_puts_fixes_after_odometry_before_frames() -> None:
    cfg = SimConfig.model_validate(
        {"field": {"n_plants": 40, "n_rows": 2}, "gnss": {"rate_hz": 1.0}}
    )
    records = list(Simulator(cfg).records())
    fixes = [i for i, r in enumerate(records) if isinstance(r, GnssFix)]
    assert len(fixes) > 10
    for i in fixes:
        fix, before, after = records[i], records[i - 1], records[i + 1]
        assert isinstance(before, Odometry) and before.t == fix.t
        assert isinstance(after, Detections) and after.t == fix.t
