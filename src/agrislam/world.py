"""The world model: one step of the pipeline of DESIGN.md, the only orchestrator.

Records go in (from any source); the map comes out as a `MapSnapshot`. `step` takes a
frame of detections of one robot and runs the pipeline: predict, add pose, place
detections, associate, update beliefs, update geometry, rows, maintain, publish.
Odometry between frames is kept and composed into the frame's pose.
"""

from __future__ import annotations

import dataclasses
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from agrislam.association import (
    PlacedDetections,
    SpatialIndex,
    assign,
    association_matrix,
    informative_measurements,
    innovation_covariance,
    max_association_distance,
)
from agrislam.config import AgrislamConfig, FieldSchema
from agrislam.geometry import se2
from agrislam.geometry.backend import (
    RangeBearing,
    RelativePosition,
    detection_covariance,
    make_backend,
)
from agrislam.geometry.depth_bias import DepthBiasEstimator
from agrislam.geometry.drift import OdometryDrift
from agrislam.geometry.rows import RowTracker
from agrislam.maintenance import MaintenanceResult, Pruner, merge_pairs
from agrislam.records import (
    Detection,
    Detections,
    DiscreteMeasurement,
    FieldPrior,
    Measurement,
    Meta,
    Odometry,
    Record,
)
from agrislam.semantics.beliefs import BeliefTable
from agrislam.semantics.heuristic import interest_surface
from agrislam.snapshot import (
    STATUS_ACTIVE,
    STATUS_MERGED,
    STATUS_PRUNED,
    MapSnapshot,
    ObjectMap,
    Trajectory,
)

STAGES = (
    "predict",
    "add_pose",
    "place",
    "associate",
    "beliefs",
    "geometry",
    "rows",
    "maintain",
    "publish",
)


@dataclass(slots=True)
class StepReport:
    """What one frame did: the object each detection went to (after merges of this
    step), which objects are new, and what maintenance changed."""

    t: float
    robot: str
    object_ids: np.ndarray
    new_ids: np.ndarray
    maintenance: MaintenanceResult
    seconds: dict[str, float]


@dataclass(slots=True)
class _Robot:
    """One robot's chain: its odometry since the last frame, and its dead reckoning."""

    start_pose: np.ndarray | None = None  # map-frame prior from the survey's meta
    start_sigma: np.ndarray | None = None
    started: bool = False  # added to the back end
    pending: tuple[np.ndarray, np.ndarray] | None = None  # composed delta, cov
    odom_pose: np.ndarray | None = None  # last absolute odometry-frame pose, if given
    dead_reckoning: np.ndarray = field(default_factory=lambda: np.zeros(3))
    dr_t: list[float] = field(default_factory=list)
    dr_poses: list[np.ndarray] = field(default_factory=list)


class _Timer:
    def __init__(self) -> None:
        self.step: dict[str, float] = {}
        self.history: dict[str, list[float]] = defaultdict(list)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.step[stage] = self.step.get(stage, 0.0) + time.perf_counter() - start

    def close_step(self) -> dict[str, float]:
        done, self.step = self.step, {}
        for stage in STAGES:
            self.history[stage].append(done.get(stage, 0.0))
        return done


