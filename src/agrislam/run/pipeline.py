"""A survey run end to end: records from a source, poses synchronised to the frames and
combined labels split, through the world model, to the output folder; ground truth is
kept aside for scoring. What the CLI runs, for any source."""

from __future__ import annotations

import dataclasses
import gc
import importlib.util
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.config import OutputsConfig, SemanticsConfig
from agrislam.evaluation.ground_truth import TruthObjects
from agrislam.evaluation.metrics import association_counts, evaluate, write_metrics
from agrislam.growing import GrowingRows
from agrislam.io.perception.label_map import LabelMap
from agrislam.io.sinks.atomic import atomic_path
from agrislam.io.sinks.csv import write_objects_csv, write_table, write_trajectory_csv
from agrislam.io.sinks.foxglove import write_foxglove_mcap
from agrislam.io.sinks.geojson import write_geojson
from agrislam.io.sinks.geopackage import write_geopackage
from agrislam.io.sinks.isoxml import write_isoxml
from agrislam.io.sinks.report import write_report
from agrislam.io.sinks.ros_map import write_map_mcap
from agrislam.io.sinks.run_folder import RunFolder, RunFolderError
from agrislam.io.sinks.shapefile import write_shapefile
from agrislam.io.sinks.sqlite import save_map, write_checkpoint
from agrislam.io.sources.base import Source, SourceError, SourceReport
from agrislam.io.sources.sync import synchronise
from agrislam.records import Detections, Meta, Record, TruthObject, TruthPose
from agrislam.run.checkpoint import FORMAT, Checkpoints, RunState, adopt
from agrislam.run.collector import PacedCollector, release_free_heap
from agrislam.run.health import Health
from agrislam.run.season import SeasonRun
from agrislam.run.season_outputs import season_outputs
from agrislam.season.field_learning import learn_field
from agrislam.semantics.heuristic import interest_surface
from agrislam.snapshot import MapSnapshot, Trajectory
from agrislam.world import StepReport, WorldModel


