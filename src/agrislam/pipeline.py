"""A survey run end to end: records from a source, poses synchronised to the frames and
combined labels split, through the world model, to the output folder; ground truth is
kept aside for scoring. What the CLI runs, for any source."""

from __future__ import annotations

import dataclasses
import importlib.util
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.evaluation import evaluate, truth_trajectories, write_metrics
from agrislam.perception.label_map import LabelMap
from agrislam.records import Detections, Meta, Record, TruthObject, TruthPose
from agrislam.sinks.csv import write_objects_csv, write_trajectory_csv
from agrislam.sinks.foxglove import write_foxglove_mcap
from agrislam.sinks.geojson import write_geojson
from agrislam.sinks.report import write_report
from agrislam.sinks.ros_map import write_map_mcap
from agrislam.sinks.sqlite import save_map
from agrislam.snapshot import MapSnapshot
from agrislam.sources.sync import synchronise
from agrislam.world import WorldModel


@dataclass(slots=True)
class Truth:
    """What the source knows of the real field; the world model never sees it."""

    objects: list[TruthObject] = field(default_factory=list)
    poses: list[TruthPose] = field(default_factory=list)
    min_plant_distance: float | None = None
    detection_ids: list[str | None] = field(default_factory=list)  # truth_id per detection
    detection_objects: list[np.ndarray] = field(default_factory=list)  # object per detection

    @property
    def present(self) -> bool:
        return bool(self.objects or self.poses or any(self.detection_ids))

    def associations(self, world: WorldModel) -> list[tuple[str | None, int]]:
        """(truth_id, final object id) of every detection (truth_id None for clutter)."""
        if not self.detection_objects:
            return []
        objects = world.resolve(np.concatenate(self.detection_objects))
        return list(zip(self.detection_ids, objects.tolist(), strict=True))


@dataclass(slots=True)
class RunResult:
    snapshot: MapSnapshot
    metrics: dict[str, Any] | None
    wall_seconds: float
    n_frames: int
    outputs: list[Path]
    issues: dict[str, int]


def run_survey(
    records: Iterable[Record],
    world: WorldModel,
    out_dir: Path | None = None,
    progress: Callable[[], None] | None = None,
) -> RunResult:
    """Feed every record to the world model, then score the map and write the outputs."""
    truth, issues, n_frames = Truth(), Counter[str](), 0
    synced = synchronise(records)
    start = time.perf_counter()
    for record in _split_labels(synced, world, issues):
        if isinstance(record, TruthObject):
            truth.objects.append(record)
        elif isinstance(record, TruthPose):
            truth.poses.append(record)
        else:
            if isinstance(record, Meta) and record.field is not None:
                truth.min_plant_distance = record.field.min_plant_distance
            report = world.process(record)
            if report is not None and isinstance(record, Detections):
                n_frames += 1
                truth.detection_ids.extend(d.truth_id for d in record.objects)
                truth.detection_objects.append(report.object_ids)
        if progress is not None:
            progress()
    world.finish()
    wall = time.perf_counter() - start
    for frame, reason in synced.unplaced:
        issues[f"frame of {frame.robot!r} not placed: {reason}"] += 1
    issues.update(world.issues)
    snapshot = world.snapshot()
    metrics = None
    if truth.present:
        metrics = evaluate(
            snapshot,
            truth.objects,
            truth.poses,
            associations=truth.associations(world),
            min_plant_distance=truth.min_plant_distance,
        )
        metrics["run"] = {"wall_seconds": wall, "frames": n_frames}
    outputs = write_outputs(snapshot, out_dir, metrics, truth) if out_dir is not None else []
    return RunResult(snapshot, metrics, wall, n_frames, outputs, dict(issues))


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


def write_outputs(
    snapshot: MapSnapshot, out_dir: Path, metrics: dict[str, Any] | None, truth: Truth
) -> list[Path]:
    """The files of DESIGN.md "Outputs of a run"."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [out_dir / "objects.csv", out_dir / "trajectory.csv", out_dir / "map.sqlite"]
    write_objects_csv(snapshot, written[0])
    write_trajectory_csv(snapshot, written[1])
    save_map(snapshot, written[2])
    if snapshot.anchor is not None:
        written.append(out_dir / "map.geojson")
        write_geojson(snapshot, written[-1])
    written.append(out_dir / "map.mcap")  # MarkerArray + Path, for RViz and Foxglove
    write_map_mcap(snapshot, written[-1], overwrite=True)
    if importlib.util.find_spec("foxglove") is not None:  # the optional `foxglove` extra
        written.append(out_dir / "map_foxglove.mcap")
        write_foxglove_mcap(snapshot, written[-1], overwrite=True)
    written.append(out_dir / "report.png")
    write_report(snapshot, written[-1], metrics=metrics, truth=truth_trajectories(truth.poses))
    if metrics is not None:
        written.append(out_dir / "metrics.json")
        write_metrics(metrics, written[-1])
    return written
