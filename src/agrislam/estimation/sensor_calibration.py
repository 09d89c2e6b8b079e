"""A range-bearing sensor's biases, learned from the survey (sec. 2.3 leaves them to "be
established and corrected"): the range's off-axis term (a depth camera reads depth along
its axis, r_meas = s r (1 - kappa (1 - cos b))), a bearing offset, and the clock offset
between the odometry and the camera, per robot.

Two sightings of one object by one robot a few seconds apart, each placed in the robot's
dead-reckoning frame, put the object at one point when the biases are right, whatever the
map says; robust least squares over many such pairs finds them. The range's overall scale
s is fitted too but not applied: over a few seconds it cannot be told from the odometry's
own scale."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from agrislam.geometry import se2
from agrislam.records import Detection

TERMS = ("scale", "off_axis", "bearing_offset", "clock_offset")
NEUTRAL = np.array([1.0, 0.0, 0.0, 0.0])
# weak priors that keep a term near neutral until pairs say otherwise (s, kappa, rad, s)
PRIOR_SIGMA = np.array([0.2, 1.0, 0.2, 0.5])
SPAN_S = (1.0, 6.0)  # seconds between the two sightings of a pair
KEPT_PAIRS = 5000  # the latest pairs of a robot an estimate uses
MIN_PAIRS = 100  # pairs before a first estimate
REFIT_EVERY = 150  # new pairs between estimates
# a term is used once it is this many of its standard errors from neutral (pairs in one
# stretch of a drive share its odometry's error: the errors, taken as independent, are small)
SIGNIFICANT = 4.0
# the spread of a pair's difference, before its scale is learned: each detection's noise as
# logged (else growing with range) and the heading drift between them
SIGMA_AT_ZERO, SIGMA_PER_M, DRIFT_PER_M_SQRT_S = 0.02, 0.02, 0.03
CAUCHY_WIDTH = 2.0  # in the pairs' own robust spread
ROBUST_SIGMA = 1.4826  # a normal sample's sigma per median absolute residual
MIN_SPREAD = 1e-3


@dataclass(slots=True)
class Sighting:
    """One range-bearing detection as the calibration keeps it, raw."""

    t: float
    pose: np.ndarray  # (3,) the robot's dead-reckoning pose
    velocity: np.ndarray  # (2,) forward speed m/s, turn rate rad/s
    range: float
    bearing: float
    sigma: float  # m, its position's noise as logged (range and bearing together)


@dataclass
class SensorTerms:
    """One sensor's terms: estimate, standard errors, and which are used."""

    value: np.ndarray = field(default_factory=lambda: NEUTRAL.copy())
    sigma: np.ndarray = field(default_factory=lambda: np.full(len(TERMS), np.inf))
    pairs: int = 0

    @property
    def used(self) -> np.ndarray:
        """(4,) the terms applied: the off-axis term, bearing and clock offsets once
        significant (never the overall scale)."""
        significant = np.abs(self.value - NEUTRAL) > SIGNIFICANT * self.sigma
        significant[0] = False
        return np.where(significant, self.value, NEUTRAL)


def range_factor(bearing: np.ndarray, terms: np.ndarray) -> np.ndarray:
    """(n,) the logged range over the true one at (offset-free) `bearing` under `terms`
    (n, 4): s (1 - kappa (1 - cos b))."""
    return terms[:, 0] * (1.0 - terms[:, 1] * (1.0 - np.cos(bearing)))


