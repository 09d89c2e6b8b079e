"""The front end (DESIGN steps 2-3): records into what the graph and the association take.
Each robot's odometry is composed into its next pose node, a motion far beyond the robot's
own held in doubt until its next frame judges it (frontend/doubt.py); GNSS fixes wait for
that node;
a frame's detections are checked against the schema and placed in the map frame with their
covariances (sec. 2.3), and once associated become measurement factors (sec. 2.6)."""

from __future__ import annotations

from collections import Counter

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.config import FieldSchema, SensorDefaults
from agrislam.estimation.estimators import Estimators
from agrislam.estimation.noise_calibration import FLOORED
from agrislam.frontend.doubt import MotionDoubt
from agrislam.frontend.sensor_model import SensorModel
from agrislam.geometry import se2
from agrislam.geometry.odometry import OdometryChain
from agrislam.geometry.placed import FrameMatch, PlacedDetections
from agrislam.records import Anchor, Detection, Detections, GnssFix, Odometry, RobotStart
from agrislam.semantics.measurements import informative_measurements


class FrontEnd:
    """Odometry chains, pose nodes, GNSS factors, placed detections and their factors."""

    def __init__(
        self,
        sensor: SensorDefaults,
        schema: FieldSchema | None,
        innovation_gate: bool,
        backend: GraphBackend,
        estimators: Estimators,
        doubt: MotionDoubt,
        issues: Counter[str],
    ) -> None:
        self.sensor = SensorModel(sensor, issues)
        self.schema, self.innovation_gate = schema, innovation_gate
        self.backend, self.estimators, self.issues = backend, estimators, issues
        self.doubt = doubt
        self.robots: dict[str, OdometryChain] = {}

    def use_starts(self, starts: dict[str, RobotStart]) -> None:
        """Start poses from a survey's meta, for the robots that have not started yet."""
        for name, start in starts.items():
            chain = self.robots.setdefault(name, OdometryChain())
            if not chain.started:
                chain.start_pose = np.asarray(start.pose, dtype=float)
                chain.start_sigma = np.asarray(start.sigma, dtype=float)

    # ------------------------------------------------------------------ records in
    def add_odometry(self, odom: Odometry) -> None:
        """Compose the motion into the robot's pending increment (DESIGN step 2), its
        covariance no sharper than the robot's jitter allows; a motion far beyond the
        robot's own is held in doubt, with the motion that would replace it (with those
        held before it: a glitch of a `pose` record is two suspects)."""
        chain = self.chain(odom.robot, odom.t)
        delta = chain.increment(odom.pose, odom.delta)
        if delta is None:
            return
        dt = odom.t - chain.time
        cov = self.doubt.covariance(odom.robot, self.sensor.odometry_covariance(odom.cov), dt)
        suspect = self.doubt.check(odom.robot, delta, dt, cov)
        if suspect is None:
            chain.move(odom.t, delta, cov)
            return
        self.doubt.hold(odom.robot, suspect)
        chain.move(odom.t, delta, cov, suspect.instead)

    def add_gnss(self, fix: GnssFix, anchor: Anchor | None) -> Anchor | None:
        """Keep a fix for the robot's next pose node; returns the survey's anchor (the first
        good fix's when it had none)."""
        chain = self.chain(fix.robot, fix.t)
        return self.estimators.gnss.receive(fix, anchor, chain.pose)

    def checked(self, frame: Detections) -> list[Detection]:
        """The frame's detections with their measurements checked against the schema; a bad
        attribute is dropped (and counted), the detection's geometry kept; a covariance
        far below what the survey's re-sightings show, or below the solver's least, is
        raised (and counted). The first ones teach the survey's d_inter where it has none
        (estimation/point_spacing.py)."""
        checked = []
        for det in frame.objects:
            det, dropped = det.within_schema(self.schema)
            for name in dropped:
                self.issues[f"measurement of {name!r} not in the schema: dropped"] += 1
            checked.append(det)
        chain = self.robots.get(frame.robot)
        velocity = chain.velocity() if chain is not None else np.zeros(2)
        checked = self.estimators.sensor.correct(frame.robot, velocity, checked)
        if not checked:
            return checked
        covs = self.detection_covariances(checked)
        floor = self.estimators.noise.detection_floor(covs)
        checked, raised = self.sensor.with_least_variance(checked, covs, floor)
        if (n_floored := int((raised & (floor > 0.0)).sum())) > 0:
            self.issues[FLOORED] += n_floored
        if not self.estimators.spacing.settled:
            covs = self.detection_covariances(checked) if raised.any() else covs
            self.estimators.spacing.observe(covs)
        return checked

    def detection_covariances(self, detections: list[Detection]) -> np.ndarray:
        """(m, 2, 2) robot-frame covariances of the detections, as the sensor model says."""
        return np.stack([self.sensor.detection_covariance(d) for d in detections])

    # ---------------------------------------------------------------- the frame
    def add_pose(self, robot: str, t: float, detections: list[Detection]) -> None:
        """The robot's pose node at t with its odometry factor, motions in doubt judged by
        the frame's `detections` first (if they can tell), and the GNSS fixes that waited
        for it as factors on it (gated on the previous pose's covariance)."""
        gnss, chain = self.estimators.gnss, self.chain(robot, t)
        if (versions := chain.in_doubt) is not None:
            fit = None
            if detections:
                xy = np.stack([d.position() for d in detections])
                cov = self.estimators.noise.scale.detection(self.detection_covariances(detections))
                fit = self.doubt.fit(robot, self.backend.current_pose(robot), versions, xy, cov)
            if (doubted := self.doubt.judge(robot, fit, looked=bool(detections))) is not None:
                chain.settle(doubted)
        pose_cov = None
        if gnss.pending.get(robot) and gnss.cfg.gate_chi2 > 0.0:
            pose_cov = self.backend.current_pose_covariance(robot)
        pending = chain.take_pending()
        if pending is not None:
            delta, parts = pending
            odometry = self.estimators.noise.scale.odometry(parts)
            self.backend.add_odometry(robot, t, delta, odometry)
        gnss.attach(self.backend, robot, chain.pose, pose_cov)

    def place(self, robot: str, detections: list[Detection]) -> PlacedDetections:
        """Detections into the map frame with their covariances (DESIGN step 3), after the
        depth-bias correction; with the innovation gate, what the pose's own uncertainty
        adds to each."""
        if not detections:
            nothing, no_cov = np.empty((0, 2)), np.empty((0, 2, 2))
            return PlacedDetections(nothing, no_cov, [], nothing, no_cov)
        xy = self.estimators.depth_bias.correct(np.stack([d.position() for d in detections]))
        cov = self.estimators.noise.scale.detection(self.detection_covariances(detections))
        pose = self.backend.current_pose(robot)
        map_xy, map_cov = se2.to_map_frame(pose, xy, cov)
        pose_cov = None
        if self.innovation_gate:
            pose_cov = se2.pose_uncertainty_at(
                pose, self.backend.current_pose_covariance(robot), xy
            )
        measurements = [informative_measurements(self.schema, d.attributes) for d in detections]
        return PlacedDetections(map_xy, map_cov, measurements, xy, cov, pose_cov)

    def measure(self, match: FrameMatch, floor: np.ndarray) -> bool:
        """The frame's detections as factors between the robot's pose and their objects,
        with `floor` (m,) m of isotropic noise added to each; one solve of the back end.
        True if the solve folded a window."""
        sigma_scale = float(self.estimators.noise.scale.sigma[0])
        placed = match.placed
        factors = (match.detections, match.object_ids.tolist(), placed.robot_xy, placed.robot_cov)
        for det, obj, xy, cov, f in zip(*factors, floor, strict=True):
            measurement = self.sensor.measurement(det, xy, cov, sigma_scale, float(f))
            self.backend.add_observation(match.robot, obj, measurement)
        return self.backend.update()

    # ----------------------------------------------------------------- helpers
    def chain(self, name: str, t: float) -> OdometryChain:
        """The robot's odometry chain, started in the back end at its first record's time:
        at its start pose, or at the origin (the world places a later robot without one
        before its first record comes here: season/newcomers.py)."""
        chain = self.robots.get(name)
        if chain is None:
            chain = self.robots[name] = OdometryChain()
        if not chain.started:
            start = np.zeros(3) if chain.start_pose is None else chain.start_pose
            self.backend.add_robot(name, start, chain.start_sigma, t)
            chain.start(start, t)
        return chain

    def robot_index(self, name: str) -> int:
        """A robot's number, in the order robots were first heard of."""
        return list(self.robots).index(name)