@dataclass(slots=True)
class Truth:
    """What the source knows of the real field; the world model never sees it."""

    objects: TruthObjects = field(default_factory=TruthObjects)  # numbers the truth ids
    tracks: dict[str, tuple[GrowingRows, GrowingRows]] = field(default_factory=dict)
    min_plant_distance: float | None = None
    detection_truths: GrowingRows = field(default_factory=lambda: GrowingRows(dtype=np.int32))
    detection_objects: GrowingRows = field(default_factory=lambda: GrowingRows(dtype=np.int32))

    @property
    def present(self) -> bool:
        return bool(len(self.objects) or self.tracks)

    def add_pose(self, record: TruthPose) -> None:
        """A true pose, kept in its robot's arrays (times, poses) in the order it came."""
        times, poses = self.tracks.setdefault(record.robot, (GrowingRows(), GrowingRows((3,))))
        times.append(record.t)
        poses.append(record.pose)

    def trajectories(self) -> dict[str, Trajectory]:
        """Each robot's true poses in time order (`evaluation.truth_trajectories` of the
        records), straight from the arrays: no TruthPose object per pose."""
        out = {}
        for robot, (times, poses) in self.tracks.items():
            order = np.argsort(times.array, kind="stable")
            out[robot] = Trajectory(robot, times.array[order], poses.array[order])
        return out

    def saw(self, truth_ids: Iterable[str | None], object_ids: np.ndarray) -> None:
        """A frame's detections: the truth id of each (None: clutter) and its object; kept
        in two int arrays, the ids numbered once each."""
        number = self.objects.number
        truths = [-1 if t is None else number(t) for t in truth_ids]
        self.detection_truths.extend(truths)
        self.detection_objects.extend(object_ids)

    def association_arrays(self, final_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(truth number, -1 clutter) and final object id of every detection, given the
        object each id stands for at the end (`final_ids`, by id: merges followed)."""
        truths = self.detection_truths.array.astype(np.int64)
        return truths, final_ids[self.detection_objects.array]


@dataclass(slots=True)
class RunResult:
    """What a run did. `error`: what stopped it (None: it read its source to the end);
    `records`: records the world model took, by kind; `output_errors`: outputs that could
    not be written, and why."""

    snapshot: MapSnapshot | None
    metrics: dict[str, Any] | None
    wall_seconds: float
    n_frames: int
    outputs: list[Path]
    issues: dict[str, int]
    error: BaseException | None = None
    records: dict[str, int] = field(default_factory=dict)
    output_errors: dict[str, str] = field(default_factory=dict)
    source_report: SourceReport | None = None
    noise: dict[str, Any] | None = None  # the noise scales the run estimated (noise_calibration)
    existence: dict[str, Any] | None = None  # young objects confirmed, dropped (maintenance/)
    sensor: dict[str, Any] | None = None  # each range-bearing sensor's biases, as learned
    gnss: dict[str, int] = field(default_factory=dict)  # fixes used and rejected
    checkpoints: dict[str, Any] | None = None  # resumed at which record, checkpoints taken
    season: dict[str, Any] | None = None  # a survey that continued a saved map
    health: Health = field(default_factory=Health)  # what the map did, minute by minute
    align: bool = False  # the map frame is the first robot's first pose: aligned to be scored

    @property
    def usable(self) -> bool:
        """Whether the source gave the map anything to work with (motion or detections)."""
        return bool(self.records.get("Odometry") or self.records.get("Detections"))

    @property
    def status(self) -> str:
        if self.error is None:
            return "finished"
        return f"stopped after {sum(self.records.values())} records: {describe(self.error)}"


class RunError(Exception):
    """A run that stopped before the end of its source (an error of the source, the core
    or an interrupt, `__cause__`); `result` holds what was mapped until then and the
    outputs written of it."""

    def __init__(self, result: RunResult) -> None:
        assert result.error is not None
        super().__init__(result.status)
        self.result = result


def describe(error: BaseException) -> str:
    """An error in one line: its message, with its type where the message alone is vague."""
    if isinstance(error, KeyboardInterrupt):
        return "interrupted"
    text = str(error).strip().splitlines()[0] if str(error).strip() else ""
    if isinstance(error, (SourceError, RunFolderError)) and text:
        return text
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def run_survey(
    records: Iterable[Record] | Source,
    world: WorldModel,
    out_dir: str | Path | RunFolder | None = None,
    progress: Callable[[], None] | None = None,
    *,
    force: bool = False,
    checkpoints: Checkpoints | None = None,
    resume: bool = False,
    season: SeasonRun | None = None,
    release_world: bool = False,
) -> RunResult:
    """Feed every record to the world model, then score the map and write the outputs.

    `records`: a source (its report then goes into the outputs: `skipped.csv` and the
    metrics' `input` section) or any records. `out_dir`: a folder, checked and locked
    before the first record is read (`sinks.run_folder`; `force` replaces an earlier run's
    outputs), or a `RunFolder` the caller holds. Whatever stops the run (a bad line in
    strict mode, an error of the core, Ctrl-C), the map of the records before it is
    written and `RunError` raised with the result.

    `checkpoints`: save the run's state every so many frames (`agrislam.run.checkpoint`);
    `resume`: first carry on from the checkpoint there (`ResumeError` if it is of another
    input or config), skipping the records it had mapped. `release_world`: once the map is
    taken and scored, the world model lets its solver and per-object state go
    (`WorldModel.release`), so the outputs of a whole field reuse that memory; for a
    caller that does not use the world after the run (the CLI)."""

    def run(folder: RunFolder | None) -> RunResult:
        return _run(records, world, folder, progress, checkpoints, resume, season, release_world)

    if isinstance(out_dir, (str, Path)):
        with RunFolder(out_dir, force=force, resume=resume) as folder:
            result = run(folder)
    else:
        result = run(out_dir)
    if result.error is not None:
        raise RunError(result) from result.error
    return result


def _run(
    records: Iterable[Record] | Source,
    world: WorldModel,
    folder: RunFolder | None,
    progress: Callable[[], None] | None,
    checkpoints: Checkpoints | None = None,
    resume: bool = False,
    season: SeasonRun | None = None,
    release_world: bool = False,
) -> RunResult:
    source = records if isinstance(records, Source) else None
    stream = source.records() if source is not None else records
    saved = checkpoints.resume() if checkpoints is not None and resume else None
    state = _carry_on(world, saved) if saved is not None else RunState(world, Truth())
    resumed_at, issues = state.position, Counter[str]()
    synced = synchronise(stream)
    start = time.perf_counter()
    error = None
    try:
        with PacedCollector() as collector:  # no full collection mid-step
            if season is None:  # the field prior a log does not give, from its plants
                gated = learn_field(synced, world.config, issues)
            else:
                gated = season.gate(synced, world)
            for position, record in enumerate(_split_labels(gated, world, issues), 1):
                if position > state.position:  # else mapped before the checkpoint resumed
                    frame = _feed(record, world, state.truth, state.health)
                    if frame:
                        collector.frame()
                    state.n_frames += frame
                    state.counts[type(record).__name__] += 1
                    state.position = position
                    if frame and checkpoints is not None and checkpoints.due(state.n_frames):
                        state = _carry_on(world, checkpoints.take(state))
                if progress is not None:
                    progress()
            done = world.finish()  # the robots placed at the end map their frames first
            state.n_frames += _stepped(world.take_late_frames(), state.truth, state.health)
            state.health.finish(done)
            if season is not None:
                season.finish(world)
    except (Exception, KeyboardInterrupt) as err:  # the map so far is still written
        error = err
    wall = time.perf_counter() - start
    truth, counts, n_frames = state.truth, state.counts, state.n_frames
    for frame, reason in synced.unplaced:
        issues[f"frame of {frame.robot!r} not placed: {reason}"] += 1
    issues.update(world.issues)
    issues.update(checkpoints.issues if checkpoints is not None else {})
    result = RunResult(None, None, wall, n_frames, [], dict(issues), error, dict(counts))
    result.source_report = source.report if source is not None else None
    result.health = state.health
    learned = world.report()
    result.noise, result.existence, result.gnss, result.sensor = (
        learned[k] for k in ("noise", "existence", "gnss", "sensor")
    )
    if checkpoints is not None:
        result.checkpoints = {
            "resumed_at_record": resumed_at if saved is not None else None,
            "taken": checkpoints.taken,
            "seconds": checkpoints.seconds,
        }
    result.snapshot = _snapshot(world, result)
    result.align = world.frame_free
    scoring = result.snapshot is not None and truth.present
    final_ids = world.resolve(np.arange(len(world.objects))) if scoring else None
    writing = folder is not None and (counts or error is None)
    extra = season_outputs(season, world, result.snapshot) if writing else None
    if writing and release_world:
        _let_go(world)  # the scores, the surface and the outputs reuse its memory
    if final_ids is not None:
        result.metrics = _score(result, final_ids, truth)
    _add_surface(result, world.settings.semantics)
    summary = _summary(result)
    if season is not None:
        summary["season"] = season.summary()
        result.season = summary["season"]
    if folder is not None and writing:
        kept = None  # a stopped run keeps its last checkpoint in map.sqlite, to resume
        if checkpoints is not None and error is not None:
            kept = checkpoints.last or {"format": FORMAT}
        result.outputs, result.output_errors = write_outputs(
            result.snapshot,
            folder.path,
            result.metrics,
            truth,
            summary,
            world.config.outputs,
            kept,
            extra,
        )
    return result


def _let_go(world: WorldModel) -> None:
    """The world's state goes before the outputs are written: they reuse its memory."""
    world.release()
    gc.collect()  # a deferred covariance job holds the back end that holds it
    release_free_heap()


def _carry_on(world: WorldModel, state: RunState) -> RunState:
    """The run goes on from `state` (a checkpoint read back), in the caller's world."""
    adopt(world, state.world)
    state.world = world
    return state


def _feed(record: Record, world: WorldModel, truth: Truth, health: Health) -> int:
    """One record to the world model (truth aside, the steps' health kept); the frames it
    mapped: this one, and those of a robot it placed (`WorldModel.take_late_frames`)."""
    if isinstance(record, TruthObject):
        truth.objects.add(record)
        return 0
    if isinstance(record, TruthPose):
        truth.add_pose(record)
        return 0
    if isinstance(record, Meta) and record.field is not None:
        truth.min_plant_distance = record.field.min_plant_distance
    report = world.process(record)
    frames = world.take_late_frames()
    if report is not None and isinstance(record, Detections):
        frames.append((record, report))
    return _stepped(frames, truth, health)


def _stepped(frames: list[tuple[Detections, StepReport]], truth: Truth, health: Health) -> int:
    """The frames mapped, with their steps, in the truth and the health; how many."""
    for frame, step in frames:
        truth.saw((d.truth_id for d in frame.objects), step.object_ids)
        health.step(step)
    return len(frames)


def _snapshot(world: WorldModel, result: RunResult) -> MapSnapshot | None:
    """The world's map without its interest surface (`_add_surface`), also after an
    error; None, with an issue, if the world cannot give one at all."""
    try:
        return world.snapshot(with_surface=False)
    except Exception as err:
        failed = describe(err)
    result.issues[f"no map: the snapshot failed ({failed})"] = 1
    if result.error is None:
        result.error = RuntimeError(f"the map could not be read: {failed}")
    return None


def _add_surface(result: RunResult, config: SemanticsConfig) -> None:
    """The map's interest surface, from its objects' positions and interest alone: made once
    the world's state may be released, so its grids reuse that memory; an issue, and a map
    without it, if it cannot be made."""
    snapshot = result.snapshot
    if snapshot is None or len(snapshot.objects.ids) == 0:
        return
    try:
        surface = interest_surface(snapshot.objects.xy, snapshot.objects.interest, config)
    except Exception as err:
        result.issues[f"no interest surface: {describe(err)}"] = 1
        return
    result.snapshot = dataclasses.replace(snapshot, interest_surface=surface)


def _score(result: RunResult, final_ids: np.ndarray, truth: Truth) -> dict[str, Any] | None:
    assert result.snapshot is not None
    try:
        metrics = evaluate(
            result.snapshot,
            truth.objects,
            truth.trajectories(),
            min_plant_distance=truth.min_plant_distance,
            align=result.align,
        )
        if len(truth.detection_objects):
            metrics["association"] = association_counts(*truth.association_arrays(final_ids))
    except Exception as err:
        result.issues[f"no scores: evaluation failed ({describe(err)})"] = 1
        return None
    metrics["run"] = {"wall_seconds": result.wall_seconds, "frames": result.n_frames}
    return metrics


def _summary(result: RunResult) -> dict[str, Any]:
    """The run's own sections of metrics.json: status, what was read and skipped, issues,
    and the map's health by minute (run/health.py)."""
    report = result.source_report
    return {
        "run": {
            "status": result.status,
            "wall_seconds": result.wall_seconds,
            "frames": result.n_frames,
            "records": result.records,
            "issues": result.issues,
            "noise_calibration": result.noise,
            "sensor_calibration": result.sensor,
            "existence": result.existence,
            "checkpoints": result.checkpoints,
        },
        "input": report.as_dict() if report is not None else None,
        "skipped": skipped_table(report),
        "health": result.health.rows(),
        **({"gnss": result.gnss} if result.gnss else {}),
    }


def skipped_table(report: SourceReport | None) -> dict[str, list[Any]] | None:
    """A source's skipped input as columns (a log's lines, a bag's messages), if any."""
    table = getattr(report, "skipped_table", None)
    columns = table() if callable(table) else None
    return columns if columns and any(len(c) for c in columns.values()) else None


def _split_labels(
    records: Iterable[Record], world: WorldModel, issues: Counter
) -> Iterator[Record]:
    """Combined detector labels (`crop_small_healthy`) into attribute measurements, with
    the schema of the run; a label the map cannot split is reported, its geometry kept."""
    labels: LabelMap | None = None
    for record in records:
        if isinstance(record, Detections) and any(d.label for d in record.objects):
            if labels is None:  # after the Meta record: the schema is known now
                labels = LabelMap.from_config(world.config.label_map, world.schema)
            objects = []
            for det in record.objects:
                try:
                    objects.append(labels.apply(det))
                except ValueError as err:
                    issues[f"detection label dropped: {err}"] += 1
                    objects.append(dataclasses.replace(det, label=None, label_p=None))
            record = dataclasses.replace(record, objects=tuple(objects))
        yield record


GEO_FILES = {
    "geojson": "map.geojson",
    "gpkg": "map.gpkg",
    "isoxml": "taskdata.zip",
    "shapefile": "prescription_shp.zip",
}


def geo_writers(
    snapshot: MapSnapshot, cfg: OutputsConfig
) -> list[tuple[str, Callable[[Path], Any]]]:
    """The georeferenced files `outputs.formats` names; by default GeoJSON and GeoPackage when
    the map has an anchor. A named format the map cannot take (no anchor, no weeds) is an
    output error of the run."""
    if cfg.formats is None and snapshot.anchor is None:
        return []
    write = {
        "geojson": lambda p: write_geojson(snapshot, p),
        "gpkg": lambda p: write_geopackage(snapshot, p),
        "isoxml": lambda p: write_isoxml(snapshot, p, cfg),
        "shapefile": lambda p: write_shapefile(snapshot, p, cfg),
    }
    formats = cfg.formats if cfg.formats is not None else ["geojson", "gpkg"]
    return [(GEO_FILES[f], write[f]) for f in dict.fromkeys(formats)]


def _save_map(snapshot: MapSnapshot, path: Path, checkpoint: dict[str, bytes] | None) -> None:
    save_map(snapshot, path)
    if checkpoint is not None:
        write_checkpoint(path, checkpoint)


def write_outputs(
    snapshot: MapSnapshot | None,
    out_dir: Path,
    metrics: dict[str, Any] | None,
    truth: Truth,
    summary: dict[str, Any] | None = None,
    outputs: OutputsConfig | None = None,
    checkpoint: dict[str, bytes] | None = None,
    extra: list[tuple[str, Callable[[Path], Any]]] | None = None,
) -> tuple[list[Path], dict[str, str]]:
    """The files of DESIGN.md "Outputs of a run", each written atomically (a killed run
    leaves whole files only) and each on its own: one that fails is reported in the second
    value (name -> why) and the others are still written. `summary`: the run's own
    section of metrics.json and its skipped input (`skipped.csv`); metrics.json is written
    last, so it marks a run whose outputs are all there. `checkpoint`: entries of the
    run's last checkpoint, kept in map.sqlite (a stopped run, to resume)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = dict(summary or {})
    skipped = summary.pop("skipped", None)
    writers: list[tuple[str, Callable[[Path], Any]]] = []
    if snapshot is not None:
        writers += [
            ("objects.csv", lambda p: write_objects_csv(snapshot, p)),
            ("trajectory.csv", lambda p: write_trajectory_csv(snapshot, p)),
            ("map.sqlite", lambda p: _save_map(snapshot, p, checkpoint)),
        ]
    if skipped is not None:
        writers.append(("skipped.csv", lambda p: write_table(skipped, p)))
    if snapshot is not None:
        writers += geo_writers(snapshot, outputs or OutputsConfig())
        # MarkerArray + Path, for RViz and Foxglove
        writers.append(("map.mcap", lambda p: write_map_mcap(snapshot, p)))
        if importlib.util.find_spec("foxglove") is not None:  # the optional `foxglove` extra
            writers.append(("map_foxglove.mcap", lambda p: write_foxglove_mcap(snapshot, p)))
        trajectories = truth.trajectories()
        writers.append(
            ("report.png", lambda p: write_report(snapshot, p, metrics=metrics, truth=trajectories))
        )
    writers = _with_extra(writers, extra or [])
    written: list[Path] = []
    failed: dict[str, str] = {}
    for name, write in writers:
        try:
            with atomic_path(out_dir / name) as tmp:
                write(tmp)
        except Exception as err:
            failed[name] = describe(err)
            continue
        written.append(out_dir / name)
    if metrics is not None or summary:
        run = {**(metrics or {}).get("run", {}), **summary.get("run", {})}
        run.update(outputs=[p.name for p in written], output_errors=failed)
        with atomic_path(out_dir / "metrics.json") as tmp:
            write_metrics({**(metrics or {}), **summary, "run": run}, tmp)
        written.append(out_dir / "metrics.json")
    return written, failed


def _with_extra(
    writers: list[tuple[str, Callable[[Path], Any]]], extra: list[tuple[str, Callable[[Path], Any]]]
) -> list[tuple[str, Callable[[Path], Any]]]:
    """The writers with `extra` ones: one of the same name writes after the first into the
    same temporary file (map.sqlite gains the season's tables in the same atomic write)."""
    out = list(writers)
    for name, write in extra:
        at = next((k for k, (n, _) in enumerate(out) if n == name), None)
        if at is None:
            out.append((name, write))
        else:
            first = out[at][1]
            out[at] = (name, lambda p, first=first, write=write: (first(p), write(p)))
    return out