def camera_point(
    range_: np.ndarray, bearing: np.ndarray, velocity: np.ndarray, terms: np.ndarray
) -> np.ndarray:
    """(n, 2) where each detection lies in the frame of the pose it is stamped with, under
    `terms` (n, 4): the bearing offset taken off, the range divided by its off-axis and
    scale terms, and the camera's own pose then, `clock_offset` s from the stamp along the
    robot's motion."""
    clock = terms[:, 3]
    bearing = bearing - terms[:, 2]
    true_range = range_ / range_factor(bearing, terms)
    point = true_range[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    moved = np.column_stack([velocity[:, 0] * clock, np.zeros(len(clock)), velocity[:, 1] * clock])
    return se2.compose_points(moved, point)


class SensorCalibration:
    """The biases of each robot's range-bearing sensor, from pairs of its sightings."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self.terms: dict[str, SensorTerms] = {}
        self._last: dict[tuple[str, int], list[Sighting]] = {}  # (robot, object) -> recent
        self._pairs: dict[str, list[tuple[Sighting, Sighting]]] = {}
        self._new: dict[str, int] = {}
        self._frame: dict[str, list[Detection]] = {}  # each robot's latest frame, raw

    def correct(self, robot: str, velocity: np.ndarray, detections: list[Detection]) -> list:
        """The robot's detections with its sensor's significant biases taken off (the raw
        ones are kept for `observe`)."""
        self._frame[robot] = detections
        terms = self.terms.get(robot)
        if not self.enabled or terms is None or not detections:
            return detections
        used = terms.used
        if np.array_equal(used, NEUTRAL):
            return detections
        ranged = [i for i, d in enumerate(detections) if _ranged(d)]
        if not ranged:
            return detections
        rng = np.array([detections[i].range for i in ranged])
        bearing = np.array([detections[i].bearing for i in ranged])
        n = len(ranged)
        point = camera_point(rng, bearing, np.tile(velocity, (n, 1)), np.tile(used, (n, 1)))
        corrected = list(detections)
        for i, (x, y) in zip(ranged, point.tolist(), strict=True):
            det = detections[i]
            corrected[i] = dataclasses.replace(
                det, range=float(np.hypot(x, y)), bearing=float(np.arctan2(y, x))
            )
        return corrected

    def observe(
        self,
        robot: str,
        t: float,
        pose: np.ndarray,
        velocity: np.ndarray,
        mapped: np.ndarray,
        object_ids: np.ndarray,
    ) -> None:
        """The robot's latest frame (`correct`'s, raw) at dead-reckoning `pose`: its
        `mapped` detections and the objects they went to. Each pairs with the robot's
        latest sighting of its object SPAN_S ago."""
        frame = self._frame.pop(robot, [])
        if not self.enabled or len(frame) != len(mapped):
            return
        raw = [det for det, m in zip(frame, mapped.tolist(), strict=True) if m]
        for det, obj in zip(raw, object_ids.tolist(), strict=True):
            if not _ranged(det):
                continue
            now = Sighting(
                t, pose.copy(), velocity.copy(), float(det.range), float(det.bearing), _sigma(det)
            )
            recent = self._last.setdefault((robot, obj), [])
            recent[:] = [s for s in recent if t - s.t <= SPAN_S[1]]
            then = next((s for s in reversed(recent) if t - s.t >= SPAN_S[0]), None)
            if then is not None:
                pairs = self._pairs.setdefault(robot, [])
                pairs.append((then, now))
                del pairs[:-KEPT_PAIRS]
                self._new[robot] = self._new.get(robot, 0) + 1
            recent.append(now)
        if len(self._pairs.get(robot, ())) >= MIN_PAIRS and self._new.get(robot, 0) >= REFIT_EVERY:
            self._new[robot] = 0
            self.terms[robot] = fitted(self._pairs[robot], self.terms.get(robot))

    def report(self) -> dict[str, dict[str, object]]:
        """Per robot: each term's estimate and standard error, whether it is used, pairs."""
        return {
            robot: {
                "pairs": terms.pairs,
                **{
                    name: {"estimate": float(v), "sigma": float(s), "used": bool(u != n)}
                    for name, v, s, u, n in zip(
                        TERMS, terms.value, terms.sigma, terms.used, NEUTRAL, strict=True
                    )
                },
            }
            for robot, terms in sorted(self.terms.items())
        }


def fitted(pairs: list[tuple[Sighting, Sighting]], start: SensorTerms | None) -> SensorTerms:
    """The terms that best put each pair's two sightings at one point (robust least
    squares: Cauchy on the pairs' own spread), with their standard errors."""
    then = _columns([p[0] for p in pairs])
    now = _columns([p[1] for p in pairs])
    span = now["t"] - then["t"]

    def placed(sighting: dict[str, np.ndarray], tiled: np.ndarray) -> np.ndarray:
        local = camera_point(sighting["range"], sighting["bearing"], sighting["velocity"], tiled)
        return se2.compose_points(sighting["pose"], local)

    reach = 0.5 * (then["range"] + now["range"])  # as logged
    logged_sigma = np.sqrt(
        then["sigma"] ** 2 + now["sigma"] ** 2 + (DRIFT_PER_M_SQRT_S * np.sqrt(span) * reach) ** 2
    )

    def residuals(terms: np.ndarray) -> np.ndarray:
        tiled = np.tile(terms, (len(span), 1))  # the terms, one row per pair
        a, b = placed(then, tiled), placed(now, tiled)
        # the spread shrinks with the ranges the terms give: shrinking every range would
        # otherwise shrink the noise's differences and pass for a better fit
        shrunk = 0.5 * sum(range_factor(s["bearing"] - terms[2], tiled) for s in (then, now))
        sigma = logged_sigma / shrunk
        return np.r_[((b - a) / sigma[:, None]).ravel(), (terms - NEUTRAL) / PRIOR_SIGMA]

    x0 = NEUTRAL if start is None else start.value
    spread = max(ROBUST_SIGMA * float(np.median(np.abs(residuals(x0)))), MIN_SPREAD)
    solution = least_squares(
        residuals, x0, loss="cauchy", f_scale=CAUCHY_WIDTH * spread, method="trf"
    )
    spread = max(ROBUST_SIGMA * float(np.median(np.abs(solution.fun))), MIN_SPREAD)
    jac = solution.jac
    try:
        sigma = np.sqrt(np.clip(np.diag(np.linalg.inv(jac.T @ jac)), 0.0, None)) * spread
    except np.linalg.LinAlgError:
        sigma = np.full(len(TERMS), np.inf)
    return SensorTerms(solution.x, sigma, len(pairs))


def _columns(sightings: list[Sighting]) -> dict[str, np.ndarray]:
    return {
        "t": np.array([s.t for s in sightings]),
        "pose": np.array([s.pose for s in sightings]),
        "velocity": np.array([s.velocity for s in sightings]),
        "range": np.array([s.range for s in sightings]),
        "bearing": np.array([s.bearing for s in sightings]),
        "sigma": np.array([s.sigma for s in sightings]),
    }


def _sigma(det: Detection) -> float:
    """A range-bearing detection's position noise (m) as logged, else a guess growing with
    range."""
    if det.sigma_range is None or det.sigma_bearing is None:
        return SIGMA_AT_ZERO + SIGMA_PER_M * det.range
    return float(np.hypot(det.sigma_range, det.range * det.sigma_bearing))


def _ranged(det: Detection) -> bool:
    """Whether a detection is a range and bearing (the terms apply to those alone)."""
    return det.range is not None and det.bearing is not None and det.xy is None
