"""Wheel/leg odometry of a simulated robot: the true motion increments with white noise per
step and a slowly wandering heading bias (the field), or random-walk noise with a scale
and heading bias per robot (the arena), either with a turn scale of its own if its effects
say so, and the trajectory dead reckoning makes of them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrislam.geometry.se2 import wrap_angle
from agrislam.sim.arena_config import ArenaOdometry
from agrislam.sim.config import OdometryNoise
from agrislam.sim.effects import turn_scale


@dataclass(frozen=True, slots=True)
class OdometryTrack:
    delta: np.ndarray  # (m-1, 3) measured increments, each in the previous robot frame
    cov: np.ndarray  # (m-1, 3, 3) the covariance reported with each increment
    dead_reckoned: np.ndarray  # (m, 3) the increments integrated from the true start

    def record(self, i: int, standstill: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Motion and covariance of the i-th odometry record. The first marks where the
        robot's timeline starts: zero motion, with the `standstill` covariance (a zero one
        would be singular in the graph)."""
        if i == 0:
            return np.zeros(3), standstill
        return self.delta[i - 1], self.cov[i - 1]


def increments(poses: np.ndarray) -> np.ndarray:
    """p_{k-1}^-1 (+) p_k for consecutive poses (m, 3) -> (m-1, 3)."""
    d = np.diff(poses[:, :2], axis=0)
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    return np.column_stack(
        [c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap_angle(np.diff(poses[:, 2]))]
    )


def integrate(start: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Dead reckoning: start (+) delta_1 (+) delta_2 ... as poses (m, 3), vectorised."""
    theta = start[2] + np.concatenate([[0.0], np.cumsum(delta[:, 2])])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    step = np.column_stack([c * delta[:, 0] - s * delta[:, 1], s * delta[:, 0] + c * delta[:, 1]])
    xy = start[:2] + np.vstack([[0.0, 0.0], np.cumsum(step, axis=0)])
    return np.column_stack([xy, wrap_angle(theta)])


def step_sigma(delta: np.ndarray, noise: OdometryNoise) -> np.ndarray:
    """Std (m-1, 3) of the white noise on each true increment: a floor plus parts that grow
    with the distance driven and the angle turned."""
    ds = np.hypot(delta[:, 0], delta[:, 1])
    floor = np.asarray(noise.sigma_floor)
    return np.column_stack(
        [
            floor[0] + noise.sigma_x_per_m * ds,
            floor[1] + noise.sigma_y_per_m * ds,
            floor[2]
            + noise.sigma_theta_per_m * ds
            + noise.sigma_theta_per_rad * np.abs(delta[:, 2]),
        ]
    )


def heading_bias(
    t: np.ndarray, ds: np.ndarray, noise: OdometryNoise, rng: np.random.Generator
) -> np.ndarray:
    """Yaw-rate bias (rad/s) over each interval of t (`ds` m driven in each): of the
    configured size with a random sign per robot, plus a slow random walk (bias
    instability); with `drift.bias_length`, relaxing over distance instead (DistanceDrift)."""
    dt = np.diff(t)
    walk = np.cumsum(rng.normal(0.0, 1.0, len(dt)) * noise.heading_bias_walk * np.sqrt(dt))
    sign = rng.choice([-1.0, 1.0])
    drift = noise.drift
    if drift.bias_length <= 0.0:
        return sign * noise.heading_bias + walk
    keep = np.exp(-ds / drift.bias_length)  # Ornstein-Uhlenbeck in distance, exact steps
    kick = np.sqrt(1.0 - keep**2) * drift.bias_spread * rng.normal(0.0, 1.0, len(ds))
    bias, b = np.empty(len(ds)), sign * noise.heading_bias
    for k, (a, w) in enumerate(zip(keep.tolist(), kick.tolist(), strict=True)):
        bias[k] = b
        b = a * b + w
    return bias


def noisy_odometry(
    poses: np.ndarray, t: np.ndarray, noise: OdometryNoise, rng: np.random.Generator
) -> OdometryTrack:
    """What the robot's odometry reports while it follows the true poses (m, 3) at times t:
    white noise, a heading bias and a distance scale error (neither reported)."""
    true = increments(poses)
    sigma = step_sigma(true, noise)
    measured = true + rng.normal(0.0, 1.0, true.shape) * sigma
    ds = np.hypot(true[:, 0], true[:, 1])
    measured[:, 2] += heading_bias(t, ds, noise, rng) * np.diff(t)
    measured[:, 2] = wrap_angle(measured[:, 2])
    if noise.drift.scale_sigma > 0.0:
        measured[:, :2] *= 1.0 + rng.normal(0.0, noise.drift.scale_sigma)
    measured[:, 2] = _turned(measured[:, 2], true[:, 2], turn_scale(noise.effects, rng))
    cov = np.zeros((len(true), 3, 3))
    idx = np.arange(3)
    cov[:, idx, idx] = (noise.report_scale * sigma) ** 2
    return OdometryTrack(delta=measured, cov=cov, dead_reckoned=integrate(poses[0], measured))


def random_walk_variance(true: np.ndarray, dt: np.ndarray, noise: ArenaOdometry) -> np.ndarray:
    """(m-1, 3) variance of the white noise on each true increment (x, y, theta): each grows
    with the metres driven, the radians turned and the seconds passed, whatever the rate."""
    ds = np.hypot(true[:, 0], true[:, 1])
    per_s = np.square(noise.sigma_per_sqrt_s)
    return np.column_stack(
        [
            noise.sigma_x_per_sqrt_m**2 * ds + per_s[0] * dt,
            noise.sigma_y_per_sqrt_m**2 * ds + per_s[1] * dt,
            noise.sigma_theta_per_sqrt_m**2 * ds
            + noise.sigma_theta_per_sqrt_rad**2 * np.abs(true[:, 2])
            + per_s[2] * dt,
        ]
    )


def drifting_odometry(
    poses: np.ndarray, t: np.ndarray, noise: ArenaOdometry, rng: np.random.Generator
) -> OdometryTrack:
    """What a robot's wheel odometry reports while it follows the true poses (m, 3) at times
    t: random-walk noise, a distance scale error, a heading bias per metre and a turn scale of
    its own (drawn here, once), and a covariance that reports the white noise by
    `report_sigma_factor` (and the biases not at all)."""
    true = increments(poses)
    var = random_walk_variance(true, np.diff(t), noise)
    scale = 1.0 + rng.normal(0.0, noise.scale_bias)
    heading_bias = rng.choice([-1.0, 1.0]) * noise.heading_bias_per_m
    measured = true + rng.normal(0.0, 1.0, true.shape) * np.sqrt(var)
    measured[:, :2] *= scale
    measured[:, 2] = wrap_angle(measured[:, 2] + heading_bias * np.hypot(true[:, 0], true[:, 1]))
    measured[:, 2] = _turned(measured[:, 2], true[:, 2], turn_scale(noise.effects, rng))
    cov = np.zeros((len(true), 3, 3))
    idx = np.arange(3)
    cov[:, idx, idx] = var * np.square(noise.report_sigma_factor)
    return OdometryTrack(delta=measured, cov=cov, dead_reckoned=integrate(poses[0], measured))


def _turned(measured: np.ndarray, true: np.ndarray, scale: float) -> np.ndarray:
    """Measured heading increments with the robot's turn `scale` on the true turn."""
    if scale == 1.0:
        return measured
    return wrap_angle(measured + (scale - 1.0) * true)
