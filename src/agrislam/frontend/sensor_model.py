"""The sensor model: the uncertainty of each record, its own where it carries one, else the
configured default (sec. 2.3: a detection deep along its viewing ray, narrow across it),
never below the least variance the solver takes (`SOLVER_VARIANCE`)."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import numpy as np

from agrislam.config import SensorDefaults
from agrislam.geometry.noise import (
    MIN_RANGE,
    Measurement,
    RangeBearing,
    RelativePosition,
    detection_covariance,
    least_variance_bound,
    raised,
)
from agrislam.records import Detection

# m^2 or rad^2: the least variance of a covariance that reaches the solver. A record may
# claim 1e-16 (sensor.limits.min_variance); next to a plant's 1e-3 that is an information
# ratio of 1e13, past what double precision factorises (GTSAM: "indeterminate linear
# system"). 1e-12 is a micrometre or a microradian, below any real sensor's noise.
SOLVER_VARIANCE = 1e-12
RAISED = (
    "record covariances raised to the solver's least variance, 1e-12 (frontend/sensor_model.py)"
)


class SensorModel:
    """The uncertainty of each record: its own where it carries one, else the configured
    default; odometry sigmas widened by `sensor.odom_sigma_scale`; what is raised to the
    solver's least variance counted in `issues`."""

    def __init__(self, sensor: SensorDefaults, issues: Counter[str]) -> None:
        self.sensor, self.issues = sensor, issues

    def odometry_covariance(self, cov: np.ndarray | None) -> np.ndarray:
        """(3, 3) covariance of a motion increment (x, y, theta in the previous frame)."""
        sensor = self.sensor
        cov = cov if cov is not None else np.diag(sensor.odom_cov_diag)
        if least_variance_bound(cov) < SOLVER_VARIANCE:
            self.issues[RAISED] += 1
            cov = raised(cov, SOLVER_VARIANCE)
        return cov * np.outer(sensor.odom_sigma_scale, sensor.odom_sigma_scale)

    def with_least_variance(
        self, detections: list[Detection], covs: np.ndarray, least: np.ndarray
    ) -> tuple[list[Detection], np.ndarray]:
        """The detections of covariances `covs` (m, 2, 2), each with no variance below
        `least` (m,) nor the solver's least: its own covariance or sigmas raised (a
        range's and a bearing's each), or the configured default's put in its place;
        and which were raised ((m,) bool). Those below the solver's alone are counted."""
        floor = np.maximum(least, SOLVER_VARIANCE)
        low = np.linalg.eigvalsh(covs)[:, 0] < floor
        if not low.any():
            return detections, low
        if (n_raised := int((low & (least < SOLVER_VARIANCE)).sum())) > 0:
            self.issues[RAISED] += n_raised
        out = list(detections)
        for i in np.flatnonzero(low).tolist():
            det, variance = detections[i], float(floor[i])
            if det.xy is None:
                assert det.range is not None
                sigma_range, sigma_bearing = self.range_bearing_sigmas(det)
                sigma = math.sqrt(variance)
                out[i] = dataclasses.replace(
                    det,
                    sigma_range=max(sigma_range, sigma),
                    sigma_bearing=max(sigma_bearing, sigma / max(det.range, MIN_RANGE)),
                )
            else:
                out[i] = dataclasses.replace(det, cov=raised(covs[i], variance))
        return out, low

    def range_bearing_sigmas(self, det: Detection) -> tuple[float, float]:
        """A range/bearing detection's sigmas, or the configured defaults."""
        sensor = self.sensor
        return (
            det.sigma_range or sensor.detection_sigma_depth,
            det.sigma_bearing or sensor.detection_sigma_lateral / max(det.range, MIN_RANGE),
        )

    def detection_covariance(self, det: Detection) -> np.ndarray:
        """(2, 2) robot-frame covariance of a detection (sec. 2.3): its own, or deep along
        the viewing ray and narrow across it."""
        if det.cov is not None:
            return det.cov
        if det.range is not None:
            sigma_range, sigma_bearing = self.range_bearing_sigmas(det)
            return detection_covariance(det.position(), sigma_range, sigma_bearing * det.range)
        sensor = self.sensor
        return detection_covariance(
            det.position(), sensor.detection_sigma_depth, sensor.detection_sigma_lateral
        )

    def measurement(
        self,
        det: Detection,
        xy: np.ndarray,
        cov: np.ndarray,
        sigma_scale: float = 1.0,
        floor: float = 0.0,
    ) -> Measurement:
        """The factor's measurement in the form the detection came in (xy: bias-corrected,
        cov: scaled; a range and bearing's sigmas are scaled by `sigma_scale`), with
        `floor` m of isotropic noise added (a tentative object's: maintenance.Existence)."""
        if det.range is not None and det.xy is None:
            sigma_range, sigma_bearing = sigma_scale * np.asarray(self.range_bearing_sigmas(det))
            r = float(np.hypot(*xy))
            sigmas = (
                np.hypot(sigma_range, floor),
                np.hypot(sigma_bearing, floor / max(r, MIN_RANGE)),
            )
            return RangeBearing(r, det.bearing, *map(float, sigmas))
        return RelativePosition(xy, cov + floor**2 * np.eye(2))
