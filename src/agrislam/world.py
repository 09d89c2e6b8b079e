"""The world model: records of any source in, the map out (`MapSnapshot`); the only
orchestrator. `step` runs one frame of one robot through the paper's pipeline
(docs/architecture.md), each stage an object built for the survey (stages.py)."""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.config import AgrislamConfig, FieldSchema, Settings, effective
from agrislam.maintenance.maintainer import MaintenanceResult
from agrislam.mapping.objects import ObjectTable
from agrislam.records import Anchor, Detections, FieldPrior, GnssFix, Meta, Odometry, Record
from agrislam.season.newcomers import Held, Newcomers, not_placed_issue, placed_issue
from agrislam.season.prior_map import PriorMap
from agrislam.semantics.beliefs import BeliefTable
from agrislam.semantics.heuristic import interest_surface
from agrislam.snapshot import MapSnapshot, ObjectMap, Trajectory
from agrislam.stages import Stages, build_stages
from agrislam.timing import StageTimer

# what each timed stage of a step does (docs/architecture.md, "The path of one frame")
STAGES = (
    "check",  # the frame's measurements against the schema; d_inter from the first ones
    "add_pose",  # the robot's pose node, its odometry factor and the GNSS fixes on it
    "place",  # detections into the map frame, with their covariances
    "associate",  # gate, association matrix, GNN; the safeguards; new objects
    "noise",  # pairs of sightings of re-observed objects scale the noise
    "beliefs",  # Bayes / Kalman updates, each belief brought to t first
    "confirm",  # young objects in view: counted, confirmed or dropped
    "optimise",  # measurement factors and the back end's incremental solve
    "index",  # the spatial index follows the objects the solve moved
    "depth_bias",  # the depth bias learned from this frame's residuals
    "rows",  # row fits and row constraints
    "maintain",  # merge (and close a returning robot's loop), prune
)


@dataclass(slots=True)
class StepReport:
    """What one frame did: the object each detection went to (after merges of this
    step), which objects are new, what maintenance changed, the NIS of the mapped
    detections the association put on objects (NaN for the others) and whether the frame
    rejoined the map."""

    t: float
    robot: str
    object_ids: np.ndarray
    new_ids: np.ndarray
    maintenance: MaintenanceResult
    seconds: dict[str, float]
    nis: np.ndarray = dataclasses.field(default_factory=lambda: np.empty(0))
    rejoined: bool = False


