"""The world model: one step of the pipeline of DESIGN.md, the only orchestrator.

Records go in (from any source); the map comes out as a `MapSnapshot`. `step` takes a
frame of detections of one robot and runs the pipeline: check the measurements, add the
pose, place the detections, associate, update beliefs (each predicted to t first),
optimise, follow in the spatial index, learn the depth bias, rows, maintain (merge, close
a returning robot's loop, prune). Odometry between frames is kept in the robot's chain and
composed into the frame's pose.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np

from agrislam.association.gnn import (
    D_INTER_SAMPLE,
    PlacedDetections,
    assign,
    association_matrix,
    informative_measurements,
    innovation_covariance,
    landmark_association,
    max_association_distance,
    rivals_on_one_metric,
)
from agrislam.association.loop_closure import RECENT_S, LoopCloser
from agrislam.association.range_outliers import RANGE_ERRORS, RangeOutliers
from agrislam.association.rejoin import Rejoiner
from agrislam.backend import make_backend
from agrislam.config import AgrislamConfig, AssociationConfig, FieldSchema
from agrislam.estimation.depth_bias import DepthBiasEstimator
from agrislam.estimation.gnss import GnssFixes
from agrislam.estimation.noise_calibration import NoiseCalibration
from agrislam.estimation.rows import RowTracker
from agrislam.frontend.odometry import OdometryChain
from agrislam.geometry import se2
from agrislam.geometry.drift import since_seen
from agrislam.geometry.noise import SensorModel
from agrislam.maintenance import AfterFold, Existence, MaintenanceResult, Merger, prune_due
from agrislam.mapping.births import Births
from agrislam.mapping.index_upkeep import IndexUpkeep
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex
from agrislam.records import Detection, Detections, FieldPrior, GnssFix, Meta, Odometry, Record
from agrislam.season.prior_backend import PriorBackend
from agrislam.season.prior_map import PriorMap
from agrislam.semantics.beliefs import BeliefTable
from agrislam.semantics.heuristic import interest_surface
from agrislam.snapshot import STATUS_MERGED, STATUS_PRUNED, MapSnapshot, ObjectMap, Trajectory
from agrislam.timing import StageTimer

# what each timed stage of a step does (DESIGN.md "The pipeline, one step")
STAGES = (
    "check",  # the frame's measurements against the schema (beliefs are predicted lazily)
    "add_pose",  # the robot's pose node and odometry factor
    "gnss",  # the GNSS fixes since the last pose, as factors on the new one (issue 13)
    "place",  # detections into the map frame, with their covariances
    "associate",  # gate, association matrix, GNN; new objects
    "noise",  # pairs of sightings of re-observed objects scale the noise (calibration.py)
    "beliefs",  # Bayes / Kalman updates, each belief brought to t first
    "confirm",  # young objects in view: counted, confirmed or dropped (maintenance.Existence)
    "optimise",  # measurement factors and the back end's incremental solve
    "index",  # the spatial index follows the objects the solve moved
    "depth_bias",  # the depth bias learned from this frame's residuals
    "rows",  # row fits and row constraints
    "maintain",  # merge (and close a returning robot's loop), prune
)
# the parts `release` lets go of
RELEASED = ("backend", "objects", "index", "rows", "robots", "existence", "rejoiner", "loops")


class Released:
    """A released part of a world model: any use of it says what happened."""

    def __init__(self, part: str) -> None:
        self._part = part

    def _refuse(self) -> NoReturn:
        raise RuntimeError(
            f"the world model's {self._part!r} was released once the run's map was taken "
            "(WorldModel.release): it maps and answers nothing more"
        )

    def __getattr__(self, name: str) -> Any:
        self._refuse()

    def __len__(self) -> int:
        self._refuse()

    def __getitem__(self, key: Any) -> Any:
        self._refuse()


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


class WorldModel:
    """A probabilistic semantic map of a field, built from records of any source.

    The configuration is read, never written: what a survey's meta adds (its schema, its
    field prior's plant spacing) is kept on the world, so one config object serves any
    number of surveys."""

    def __init__(self, config: AgrislamConfig | None = None) -> None:
        self.config = config or AgrislamConfig()
        self.schema: FieldSchema | None = self.config.field_schema()
        self.association: AssociationConfig = self.config.association
        self.sensor = SensorModel(self.config.sensor)
        self.noise = NoiseCalibration(self.config.sensor.calibration)
        self.objects = ObjectTable(BeliefTable(self.schema, self.config.semantics))
        self.backend = make_backend(self.config.slam, self.config.rows)
        self.rows = RowTracker(self.config.rows) if self.config.rows.enabled else None
        self.index = SpatialIndex(self.association.index_margin, self.association.index_sweep_steps)
        self.objects.on_retire(self.index.forget)
        self.index_upkeep = IndexUpkeep()
        self._after_fold, self.merger, self.outliers = AfterFold(), Merger(), RangeOutliers()
        self.depth_bias = DepthBiasEstimator(self.config.sensor.depth_bias)
        self.existence = Existence(self.config.maintenance)
        self.anchor = None
        self.issues: Counter[str] = self.backend.issues  # with what the back end isolated
        self.births = Births(RECENT_S)  # which objects are old (rejoin, loop closure)
        self.rejoiner = Rejoiner(self.index, self.births, self.issues)
        self.loops = LoopCloser(self.births, self.issues)
        self.robots: dict[str, OdometryChain] = {}
        self._field_prior: FieldPrior | None = None
        # the defaults that depend on the survey are chosen; the first sharpest sigmas (d_inter)
        self._settled, self._sharpest = False, np.empty(0)
        self.gnss = GnssFixes(self.config.gnss)
        self._timer = StageTimer(STAGES)
        self.prior: PriorMap | None = None  # a saved map this survey continues (issue 15)
        self.survey_start: float | None = None  # absolute time (Unix s) of t = 0

    def use_prior(self, prior: PriorMap) -> None:
        """Continue a saved map: its plants enter with the survey's meta (whose start time
        says how long they grew). Call before the first record."""
        if len(self.objects) or self.robots:
            raise RuntimeError("a prior map must be given before the survey's first record")
        self.prior = prior

    @property
    def beliefs(self) -> BeliefTable:
        """The objects' semantic beliefs (the object table's semantic columns)."""
        return self.objects.beliefs

    # ------------------------------------------------------------------ records in

    def process(self, record: Record) -> StepReport | None:
        """Feed one record; a frame of detections runs a pipeline step."""
        if isinstance(record, Meta):
            self.configure(record)
        elif isinstance(record, Odometry):
            self.add_odometry(record)
        elif isinstance(record, Detections):
            return self.step(record)
        elif isinstance(record, GnssFix):
            self.add_gnss(record)
        return None  # truth records are for evaluation only

    def configure(self, meta: Meta) -> None:
        """Take the schema, start poses, anchor and field knowledge of a survey."""
        if meta.survey_start is not None:
            self.survey_start = meta.survey_start
        if self.prior is not None and not isinstance(self.backend, PriorBackend):
            self._enter_prior(self.prior, meta)
        if self.schema is None and meta.schema is not None and len(self.objects) == 0:
            self.schema = meta.schema
            self.objects = ObjectTable(BeliefTable(self.schema, self.config.semantics))
            self.objects.on_retire(self.index.forget)
        self.anchor = meta.anchor or self.anchor
        if meta.field is not None:
            self._use_field_prior(meta.field)
        for name, start in meta.robots.items():
            chain = self.robots.setdefault(name, OdometryChain())
            if not chain.started:
                chain.start_pose = np.asarray(start.pose, dtype=float)
                chain.start_sigma = np.asarray(start.sigma, dtype=float)

    def _enter_prior(self, prior: PriorMap, meta: Meta) -> None:
        """The saved plants as objects with their ids, beliefs stamped with the saved
        survey's time in this survey's clock (App. B carries them when read), positions
        answered by the prior back end until seen again."""
        if prior.schema is not None and meta.schema is not None and prior.schema != meta.schema:
            raise ValueError("the survey's schema differs from the saved map's")
        self.schema = self.schema or prior.schema
        # a map without history has no time: its beliefs are as of this survey's start
        known = np.isfinite(prior.t_abs)
        belief_time = prior.t_abs - (self.survey_start or 0.0) if known else 0.0
        self.objects = ObjectTable(prior.belief_table(self.config.semantics, belief_time))
        self.objects.on_retire(self.index.forget)
        self.objects.young[:] = False
        gaps = np.setdiff1d(np.arange(len(self.objects)), prior.ids)
        if len(gaps):
            self.objects.retire(gaps, STATUS_PRUNED)
        self.backend = PriorBackend(self.backend, prior.ids, prior.xy, prior.cov)
        self.index.rebuild(prior.ids, prior.xy)
        self.births.record(-np.inf, len(self.objects))  # started in an earlier survey

    def _use_field_prior(self, prior: FieldPrior) -> None:
        """What the survey knows of its field, unless the run's config says otherwise."""
        configured = self.config.association
        self._field_prior = prior
        if prior.row_spacing is not None and not prior.row_spacing > 0.0:
            # sources refuse such a meta; a prior built in code must not reach the rows
            self.issues[f"field prior row_spacing {prior.row_spacing} ignored"] += 1
            prior = dataclasses.replace(prior, row_spacing=None)
        if (prior.min_plant_distance or 0.0) > 0.0 and "d_inter" not in configured.model_fields_set:
            # a detection nearer than half the plant spacing is this plant, not its neighbour
            d_inter = 0.5 * prior.min_plant_distance
            self.association = configured.model_copy(update={"d_inter": d_inter})
        if self.rows is not None:
            self.rows.use_prior(prior)

    def _settle_defaults(self, detections: list[Detection]) -> None:
        """From the first detections on: a survey without a field prior is mapped as point
        landmarks (`association.landmark_defaults`), each default the config sets kept."""
        configured = self.config.association
        if self._field_prior is not None or not configured.landmark_defaults:
            self._settled = True
            return
        first = len(self._sharpest) == 0
        cov = np.stack([self.sensor.detection_covariance(d) for d in detections])
        self._sharpest = np.r_[self._sharpest, np.sqrt(np.linalg.eigvalsh(cov)[:, 0])]
        self._settled = len(self._sharpest) >= D_INTER_SAMPLE
        self.association = landmark_association(self.association, configured, self._sharpest)
        self.loops.reach = 2.0 * self.association.d_inter  # the merger's company
        if not first:
            return
        self._rows_off_by_default()
        self.merger.spare_together = self.outliers.enabled = True  # no plant spacing or rows
        # no repeating rows to mislead a lost or returning robot
        self.rejoiner.gate_chi2 = self.loops.gate_chi2 = self.association.gate_chi2
        # landmarks seen now and then from far: no confirmation (it cost VP 41 of 114 trees)
        if "existence" not in (maintenance := self.config.maintenance).model_fields_set:
            self.existence = Existence(maintenance.model_copy(update={"existence": False}))

    def add_odometry(self, odom: Odometry) -> None:
        """Compose the motion into the robot's pending increment (DESIGN step 2)."""
        chain = self._chain(odom.robot, odom.t)
        delta = chain.increment(odom.pose, odom.delta)
        if delta is not None:
            chain.move(odom.t, delta, self.sensor.odometry_covariance(odom.cov))

    def add_gnss(self, fix: GnssFix) -> None:
        """Keep a fix for the robot's next pose node; the first good fix anchors a survey
        without an anchor. A survey with fixes it can use maps without the row prior (rows
        fitted before the first fix stay), unless the config sets `rows.enabled`: the fixes
        hold the plants, and a straight line at a fitted angle fights them along a long row
        (0.1 deg over 450 m: 0.8 m) and twists the robot's heading by degrees."""
        chain = self._chain(fix.robot, fix.t)
        self.anchor = self.gnss.receive(fix, self.anchor, chain.pose)
        if self.gnss.pending and self.rows is not None and self.rows.angle is None:
            self._rows_off_by_default()

    def _rows_off_by_default(self) -> None:
        """No row prior for this survey, unless the config sets `rows.enabled`."""
        if "enabled" not in self.config.rows.model_fields_set:
            self.rows = None

    # ---------------------------------------------------------------- the pipeline

    def step(self, frame: Detections) -> StepReport:
        """One frame of one robot: the pipeline of DESIGN.md, top to bottom."""
        t, robot, timer = frame.t, frame.robot, self._timer
        with timer("check"):
            detections = self._within_schema(frame)
            if not self._settled and detections:
                self._settle_defaults(detections)
        with timer("gnss"):
            pose_cov = self._gnss_pose_covariance(robot)
        with timer("add_pose"):
            self._add_pose(robot, t)
        with timer("gnss"):
            self.gnss.attach(self.backend, robot, self.robots[robot].pose, pose_cov)
        with timer("place"):
            placed = self._place(robot, detections)
        with timer("associate"):
            object_ids = self._associate(robot, placed, t)
            pose, parts = self.backend.current_pose(robot), (self.index, self.backend, self.objects)
            on_ray = self.outliers.of_new_objects(pose, placed, object_ids, *parts)
            mapped = (on_ray < 0) | (not self.outliers.trusted)
            if not mapped.all():  # gross range errors: reported as their objects, not mapped
                self.issues[RANGE_ERRORS] += int((~mapped).sum())
                detections = [d for d, m in zip(detections, mapped, strict=True) if m]
                placed, object_ids = placed.subset(mapped), object_ids[mapped]
            new_ids = self._create_objects(object_ids, placed, t)
            self.outliers.born(object_ids[on_ray[mapped] >= 0], t, self.objects)
            seen = np.unique(object_ids)
            self.merger.saw(object_ids, placed.xy, 2.0 * self.association.d_inter)
        with timer("noise"):
            self._sighted(robot, placed, object_ids, new_ids)
        with timer("beliefs"):
            self.beliefs.update(object_ids, [d.attributes for d in detections], t)
        with timer("confirm"):
            self.existence.observe(placed.robot_xy)
            self.outliers.saw(pose, placed, object_ids, self.index, self.backend, self.objects)
            dropped = self.existence.look(pose, self.index, seen, self.objects, self._first_own)
        with timer("optimise"):
            sigma_scale = float(self.noise.scale.sigma[0])
            # a tentative object's detections say where it is, not where the robot is
            floor = np.where(self.objects.tentative[object_ids], self.association.d_inter, 0.0)
            factors = (detections, object_ids.tolist(), placed.robot_xy, placed.robot_cov, floor)
            for det, obj, xy, cov, f in zip(*factors, strict=True):
                measurement = self.sensor.measurement(det, xy, cov, sigma_scale, float(f))
                self.backend.add_observation(robot, obj, measurement)
            folded = self.backend.update()
        with timer("index"):
            self.index_upkeep.follow(self.index, seen, self.objects, self.backend, self.association)
        with timer("depth_bias"):
            self._calibrate_depth(robot, placed, object_ids)
        with timer("rows"):
            touched = self.objects.active(self._after_fold.ready(seen, folded))
            if self.rows is not None:
                # a tentative object joins no row: clutter would bend the rows
                confirmed = np.where(self.objects.tentative, 0, self.objects.n_frames)
                self.rows.after_step(self.backend, touched, len(detections), confirmed)
        with timer("maintain"):
            result = self._maintain(touched, t)
            scale = float(self.noise.scale.variance[0])
            loop = self.loops.pairs(self._robot_index(robot), t, self.objects, self.backend, scale)
            result.merged += self._merge(loop)
            result.pruned += self._prune(self.objects.active(dropped).tolist())
        on_ray[mapped] = object_ids  # the report: range errors go to their landmarks
        report = StepReport(t, robot, self.resolve(on_ray), new_ids, result, {})
        report.seconds = timer.close_step()
        return report

    # ----------------------------------------------------------------- the stages

    def _within_schema(self, frame: Detections) -> list[Detection]:
        """Detections with their measurements checked against the schema; a bad attribute
        is dropped (and counted), the detection's geometry kept."""
        checked = []
        for det in frame.objects:
            det, dropped = det.within_schema(self.schema)
            for name in dropped:
                self.issues[f"measurement of {name!r} not in the schema: dropped"] += 1
            checked.append(det)
        return checked

    def _add_pose(self, robot: str, t: float) -> None:
        pending = self._chain(robot, t).take_pending()
        if pending is not None:
            delta, parts = pending
            self.backend.add_odometry(robot, t, delta, self.noise.scale.odometry(parts))

    def _gnss_pose_covariance(self, robot: str) -> np.ndarray | None:
        """The covariance of the robot's latest pose, for the GNSS gate, when fixes wait
        (the motion since, a fraction of a second, adds little)."""
        if not self.gnss.pending.get(robot) or self.config.gnss.gate_chi2 <= 0.0:
            return None
        return self.backend.current_pose_covariance(robot)

    def _place(self, robot: str, detections: list[Detection]) -> PlacedDetections:
        """Detections into the map frame with their covariances (DESIGN step 3), after
        the depth-bias correction."""
        if not detections:
            nothing, no_cov = np.empty((0, 2)), np.empty((0, 2, 2))
            return PlacedDetections(nothing, no_cov, [], nothing, no_cov)
        xy = self.depth_bias.correct(np.stack([d.position() for d in detections]))
        cov = self.noise.scale.detection(
            np.stack([self.sensor.detection_covariance(d) for d in detections])
        )
        pose = self.backend.current_pose(robot)
        map_xy, map_cov = se2.to_map_frame(pose, xy, cov)
        pose_cov = None
        if self.association.innovation_gate:  # the robot pose uncertainty
            pose_cov = se2.pose_uncertainty_at(
                pose, self.backend.current_pose_covariance(robot), xy
            )
        measurements = [informative_measurements(self.schema, d.attributes) for d in detections]
        return PlacedDetections(map_xy, map_cov, measurements, xy, cov, pose_cov)

    def _associate(self, robot: str, placed: PlacedDetections, t: float) -> np.ndarray:
        """GNN over the association matrix of gated candidates (sec. 2.4); -1 = new."""
        cfg = self.association
        if len(placed) == 0:
            return np.empty(0, dtype=int)
        candidates = self.index.query(placed.xy, self._reach(placed))
        if len(candidates) == 0:
            return np.full(len(placed), -1)
        object_cov = self.backend.object_covariances(candidates)  # may solve: then positions
        object_xy = self.backend.object_positions(candidates)
        innovation = None
        if cfg.innovation_gate:
            drift = self._drift_since_seen(robot, candidates, placed)
            own = innovation_covariance(placed, object_cov, *drift)
            innovation = rivals_on_one_metric(own, placed.xy, object_xy, cfg.d_inter)
        matrix = association_matrix(
            placed,
            candidates,
            object_xy,
            object_cov,
            self.beliefs,
            cfg,
            t,
            innovation,
        )
        chosen = assign(matrix)
        ids = np.where(chosen >= 0, candidates[np.maximum(chosen, 0)], -1)
        pose = self.backend.current_pose(robot)
        return self.rejoiner.rejoin(pose[:2], placed, ids, t, self.backend)

    def _reach(self, placed: PlacedDetections) -> float:
        """The farthest an object may be from a detection and still be associated."""
        cfg = self.association
        n_measured = max(len(m) for m in placed.measurements) if cfg.use_semantics else 0
        sigma = cfg.gate_sigma_max * np.sqrt(cfg.gate_chi2)  # the Mahalanobis term's reach
        return max_association_distance(cfg.d_inter, sigma, cfg.w_sem, n_measured)

    def _drift_since_seen(
        self, robot: str, candidates: np.ndarray, placed: PlacedDetections
    ) -> tuple[np.ndarray, np.ndarray]:
        """(m, k, 2, 2) what the robot's drift since it last saw each candidate adds to
        each detection, and (k,) whether it has such a chain (geometry/drift.py)."""
        then = self.objects.last_seen(candidates, self._robot_index(robot))
        chain, scale = self.robots[robot], self.noise.scale
        heading = self.backend.current_pose(robot)[2]
        now, before = scale.odometry(chain.drift), scale.odometry(then.drift)
        drift = since_seen(chain.pose, now, before, then.known, placed.robot_xy, heading)
        return drift, then.known

    def _sighted(
        self, robot: str, placed: PlacedDetections, object_ids: np.ndarray, new_ids: np.ndarray
    ) -> None:
        """The frame's sightings, in the robot's dead-reckoning frame: with the robot's
        earlier sightings of the objects around, they scale the noise
        (estimation/noise_calibration.py); then the objects were last seen here."""
        chain, index = self.robots[robot], self._robot_index(robot)
        configured = placed.robot_cov / self.noise.scale.variance[0]
        xy, cov = se2.to_map_frame(chain.pose, placed.robot_xy, configured)
        if self.noise.enabled and len(placed):
            self._pair_sightings(placed, object_ids, new_ids, index, (xy, cov, chain.drift))
        self.objects.seen(object_ids, index, chain.drift, xy, cov)

    def _pair_sightings(
        self,
        placed: PlacedDetections,
        object_ids: np.ndarray,
        new_ids: np.ndarray,
        robot: int,
        frame: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> None:
        """The frame's detections with the robot's own last sightings of the objects
        around, for the noise calibration, with what it needs to tell a sure pair."""
        around = self.objects.active(self.index.query(placed.xy, 3.0 * self._reach(placed)))
        around = around[~np.isin(around, new_ids)]
        if len(around) < 1:
            return
        dist = np.linalg.norm(
            placed.xy[:, None, :] - self.backend.object_positions(around)[None], axis=2
        )
        then = self.objects.last_seen(around, robot)
        chosen = object_ids[:, None] == around[None, :]
        last = (then.known, then.xy, then.cov, then.drift)
        self.noise.observe(frame, robot, around, last, chosen, dist)

    @property
    def _first_own(self) -> int:
        """The first object id this survey started (a saved map's plants come first)."""
        return int(self.prior.ids.max(initial=-1)) + 1 if self.prior is not None else 0

    def _create_objects(
        self, object_ids: np.ndarray, placed: PlacedDetections, t: float
    ) -> np.ndarray:
        """Unassigned detections become new objects (in place in `object_ids`)."""
        unassigned = np.flatnonzero(object_ids < 0)
        new_ids = self.objects.add(len(unassigned), t, tentative=self.existence.enabled)
        for i, obj in zip(unassigned.tolist(), new_ids.tolist(), strict=True):
            self.backend.add_object(obj, placed.xy[i])
        object_ids[unassigned] = new_ids
        self.births.record(t, len(self.objects))
        self.index.move(new_ids, placed.xy[unassigned])
        return new_ids

    def finish(self) -> MaintenanceResult:
        """End of the survey: solve the whole graph once more (the real-time estimate
        folds history away, sec. 2.6), and prune the young uncertain objects still
        waiting for their grace period: they will not be seen again; then those still
        tentative that the survey's detections say are not there (maintenance.Existence)."""
        self.backend.refine()
        for name, chain in self.robots.items():
            if not chain.started:
                self.issues[f"robot {name!r} is in the meta but has no records"] += 1
        t = float(self.objects.last_update.max(initial=0.0))
        result = self._maintain(self._after_fold.ready(np.empty(0), False), t, grace=0.0)
        ids = self.objects.active(np.arange(self._first_own, len(self.objects)))  # not saved
        poses = [self.backend.trajectory(r)[1] for r, c in self.robots.items() if c.started]
        absent = self.existence.absent(ids, self.backend.object_positions, self.objects, poses)
        outliers = self.outliers.made_of_outliers(ids, self.objects.n_meas)
        result.pruned += self._prune(sorted(set(absent + outliers)))
        return result

    def _maintain(
        self, touched: np.ndarray, t: float, grace: float | None = None
    ) -> MaintenanceResult:
        """Merge touched objects (maintenance.Merger); prune young uncertain ones."""
        cfg, result = self.config.maintenance, MaintenanceResult()
        touched = self.objects.active(touched)
        if cfg.merge and len(touched):
            positions, d_inter = self.backend.object_positions, self.association.d_inter
            pairs = self.merger.pairs(touched, self.index, positions, self.objects, d_inter)
            result.merged = self._merge(pairs)
        if cfg.prune:
            result.pruned = self._prune(prune_due(self.objects, t, cfg, grace))
        return result

    def _prune(self, ids: list[int]) -> list[int]:
        """The objects leave the graph and the map."""
        for obj in ids:
            self.backend.remove_object(obj)
        if ids:
            self.objects.retire(np.array(ids), STATUS_PRUNED)
        return ids

    def _merge(self, pairs: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """Fold each `drop` into its `keep`: beliefs fused, graph nodes merged."""
        for keep, drop in pairs:
            self.beliefs.fuse(keep, drop)
            self.backend.merge_objects(keep, drop)
            self.objects.absorb(keep, drop)
            self.merger.merged(keep, drop)
            self.objects.retire(np.array([drop]), STATUS_MERGED, into=keep)
        return pairs

    # ------------------------------------------------------------------ map out

    def active_ids(self) -> np.ndarray:
        return self.objects.active_ids()

    def resolve(self, ids: np.ndarray) -> np.ndarray:
        """The object each id stands for now, following merges."""
        return self.objects.resolve(ids)

    def snapshot(self, t: float | None = None, with_surface: bool = True) -> MapSnapshot:
        """The current map as plain arrays (all active objects, brought to time t)."""
        ids = self.active_ids()
        t = t if t is not None else float(self.objects.last_update[ids].max(initial=0.0))
        xy = self.backend.object_positions(ids) if len(ids) else np.empty((0, 2))
        h = self.beliefs.interest(ids, t)
        objects = ObjectMap(
            ids=ids,
            xy=xy,
            cov=self.backend.object_covariances(ids) if len(ids) else np.empty((0, 2, 2)),
            n_meas=self.objects.n_meas[ids].copy(),
            interest=h,
            row=self.rows.row_of(ids) if self.rows is not None else np.full(len(ids), -1),
            discrete=self.beliefs.discrete_beliefs(ids, t),
            continuous=self.beliefs.continuous_beliefs(ids, t),
        )
        trajectories, dead_reckoning = {}, {}
        for name, chain in self.robots.items():
            if not chain.started:  # named in the meta, never drove: no trajectory
                continue
            times, poses = self.backend.trajectory(name)
            trajectories[name] = Trajectory(name, times, poses)
            dead_reckoning[name] = Trajectory(name, *chain.track())
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

    def release(self) -> None:
        """The run's map is taken (`snapshot`): the solver, the index and the per-object
        state go, so that writing a whole field's outputs reuses their memory (issue 14)."""
        for part in RELEASED:
            setattr(self, part, Released(part))

    # ----------------------------------------------------------------- helpers

    def _chain(self, name: str, t: float) -> OdometryChain:
        """The robot's odometry chain, started in the back end at its first record's time."""
        chain = self.robots.get(name)
        if chain is None:
            chain = self.robots[name] = OdometryChain()
        if not chain.started:
            if chain.start_pose is None and any(c.started for c in self.robots.values()):
                # spec: a later robot without a start pose must be placed from shared
                # landmarks; a weak prior at the origin lets the graph do so
                self.issues[f"robot {name!r} has no start pose: weak prior at the origin"] += 1
                chain.start_sigma = np.array([10.0, 10.0, np.pi])
            start = np.zeros(3) if chain.start_pose is None else chain.start_pose
            self.backend.add_robot(name, start, chain.start_sigma, t)
            chain.start(start, t)
        return chain

    def _robot_index(self, name: str) -> int:
        """A robot's number, in the order robots were first heard of."""
        return list(self.robots).index(name)

    def _calibrate_depth(self, robot: str, placed: PlacedDetections, ids: np.ndarray) -> None:
        """Along-ray residuals of well-triangulated objects refine the depth bias."""
        if not self.config.sensor.estimate_depth_bias:
            return
        known = self.objects.n_meas[ids] > self.config.sensor.depth_bias_min_views
        if known.any():
            xy = self.backend.object_positions(ids[known])
            predicted = se2.to_robot_frame(self.backend.current_pose(robot), xy)
            self.depth_bias.observe(placed.robot_xy[known], predicted)
