"""The arena robots' camera: range and bearing to every landmark within its range and field
of view, Gaussian noise, a few gross range outliers, and optionally the landmark's id read
off its barcode, sometimes wrong; with its effects on, a real camera's depth-like range,
range-dependent noise, heavy-tailed and offset bearings, misread labels and blind spells
(`effects.py`). Vectorised over all frames of a robot at once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrislam.geometry.se2 import wrap_angle
from agrislam.sim.arena_config import LandmarkAttribute, RangeBearingCamera
from agrislam.sim.effects import (
    CameraBias,
    bearing_noise,
    blinded,
    measured_range,
    misread_labels,
    range_sigma,
)

MIN_REPORTED_RANGE = 0.01  # m; the noise must not make a range negative (the log forbids it)


@dataclass(frozen=True, slots=True)
class Observations:
    """Every landmark detection of one robot, sorted by frame (struct of arrays)."""

    frame: np.ndarray  # (n,) index of the frame
    landmark: np.ndarray  # (n,) index of the landmark seen
    true_range: np.ndarray  # (n,) m
    true_bearing: np.ndarray  # (n,) rad
    range: np.ndarray  # (n,) measured, m
    bearing: np.ndarray  # (n,) measured, rad
    outlier: np.ndarray  # (n,) bool: a gross range error
    label: np.ndarray  # (n,) index of the landmark it is labelled as: `landmark` unless misread

    def __len__(self) -> int:
        return len(self.frame)

    def subset(self, keep: np.ndarray) -> Observations:
        """The detections where `keep` (n,) is true, still sorted by frame."""
        return Observations(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))

    def in_frame(self, i: int) -> range:
        """Indices of the detections of frame i."""
        lo, hi = np.searchsorted(self.frame, [i, i + 1])
        return range(int(lo), int(hi))


def true_range_bearing(poses: np.ndarray, landmarks: np.ndarray) -> tuple[np.ndarray, ...]:
    """(f, k) true range and bearing of each of k landmarks (k, 2) from each pose (f, 3)."""
    d = landmarks[None, :, :] - poses[:, None, :2]
    r = np.hypot(d[..., 0], d[..., 1])
    return r, wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - poses[:, 2:3])


def in_view(
    poses: np.ndarray, landmarks: np.ndarray, cfg: RangeBearingCamera
) -> tuple[np.ndarray, ...]:
    """(frame, landmark) index pairs of the landmarks inside range and field of view from each
    pose (f, 3), sorted by frame, with their true range and bearing."""
    r, b = true_range_bearing(poses, landmarks)
    seen = (r >= cfg.min_range) & (r <= cfg.max_range) & (np.abs(b) <= np.deg2rad(cfg.fov_deg) / 2)
    frame, landmark = np.nonzero(seen)  # row-major: sorted by frame
    return frame, landmark, r[frame, landmark], b[frame, landmark]


def observe(
    poses: np.ndarray,
    landmarks: np.ndarray,
    cfg: RangeBearingCamera,
    rng: np.random.Generator,
    bias: CameraBias | None = None,
    effects_rng: np.random.Generator | None = None,
) -> Observations:
    """What the camera measures from each true pose (f, 3) of a robot's frames: the range
    `measured_range` reads (the true one without effects) with noise growing with it, the
    bearing with the robot's offset `bias`, labels misread by `effects_rng`."""
    bias = bias or CameraBias()
    fx = cfg.effects
    frame, landmark, r, b = in_view(poses, landmarks, cfg)
    n = len(frame)
    noisy = measured_range(r, b, fx, bias) + rng.normal(0.0, 1.0, n) * range_sigma(
        r, cfg.sigma_range, fx
    )
    outlier = rng.random(n) < cfg.outlier_rate
    wild = rng.uniform(cfg.min_range, cfg.max_range, n)
    bearing = b + bearing_noise(n, cfg.sigma_bearing, fx, rng) + bias.bearing_offset
    label = misread_labels(landmark, len(landmarks), fx, effects_rng or rng)
    return Observations(
        frame=frame,
        landmark=landmark,
        true_range=r,
        true_bearing=b,
        range=np.maximum(np.where(outlier, wild, noisy), MIN_REPORTED_RANGE),
        bearing=wrap_angle(bearing),
        outlier=outlier,
        label=label,
    )


def read_by_chance(seen: Observations, p: float, rng: np.random.Generator) -> Observations:
    """The detections kept when each landmark in view is read with chance `p`."""
    if p >= 1.0:
        return seen
    return seen.subset(rng.random(len(seen)) < p)


def unless_blind(seen: Observations, t_frames: np.ndarray, spells: np.ndarray) -> Observations:
    """The detections of the frames (times `t_frames`) outside the blind spells (k, 2)."""
    if len(spells) == 0:
        return seen
    return seen.subset(~blinded(t_frames[seen.frame], spells))


def read_ids(
    landmark: np.ndarray, n_landmarks: int, cfg: LandmarkAttribute, rng: np.random.Generator
) -> np.ndarray:
    """The landmark index each detection's barcode read reports: its own, or with
    `error_rate` one of the others, uniformly."""
    wrong = rng.random(len(landmark)) < cfg.error_rate
    if n_landmarks < 2:
        return landmark.copy()
    other = (landmark + rng.integers(1, n_landmarks, len(landmark))) % n_landmarks
    return np.where(wrong, other, landmark)
