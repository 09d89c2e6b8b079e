"""The estimators stage: what the program learns from the data as it maps. The noise
scales from pairs of sightings of one object, the depth bias from multi-view residuals
(sec. 2.3), d_inter from the first detections; and the map's outside references, GNSS
fixes and rows (sec. 2.6.2)."""

from __future__ import annotations

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.config import Settings
from agrislam.estimation.depth_bias import DepthBiasEstimator
from agrislam.estimation.gnss import GnssFixes
from agrislam.estimation.noise_calibration import NoiseCalibration
from agrislam.estimation.point_spacing import PointSpacing
from agrislam.estimation.rows import RowTracker
from agrislam.estimation.sensor_calibration import SensorCalibration
from agrislam.geometry import se2
from agrislam.geometry.placed import FrameMatch
from agrislam.mapping.map_state import MapState


class Estimators:
    """The survey's own noise, depth bias and d_inter; its GNSS fixes and rows."""

    def __init__(self, settings: Settings, map_state: MapState, backend: GraphBackend) -> None:
        """The estimators of a survey with `settings` over its map and back end."""
        sensor = settings.sensor
        sharpest = min(sensor.detection_sigma_lateral, sensor.detection_sigma_depth)
        self.noise = NoiseCalibration(sensor.calibration, sharpest)
        self.depth_bias = DepthBiasEstimator(sensor.depth_bias)
        self.sensor = SensorCalibration(sensor.estimate_biases)
        self.spacing = PointSpacing(settings.association.d_inter)
        self.gnss = GnssFixes(settings.gnss, backend.issues)
        rows = settings.rows
        self.rows = RowTracker(rows, backend.issues) if rows.enabled else None
        self.depth_min_views = sensor.depth_bias_min_views if sensor.estimate_depth_bias else None
        self.map, self.backend = map_state, backend

    def sighted(self, match: FrameMatch) -> None:
        """The frame's sightings, in the robot's dead-reckoning frame: with the robot's
        earlier sightings of the objects around (within 3 association reaches), they scale
        the noise (estimation/noise_calibration.py); then the objects were last seen here."""
        objects, placed, chain = self.map.objects, match.placed, match.chain
        robot = match.robot_index
        object_ids, new_ids, reach = match.object_ids, match.new_ids, match.reach
        configured = placed.robot_cov / self.noise.scale.variance[0]
        xy, cov = se2.to_map_frame(chain.pose, placed.robot_xy, configured)
        if self.noise.enabled and len(placed):
            around = objects.active(self.map.index.query(placed.xy, 3.0 * reach))
            around = around[~np.isin(around, new_ids)]
            if len(around) >= 1:
                estimates = self.backend.object_positions(around)
                dist = np.linalg.norm(placed.xy[:, None, :] - estimates[None], axis=2)
                then = objects.last_seen(around, robot)
                chosen = object_ids[:, None] == around[None, :]
                last = (then.known, then.xy, then.cov, then.drift)
                frame = (xy, cov, chain.drift)
                self.noise.observe(frame, robot, around, last, chosen, dist)
        objects.seen(object_ids, robot, chain.drift, xy, cov)
        self.sensor.observe(
            match.robot, match.t, chain.pose, chain.velocity(), match.mapped, object_ids
        )

    def calibrate_depth(self, match: FrameMatch) -> None:
        """Along-ray residuals of well-triangulated objects refine the depth bias."""
        if self.depth_min_views is None:
            return
        robot, placed, object_ids = match.robot, match.placed, match.object_ids
        known = self.map.objects.n_meas[object_ids] > self.depth_min_views
        if known.any():
            xy = self.backend.object_positions(object_ids[known])
            predicted = se2.to_robot_frame(self.backend.current_pose(robot), xy)
            self.depth_bias.observe(placed.robot_xy[known], predicted)

    def fit_rows(self, touched: np.ndarray, n_detections: int) -> None:
        """Row fits and row constraints (sec. 2.6.2) for the objects due; a tentative
        object joins no row (clutter would bend the rows)."""
        if self.rows is None:
            return
        objects = self.map.objects
        confirmed = np.where(objects.tentative, 0, objects.n_frames)
        self.rows.after_step(self.backend, touched, n_detections, confirmed)

    def rows_give_way_to_gnss(self) -> None:
        """Fixes the survey can use hold the plants: rows not fitted yet, and left to the
        survey, are not fitted (a straight row at a fitted angle fights the fixes along a
        long row and twists the robot's heading)."""
        rows = self.rows
        unfitted = rows is not None and rows.angle is None
        if self.gnss.pending and unfitted and rows.config.give_way_to_gnss:
            self.rows = None
