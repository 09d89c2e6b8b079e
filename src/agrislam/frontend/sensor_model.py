"""The sensor model: the uncertainty of each record, its own where it carries one, else the
configured default (sec. 2.3: a detection deep along its viewing ray, narrow across it)."""

from __future__ import annotations

import numpy as np

from agrislam.config import SensorDefaults
from agrislam.geometry.noise import (
    MIN_RANGE,
    Measurement,
    RangeBearing,
    RelativePosition,
    detection_covariance,
)
from agrislam.records import Detection


class SensorModel:
    """The uncertainty of each record: its own where it carries one, else the configured
    default; odometry sigmas widened by `sensor.odom_sigma_scale`."""

    def __init__(self, sensor: SensorDefaults) -> None:
        self.sensor = sensor

    def odometry_covariance(self, cov: np.ndarray | None) -> np.ndarray:
        """(3, 3) covariance of a motion increment (x, y, theta in the previous frame)."""
        sensor = self.sensor
        cov = cov if cov is not None else np.diag(sensor.odom_cov_diag)
        return cov * np.outer(sensor.odom_sigma_scale, sensor.odom_sigma_scale)

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