class WorldModel:
    """A probabilistic semantic map of a field, built from records of any source."""

    def __init__(self, config: AgrislamConfig | None = None) -> None:
        self.config = config or AgrislamConfig()
        self.schema: FieldSchema | None = self.config.field_schema()
        self.beliefs = BeliefTable(self.schema, self.config.semantics)
        self.backend = make_backend(self.config.slam, self.config.rows)
        self.rows = RowTracker(self.config.rows) if self.config.rows.enabled else None
        self.index = SpatialIndex(self.config.association.index_margin)
        self._steps_since_rebuild = 0
        self.pruner = Pruner(self.config.maintenance)
        self.depth_bias = DepthBiasEstimator(self.config.sensor.depth_bias)
        self.drift = OdometryDrift()
        self.anchor = None
        self.issues: dict[str, int] = defaultdict(int)
        self._robots: dict[str, _Robot] = {}
        self._status = np.zeros(1024, dtype=np.int8)
        self._merged_into = np.full(1024, -1, dtype=np.int64)
        self._timer = _Timer()
        self._listeners: list[Callable[[StepReport], None]] = []

    # ------------------------------------------------------------------ records in

    def process(self, record: Record) -> StepReport | None:
        """Feed one record; a frame of detections runs a pipeline step."""
        if isinstance(record, Meta):
            self.configure(record)
        elif isinstance(record, Odometry):
            self.add_odometry(record)
        elif isinstance(record, Detections):
            return self.step(record)
        return None  # truth records are for evaluation only

    def configure(self, meta: Meta) -> None:
        """Take the schema, start poses, anchor and field knowledge of a survey."""
        if self.schema is None and meta.schema is not None and len(self.beliefs) == 0:
            self.schema = meta.schema
            self.beliefs = BeliefTable(self.schema, self.config.semantics)
        self.anchor = meta.anchor or self.anchor
        if meta.field is not None:
            self._use_field_prior(meta.field)
        for name, start in meta.robots.items():
            robot = self._robots.setdefault(name, _Robot())
            if not robot.started:
                robot.start_pose = np.asarray(start.pose, dtype=float)
                robot.start_sigma = np.asarray(start.sigma, dtype=float)

    def _use_field_prior(self, prior: FieldPrior) -> None:
        """What the survey knows of its field, unless the run's config says otherwise."""
        association = self.config.association
        if prior.min_plant_distance and "d_inter" not in association.model_fields_set:
            # a detection nearer than half the plant spacing is this plant, not its neighbour
            association.d_inter = 0.5 * prior.min_plant_distance
        if self.rows is not None:
            self.rows.use_prior(prior)

    def add_odometry(self, odom: Odometry) -> None:
        """Compose the motion into the robot's pending increment (DESIGN step 2)."""
        robot = self._robot(odom.robot, odom.t)
        delta = self._increment(robot, odom)
        if delta is None:
            return
        sensor = self.config.sensor
        cov = odom.cov if odom.cov is not None else np.diag(sensor.odom_cov_diag)
        cov = cov * np.outer(sensor.odom_sigma_scale, sensor.odom_sigma_scale)
        if robot.pending is None:
            robot.pending = (delta, cov)
        else:
            robot.pending = se2.compose_increments(*robot.pending, delta, cov)
        robot.dead_reckoning = se2.compose(robot.dead_reckoning, delta)
        robot.dr_t.append(odom.t)
        robot.dr_poses.append(robot.dead_reckoning)

    def subscribe(self, listener: Callable[[StepReport], None]) -> None:
        """Call `listener` with every step's report (the publish stage)."""
        self._listeners.append(listener)

    # ---------------------------------------------------------------- the pipeline

    def step(self, frame: Detections) -> StepReport:
        """One frame of one robot: the pipeline of DESIGN.md, top to bottom."""
        t, timer = frame.t, self._timer
        with timer("predict"):
            detections = self._valid_detections(frame)  # beliefs are predicted lazily
        with timer("add_pose"):
            self._add_pose(frame.robot, t)
        with timer("place"):
            placed = self._place(frame.robot, detections)
        with timer("associate"):
            object_ids = self._associate(frame.robot, placed, t)
            new_ids = self._create_objects(object_ids, placed, t)
            self.drift.seen(frame.robot, object_ids)
        with timer("beliefs"):
            self.beliefs.update(object_ids, [d.attributes for d in detections], t)
        with timer("geometry"):
            for i, (det, obj) in enumerate(zip(detections, object_ids.tolist(), strict=True)):
                measurement = self._measurement(det, placed.robot_xy[i], placed.robot_cov[i])
                self.backend.add_observation(frame.robot, obj, measurement)
            self.backend.update()
            self._refresh_index(np.unique(object_ids))
            self._calibrate_depth(frame.robot, placed, object_ids)
        with timer("rows"):
            if self.rows is not None:
                self.rows.after_step(self.backend, np.unique(object_ids), len(detections))
        with timer("maintain"):
            result = self._maintain(np.unique(object_ids), t)
        with timer("publish"):
            report = StepReport(t, frame.robot, self.resolve(object_ids), new_ids, result, {})
            for listener in self._listeners:
                listener(report)
        report.seconds = timer.close_step()
        return report

    # ----------------------------------------------------------------- the stages

    def _valid_detections(self, frame: Detections) -> list[Detection]:
        """Detections with their measurements checked against the schema; a bad attribute
        is dropped (and counted), the detection's geometry kept."""
        return [self._checked(det) for det in frame.objects]

    def _add_pose(self, robot_name: str, t: float) -> None:
        robot = self._robot(robot_name, t)
        if robot.pending is not None:
            delta, cov = robot.pending
            self.backend.add_odometry(robot_name, t, delta, cov)
            self.drift.advance(robot_name, robot.dead_reckoning, cov)
            robot.pending = None

    def _place(self, robot: str, detections: list[Detection]) -> PlacedDetections:
        """Detections into the map frame with their covariances (DESIGN step 3), after
        the depth-bias correction."""
        if not detections:
            return PlacedDetections(np.empty((0, 2)), np.empty((0, 2, 2)), [])
        xy = self.depth_bias.correct(np.stack([d.position() for d in detections]))
        cov = np.stack([self._robot_frame_cov(d) for d in detections])
        pose = self.backend.current_pose(robot)
        map_xy, map_cov = se2.to_map_frame(pose, xy, cov)
        pose_cov = None
        if self.config.association.detection_covariance:  # the robot pose uncertainty
            pose_cov = se2.pose_uncertainty_at(
                pose, self.backend.current_pose_covariance(robot), xy
            )
        measurements = [informative_measurements(self.schema, d.attributes) for d in detections]
        return PlacedDetections(map_xy, map_cov, measurements, xy, cov, pose_cov)

    def _associate(self, robot: str, placed: PlacedDetections, t: float) -> np.ndarray:
        """GNN over the association matrix of gated candidates (sec. 2.4); -1 = new."""
        cfg = self.config.association
        if len(placed) == 0:
            return np.empty(0, dtype=int)
        n_measured = max(len(m) for m in placed.measurements) if cfg.use_semantics else 0
        sigma = cfg.gate_sigma_max * np.sqrt(cfg.gate_chi2)  # the Mahalanobis term's reach
        radius = max_association_distance(cfg.d_inter, sigma, cfg.w_sem, n_measured)
        candidates = self.index.query(placed.xy, radius)
        if len(candidates) == 0:
            return np.full(len(placed), -1)
        object_cov = self.backend.object_covariances(candidates)
        innovation = None
        if cfg.detection_covariance:
            heading = self.backend.current_pose(robot)[2]
            drift = self.drift.since_seen(robot, candidates, placed.robot_xy, heading)
            innovation = innovation_covariance(placed, object_cov, *drift)
        matrix = association_matrix(
            placed,
            candidates,
            self.backend.object_positions(candidates),
            object_cov,
            self.beliefs,
            cfg,
            t,
            innovation,
        )
        chosen = assign(matrix)
        return np.where(chosen >= 0, candidates[np.maximum(chosen, 0)], -1)

    def _create_objects(
        self, object_ids: np.ndarray, placed: PlacedDetections, t: float
    ) -> np.ndarray:
        """Unassigned detections become new objects (in place in `object_ids`)."""
        unassigned = np.flatnonzero(object_ids < 0)
        new_ids = self.beliefs.add(len(unassigned), t)
        self._grow_status(len(self.beliefs))
        for i, obj in zip(unassigned.tolist(), new_ids.tolist(), strict=True):
            self.backend.add_object(obj, placed.xy[i])
        object_ids[unassigned] = new_ids
        self.index.move(new_ids, placed.xy[unassigned])
        self.pruner.watch(new_ids)
        return new_ids

    def finish(self) -> MaintenanceResult:
        """End of the survey: solve the whole graph once more (the real-time estimate
        folds history away, sec. 2.6), and prune the young uncertain objects still
        waiting for their grace period: they will not be seen again."""
        self.backend.refine()
        t = float(self.beliefs.last_update.max(initial=0.0))
        return self._maintain(np.empty(0, dtype=int), t, grace=0.0)

    def _maintain(
        self, touched: np.ndarray, t: float, grace: float | None = None
    ) -> MaintenanceResult:
        """Merge touched objects closer than d_inter; prune young uncertain ones."""
        cfg, result = self.config.maintenance, MaintenanceResult()
        touched = touched[self._status[touched] == STATUS_ACTIVE]
        if cfg.merge and len(touched):
            pairs = merge_pairs(
                touched,
                self.backend.object_positions(touched),
                self.index,
                self.backend.object_positions,
                self.beliefs.n_meas,
                self.config.association.d_inter,
            )
            result.merged = self._merge(pairs)
        if cfg.prune:
            for obj in self.pruner.due(self.beliefs, t, grace):
                if self._status[obj] == STATUS_ACTIVE:
                    self.backend.remove_object(obj)
                    self._retire(obj, STATUS_PRUNED)
                    result.pruned.append(obj)
        return result

    def _merge(self, pairs: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """Fold each `drop` into its `keep`: beliefs fused, graph nodes merged."""
        for keep, drop in pairs:
            self.beliefs.fuse(keep, drop)
            self.backend.merge_objects(keep, drop)
            self.drift.merge(keep, drop)
            self._retire(drop, STATUS_MERGED, into=keep)
        return pairs

    # ------------------------------------------------------------------ map out

    def active_ids(self) -> np.ndarray:
        return np.flatnonzero(self._status[: len(self.beliefs)] == STATUS_ACTIVE)

    def resolve(self, ids: np.ndarray) -> np.ndarray:
        """The object each id stands for now, following merges."""
        ids = np.array(ids, dtype=np.int64, copy=True)
        while True:
            target = self._merged_into[ids]
            moved = target >= 0
            if not moved.any():
                return ids
            ids[moved] = target[moved]

    def snapshot(self, t: float | None = None, with_surface: bool = True) -> MapSnapshot:
        """The current map as plain arrays (all active objects, brought to time t)."""
        ids = self.active_ids()
        t = t if t is not None else float(self.beliefs.last_update[ids].max(initial=0.0))
        xy = self.backend.object_positions(ids) if len(ids) else np.empty((0, 2))
        h = self.beliefs.interest(ids, t)
        objects = ObjectMap(
            ids=ids,
            xy=xy,
            cov=self.backend.object_covariances(ids) if len(ids) else np.empty((0, 2, 2)),
            n_meas=self.beliefs.n_meas[ids].copy(),
            interest=h,
            row=self.rows.row_of(ids) if self.rows is not None else np.full(len(ids), -1),
            discrete={n: self.beliefs.probabilities(n, ids, t) for n in self._names("discrete")},
            continuous={n: self.beliefs.gaussian(n, ids, t) for n in self._names("continuous")},
        )
        trajectories, dead_reckoning = {}, {}
        for name, robot in self._robots.items():
            times, poses = self.backend.trajectory(name)
            trajectories[name] = Trajectory(name, times, poses)
            dead_reckoning[name] = Trajectory(
                name, np.asarray(robot.dr_t), np.asarray(robot.dr_poses).reshape(-1, 3)
            )
        surface = (
            interest_surface(xy, h, self.config.semantics) if with_surface and len(ids) else None
        )
        return MapSnapshot(
            schema=self.schema,
            objects=objects,
            trajectories=trajectories,
            dead_reckoning=dead_reckoning,
            anchor=self.anchor,
            rows=self.rows.lines() if self.rows is not None else None,
            interest_surface=surface,
            step_times={k: np.asarray(v) for k, v in self._timer.history.items()},
        )

    # ----------------------------------------------------------------- helpers

    def _robot(self, name: str, t: float) -> _Robot:
        """The robot's chain, started in the back end at its first record's time."""
        robot = self._robots.get(name)
        if robot is None:
            robot = self._robots[name] = _Robot()
        if not robot.started:
            if robot.start_pose is None and any(r.started for r in self._robots.values()):
                # spec: a later robot without a start pose must be placed from shared
                # landmarks; a weak prior at the origin lets the graph do so
                self.issues[f"robot {name!r} has no start pose: weak prior at the origin"] += 1
                robot.start_sigma = np.array([10.0, 10.0, np.pi])
            start = np.zeros(3) if robot.start_pose is None else robot.start_pose
            self.backend.add_robot(name, start, robot.start_sigma, t)
            self.drift.start(name, start)
            robot.dead_reckoning, robot.started = start.copy(), True
            robot.dr_t.append(t)
            robot.dr_poses.append(robot.dead_reckoning)
        return robot

    @staticmethod
    def _increment(robot: _Robot, odom: Odometry) -> np.ndarray | None:
        """The motion since the robot's previous record, from `delta` or `pose`."""
        if odom.delta is not None:
            return np.asarray(odom.delta, dtype=float)
        pose = np.asarray(odom.pose, dtype=float)
        previous, robot.odom_pose = robot.odom_pose, pose
        return None if previous is None else se2.between(previous, pose)

    def _range_bearing_sigmas(self, det: Detection) -> tuple[float, float]:
        """A range/bearing detection's sigmas, or the configured defaults."""
        sensor = self.config.sensor
        return (
            det.sigma_range or sensor.detection_sigma_depth,
            det.sigma_bearing or sensor.detection_sigma_lateral / max(det.range, 1e-6),
        )

    def _robot_frame_cov(self, det: Detection) -> np.ndarray:
        if det.cov is not None:
            return det.cov
        if det.range is not None:
            sigma_range, sigma_bearing = self._range_bearing_sigmas(det)
            return detection_covariance(det.position(), sigma_range, sigma_bearing * det.range)
        sensor = self.config.sensor
        return detection_covariance(
            det.position(), sensor.detection_sigma_depth, sensor.detection_sigma_lateral
        )

    def _measurement(
        self, det: Detection, xy: np.ndarray, cov: np.ndarray
    ) -> RelativePosition | RangeBearing:
        """The factor's measurement in the form the detection came in (xy: corrected)."""
        if det.range is not None and det.xy is None:
            return RangeBearing(float(np.hypot(*xy)), det.bearing, *self._range_bearing_sigmas(det))
        return RelativePosition(xy, cov)

    def _checked(self, det: Detection) -> Detection:
        bad = [n for n, m in det.attributes.items() if not self._fits_schema(n, m)]
        if not bad:
            return det
        for name in bad:
            self.issues[f"measurement of {name!r} not in the schema: dropped"] += 1
        kept = {n: m for n, m in det.attributes.items() if n not in bad}
        return dataclasses.replace(det, attributes=kept)

    def _fits_schema(self, name: str, m: Measurement) -> bool:
        spec = self.schema.attributes.get(name) if self.schema is not None else None
        if spec is None or (spec.kind == "discrete") != isinstance(m, DiscreteMeasurement):
            return False
        if isinstance(m, DiscreteMeasurement):
            return m.value in spec.values and 0.0 <= m.p <= 1.0  # type: ignore[union-attr]
        return bool(np.isfinite(m.value) and np.isfinite(m.var) and m.var >= 0.0)

    def _refresh_index(self, touched: np.ndarray) -> None:
        """Move the touched objects in the spatial index; rebuild it now and then."""
        touched = touched[self._status[touched] == STATUS_ACTIVE]
        if len(touched):
            self.index.move(touched, self.backend.object_positions(touched))
        self._steps_since_rebuild += 1
        cfg = self.config.association
        if self._steps_since_rebuild >= cfg.index_rebuild_steps or self.index.n_fresh > 500:
            ids = self.active_ids()
            self.index.rebuild(ids, self.backend.object_positions(ids))
            self._steps_since_rebuild = 0

    def _calibrate_depth(
        self, robot: str, placed: PlacedDetections, object_ids: np.ndarray
    ) -> None:
        """Along-ray residuals of detections of well-triangulated objects refine the
        depth bias (geometry/depth_bias.py)."""
        if not self.config.sensor.estimate_depth_bias or len(object_ids) == 0:
            return
        known = self.beliefs.n_meas[object_ids] > self.config.sensor.depth_bias_min_views
        if not known.any():
            return
        pose = self.backend.current_pose(robot)
        predicted = se2.to_robot_frame(pose, self.backend.object_positions(object_ids[known]))
        self.depth_bias.observe(placed.robot_xy[known], predicted)

    def _retire(self, obj: int, status: int, into: int = -1) -> None:
        self._status[obj] = status
        self._merged_into[obj] = into
        self.index.forget(np.array([obj]))
        self.drift.forget(np.array([obj]))
        self.pruner.forget([obj])

    def _grow_status(self, n: int) -> None:
        if n <= len(self._status):
            return
        size = max(n, 2 * len(self._status))
        self._status = np.concatenate([self._status, np.zeros(size - len(self._status), np.int8)])
        self._merged_into = np.concatenate(
            [self._merged_into, np.full(size - len(self._merged_into), -1, np.int64)]
        )

    def _names(self, kind: str) -> list[str]:
        if self.schema is None:
            return []
        return list(self.schema.discrete if kind == "discrete" else self.schema.continuous)