class WorldModel:
    """A probabilistic semantic map of a field, built from records of any source.

    The configuration is read, never written. A survey's stages are built from it and what
    its meta says (the field prior, the schema, a saved map it continues): again for each
    meta before the first record, never after."""

    def __init__(self, config: AgrislamConfig | None = None) -> None:
        self.config = config or AgrislamConfig()
        self.schema: FieldSchema | None = self.config.field_schema()
        self.anchor: Anchor | None = None
        self.survey_start: float | None = None  # absolute time (Unix s) of t = 0
        self.prior: PriorMap | None = None  # a saved map this survey continues
        self.issues: Counter[str] = Counter()
        self._field: FieldPrior | None = None
        self._meta_schema: FieldSchema | None = None
        self._starts: dict = {}
        self._started = False  # a record other than a meta has been read
        self.newcomers = Newcomers()  # robots without a start pose, until placed
        self._late: list[tuple[Detections, StepReport]] = []  # their frames, once placed
        self._timer = StageTimer(STAGES)
        self._build()

    def _build(self) -> None:
        """The survey's stages from the config and what its meta said so far."""
        self.settings: Settings = effective(self.config, self._field)
        prior = None
        if self.prior is not None:
            self.schema = self.config.field_schema() or self.prior.schema
            # a map without history has no time: its beliefs are as of this survey's start
            known = np.isfinite(self.prior.t_abs)
            belief_time = self.prior.t_abs - (self.survey_start or 0.0) if known else 0.0
            prior = (self.prior, belief_time)
        else:
            self.schema = self.config.field_schema() or self._meta_schema
        self.stages: Stages = build_stages(
            self.settings, self.schema, prior, self._starts, self.issues
        )
        self.issues = self.stages.backend.issues

    def use_prior(self, prior: PriorMap) -> None:
        """Continue a saved map: its plants enter the survey (whose meta says how long they
        grew). Call before the first record."""
        if self._started:
            raise RuntimeError("a prior map must be given before the survey's first record")
        self.prior = prior
        self._build()

    # ------------------------------------------------------------------ records in

    def process(self, record: Record) -> StepReport | None:
        """Feed one record; a frame of detections runs a pipeline step. The records of a
        robot without a start pose wait until it is placed (season/newcomers.py); its
        frames are then mapped, their steps kept for `take_late_frames`."""
        if isinstance(record, Meta):
            self.configure(record)
            return None
        self._started = True
        if isinstance(record, (Odometry, Detections, GnssFix)) and self._waits(record.robot):
            self.newcomers.hold(record, self.schema)
            self._place_newcomers(record.t, record.robot)
            return None
        report = self._map_record(record)
        if report is not None and self.newcomers.waiting:
            self._place_newcomers(record.t)
        return report

    def take_late_frames(self) -> list[tuple[Detections, StepReport]]:
        """The frames of robots placed late, with their steps, mapped since the last call."""
        late, self._late = self._late, []
        return late

    def _map_record(self, record: Record) -> StepReport | None:
        if isinstance(record, Odometry):
            self.stages.frontend.add_odometry(record)
        elif isinstance(record, Detections):
            return self.step(record)
        elif isinstance(record, GnssFix):
            self.add_gnss(record)
        return None  # truth records are for evaluation only

    def _waits(self, robot: str) -> bool:
        """Whether a robot's records wait for it to be placed: it has no start pose while
        the map frame is set (by a start pose of the meta, or by a robot that started)."""
        if robot in self.newcomers.waiting:
            return True
        robots = self.stages.frontend.robots
        chain = robots.get(robot)
        if chain is not None and (chain.started or chain.start_pose is not None):
            return False
        return bool(self._starts) or any(c.started for c in robots.values())

    def _place_newcomers(self, t: float, robot: str | None = None, last: bool = False) -> None:
        """Start each waiting robot whose first frames now fit the map, and map its
        records held (`robot`: whose record came; `last`: the survey's end, a last try in
        the whole map)."""
        s, season = self.stages, self.settings.season
        placed = self.newcomers.place(s.map, s.backend, season, t, robot, last)
        for name, start, held in placed:
            self.issues[placed_issue(name)] += 1
            s.frontend.use_starts({name: start})
            self._replay(held)

    def _last_newcomers(self) -> None:
        """The survey's end: the robots still waiting tried in the whole map; if no robot
        drove, the first of them starts at the origin (the spec: it was the first robot
        seen) and the others are tried in its map."""
        if not any(c.started for c in self.stages.frontend.robots.values()):
            robot, held = self.newcomers.first()
            self.issues[
                f"robot {robot!r} has no start pose, and no robot with one drove: "
                "it starts at the origin"
            ] += 1
            self._replay(held)
        t = float(self.objects.last_update.max(initial=0.0))
        self._place_newcomers(t, last=True)

    def _replay(self, held: list[Held]) -> None:
        """Map the records held for a robot placed late, in their order, their steps kept."""
        for record in held:
            report = self._map_record(record)
            if isinstance(record, Detections) and report is not None:
                self._late.append((record, report))

    @property
    def frame_free(self) -> bool:
        """Whether the map frame is only the first robot's first pose: no start pose given
        and no GNSS fix used (a map to be aligned before it is scored against truth)."""
        return not self._starts and not self.stages.estimators.gnss.counts.get("used")

    def configure(self, meta: Meta) -> None:
        """Take the schema, start poses, anchor and field knowledge of a survey. Before the
        first record the stages are built again for it; after, only the anchor and the start
        poses of robots not yet started are taken."""
        self.anchor = meta.anchor or self.anchor
        self._starts = {**self._starts, **meta.robots}
        if meta.survey_start is not None:
            self.survey_start = meta.survey_start
        if self._started:
            if meta.field is not None or meta.schema is not None:
                self.issues["a meta after the first record: its field and schema ignored"] += 1
            self.stages.frontend.use_starts(meta.robots)
            return
        saved = self.prior.schema if self.prior is not None else None
        if saved is not None and meta.schema is not None and saved != meta.schema:
            raise ValueError("the survey's schema differs from the saved map's")
        self._meta_schema = meta.schema or self._meta_schema
        if meta.field is not None:
            self._field = self._checked_field(meta.field)
        self._build()

    def _checked_field(self, field: FieldPrior) -> FieldPrior:
        """The field prior without a row spacing that is not positive (sources refuse such
        a meta; a prior built in code must not reach the rows)."""
        if field.row_spacing is not None and not field.row_spacing > 0.0:
            self.issues[f"field prior row_spacing {field.row_spacing} ignored"] += 1
            return dataclasses.replace(field, row_spacing=None)
        return field

    def add_gnss(self, fix: GnssFix) -> None:
        """Keep a fix for the robot's next pose node; the first good fix anchors a survey
        without an anchor. Rows not fitted yet give way to the fixes, unless configured."""
        self.anchor = self.stages.frontend.add_gnss(fix, self.anchor)
        self.stages.estimators.rows_give_way_to_gnss()

    # ---------------------------------------------------------------- the pipeline

    def step(self, frame: Detections) -> StepReport:
        """One frame of one robot: the paper's pipeline, top to bottom."""
        t, robot, timer, s = frame.t, frame.robot, self._timer, self.stages
        with timer("check"):
            detections = s.frontend.checked(frame)
        with timer("add_pose"):
            s.frontend.add_pose(robot, t, detections)
        with timer("place"):
            placed = s.frontend.place(robot, detections)
        with timer("associate"):  # sec. 2.4
            match = s.associator.associate(robot, detections, placed, t)
        with timer("noise"):
            s.estimators.sighted(match)
        with timer("beliefs"):  # sec. 2.5
            s.map.beliefs.update(match.object_ids, match.attributes, t)
        with timer("confirm"):
            dropped = s.maintainer.confirm(match)
        with timer("optimise"):  # sec. 2.6
            folded = s.frontend.measure(match, s.maintainer.floor(match))
        with timer("index"):
            s.map.follow(match.seen, s.backend)
        with timer("depth_bias"):
            s.estimators.calibrate_depth(match)
        with timer("rows"):  # sec. 2.6.2
            touched = s.maintainer.due(match.seen, folded)
            s.estimators.fit_rows(touched, len(match.detections))
        with timer("maintain"):  # sec. 2.6.3
            variance = float(s.estimators.noise.scale.variance[0])
            result = s.maintainer.maintain(match, touched, dropped, variance)
        ids = self.resolve(match.report_ids())
        report = StepReport(t, robot, ids, match.new_ids, result, {}, match.nis, match.rejoined)
        report.seconds = timer.close_step()
        return report

    def finish(self) -> MaintenanceResult:
        """End of the survey: solve the whole graph once more (the real-time estimate
        folds history away, sec. 2.6), then the last maintenance (maintenance/)."""
        stages = self.stages
        if self.newcomers.waiting:
            self._last_newcomers()
        stages.backend.refine()
        robots = stages.frontend.robots
        for name, chain in robots.items():
            if not chain.started:
                self.issues[f"robot {name!r} is in the meta but has no records"] += 1
        for name, (frames, reason) in self.newcomers.not_placed().items():
            self.issues[not_placed_issue(name, reason)] += frames
        t = float(self.objects.last_update.max(initial=0.0))
        trajectory = stages.backend.trajectory
        return stages.maintainer.finish(
            t, lambda: [trajectory(r)[1] for r, c in robots.items() if c.started]
        )

    # ------------------------------------------------------------------ map out

    @property
    def d_inter(self) -> float | None:
        """The survey's d_inter (sec. 2.4): configured, from its field prior, or learned from
        its first detections (None before them)."""
        return self.stages.estimators.spacing.d_inter

    @property
    def backend(self) -> GraphBackend:
        return self.stages.backend

    @property
    def objects(self) -> ObjectTable:
        return self.stages.map.objects

    @property
    def beliefs(self) -> BeliefTable:
        """The objects' semantic beliefs (the object table's semantic columns)."""
        return self.stages.map.beliefs

    def active_ids(self) -> np.ndarray:
        return self.objects.active_ids()

    def resolve(self, ids: np.ndarray) -> np.ndarray:
        """The object each id stands for now, following merges."""
        return self.objects.resolve(ids)

    def snapshot(self, t: float | None = None, with_surface: bool = True) -> MapSnapshot:
        """The current map as plain arrays (all active objects, brought to time t)."""
        stages, ids = self.stages, self.active_ids()
        backend, rows = stages.backend, stages.estimators.rows
        t = t if t is not None else float(self.objects.last_update[ids].max(initial=0.0))
        xy = backend.object_positions(ids) if len(ids) else np.empty((0, 2))
        h = self.beliefs.interest(ids, t)
        objects = ObjectMap(
            ids=ids,
            xy=xy,
            cov=backend.object_covariances(ids) if len(ids) else np.empty((0, 2, 2)),
            n_meas=self.objects.n_meas[ids].copy(),
            interest=h,
            row=rows.row_of(ids) if rows is not None else np.full(len(ids), -1),
            discrete=self.beliefs.discrete_beliefs(ids, t),
            continuous=self.beliefs.continuous_beliefs(ids, t),
        )
        trajectories, dead_reckoning = {}, {}
        for name, chain in stages.frontend.robots.items():
            if not chain.started:  # named in the meta, never drove: no trajectory
                continue
            times, poses = backend.trajectory(name)
            trajectories[name] = Trajectory(name, times, poses)
            dead_reckoning[name] = Trajectory(name, *chain.track())
        semantics = self.settings.semantics
        surface = interest_surface(xy, h, semantics) if with_surface and len(ids) else None
        return MapSnapshot(
            schema=self.schema,
            objects=objects,
            trajectories=trajectories,
            dead_reckoning=dead_reckoning,
            anchor=self.anchor,
            rows=rows.lines() if rows is not None else None,
            interest_surface=surface,
            step_times={k: np.asarray(v) for k, v in self._timer.history.items()},
        )

    def report(self) -> dict[str, Any]:
        """What the run learned of its data, for the summary and metrics.json."""
        estimators = self.stages.estimators
        return {
            "noise": estimators.noise.report(),
            "existence": self.stages.maintainer.existence.report(),
            "gnss": estimators.gnss.summary(),
            "sensor": estimators.sensor.report(),
        }

    def release(self) -> None:
        """The run's map is taken (`snapshot`): the stages go (the solver, the index, the
        per-object state), so that writing a whole field's outputs reuses their memory."""
        self.stages = Released("stages")  # type: ignore[assignment]


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
