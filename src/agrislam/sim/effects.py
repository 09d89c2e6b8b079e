"""What a real robot's sensors add to the textbook models (`effects_config.py`), as
functions both simulators share: the depth-like range with its per-robot scale, noise that
grows with range, heavy-tailed bearings, misread labels, blind spells and the odometry's
per-robot turn scale. Each draws only when its effect is on, from the generator it is given,
so a scenario without effects draws exactly what it drew before."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from agrislam.sim.effects_config import CameraEffects, OdometryEffects

MAD_TO_SIGMA = 1.4826  # robust sigma of a Gaussian from its median absolute deviation


@dataclass(frozen=True, slots=True)
class CameraBias:
    """One robot's camera, drawn once: its range scale and its bearing offset."""

    range_scale: float = 1.0
    bearing_offset: float = 0.0

    @classmethod
    def draw(cls, cfg: CameraEffects, rng: np.random.Generator) -> CameraBias:
        scale = cfg.range_scale + cfg.range_scale_spread * rng.normal()
        return cls(range_scale=scale, bearing_offset=cfg.bearing_offset_spread * rng.normal())


def measured_range(
    r: np.ndarray, bearing: np.ndarray, cfg: CameraEffects, bias: CameraBias
) -> np.ndarray:
    """The range the camera reads before noise: s r - k r (1 - cos b), k = off_axis_depth x s;
    with k = s the depth along the optical axis, s r cos b."""
    s = bias.range_scale
    return s * r - cfg.off_axis_depth * s * r * (1.0 - np.cos(bearing))


def range_sigma(r: np.ndarray, sigma: np.ndarray | float, cfg: CameraEffects) -> np.ndarray:
    """Range noise std at range r: the sensor's own `sigma` and `sigma_range_per_m` x r in
    quadrature."""
    return np.hypot(sigma, cfg.sigma_range_per_m * np.asarray(r, float))


def bearing_noise(n: int, sigma: float, cfg: CameraEffects, rng: np.random.Generator) -> np.ndarray:
    """n bearing errors: Gaussian of std `sigma`, or Student-t with `bearing_dof` degrees of
    freedom scaled to the same robust sigma (so the bulk is as narrow, the tails heavier)."""
    if cfg.bearing_dof is None:
        return rng.normal(0.0, sigma, n)
    scale = sigma / (MAD_TO_SIGMA * stats.t.ppf(0.75, cfg.bearing_dof))
    return scale * rng.standard_t(cfg.bearing_dof, n)


def misread_labels(
    index: np.ndarray, n_objects: int, cfg: CameraEffects, rng: np.random.Generator
) -> np.ndarray:
    """The object each detection is labelled as: its own (`index`), or for `misread_rate`
    of them another one, uniformly."""
    if cfg.misread_rate == 0.0 or n_objects < 2:
        return index.copy()
    wrong = rng.random(len(index)) < cfg.misread_rate
    other = (index + rng.integers(1, n_objects, len(index))) % n_objects
    return np.where(wrong, other, index)


def blind_spells(t0: float, t1: float, cfg: CameraEffects, rng: np.random.Generator) -> np.ndarray:
    """(k, 2) start and end times of the camera's blind spells between t0 and t1: starts
    a Poisson process of `blind_per_minute`, each lasting `blind_duration_s` (uniform)."""
    if cfg.blind_per_minute == 0.0:
        return np.zeros((0, 2))
    n = rng.poisson(cfg.blind_per_minute * (t1 - t0) / 60.0)
    start = np.sort(rng.uniform(t0, t1, n))
    return np.column_stack([start, start + rng.uniform(*cfg.blind_duration_s, n)])


def blinded(t: np.ndarray, spells: np.ndarray) -> np.ndarray:
    """Whether each time t falls in one of the blind spells (k, 2)."""
    t = np.asarray(t, float)
    if len(spells) == 0:
        return np.zeros(t.shape, bool)
    return ((t[:, None] >= spells[None, :, 0]) & (t[:, None] < spells[None, :, 1])).any(axis=1)


def turn_scale(cfg: OdometryEffects, rng: np.random.Generator) -> float:
    """A robot's factor on every angle its odometry turns: 1 + e, e ~ N(0, spread)."""
    return 1.0 + cfg.turn_scale_spread * rng.normal() if cfg.turn_scale_spread > 0.0 else 1.0
