"""A survey that continues a saved map, as the pipeline runs it: the records held back until
the robots are re-localised in the saved map (never merged into a wrong place), then mapped
on the saved plants; at the end, what changed.

Every robot registers its own first frames: the records are released when the first robot
has its fix and every other robot heard of by then has its own or has given up (it then
starts with a weak prior, placed by the plants it shares). `SeasonRun(prior, config)` is
handed to `pipeline.run_survey`: `gate` wraps the pose-synced records, `finish` classifies
the saved plants after the world's last step."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator

import numpy as np

from agrislam.config import AgrislamConfig
from agrislam.geometry import se2
from agrislam.records import Detections, Meta, Odometry, Record
from agrislam.season.changes import Changes, ViewArea, find_changes
from agrislam.season.first_frames import Check, FirstFrames, compatibility
from agrislam.season.prior_map import PriorMap
from agrislam.season.relocalise import Fix, Relocaliser
from agrislam.snapshot import STATUS_ACTIVE, STATUS_GONE
from agrislam.world import WorldModel


class SeasonRun:
    """Re-localisation and change finding of one survey against a saved map."""

    def __init__(self, prior: PriorMap, config: AgrislamConfig) -> None:
        self.prior, self.config, self.cfg = prior, config, config.advanced.season
        map_var = np.trace(prior.cov, axis1=1, axis2=2) / 2.0 if len(prior) else None
        self.relocaliser = Relocaliser(prior.xy, self.cfg, map_var=map_var)
        self.fix: Fix | None = None  # the first robot's latest try
        self.tries: list[tuple[float, str]] = []  # (s driven, outcome) of its every try
        self.localised_after: float | None = None  # s of driving until its fix
        self.robots: dict[str, FirstFrames] = {}  # every robot's first frames and fix
        self._first: str | None = None  # the first robot to detect anything
        self.merged = False
        self.start_check: str | None = None
        self.changes: Changes | None = None
        self._robot_xy: list[np.ndarray] = []
        self.history = None  # the saved map's history (sinks.history.History), if it has one

    # ----------------------------------------------------------------- the gate
    def gate(self, records: Iterable[Record], world: WorldModel) -> Iterator[Record]:
        """Hold the records back until the robots' fixes (or the survey ends, or time runs
        out without the first robot's fix: then the survey maps on its own, not merged);
        then the meta with the fixed start poses and everything held."""
        meta: Meta | None = None
        held: list[Record] = []
        frames = self.robots
        it = iter(records)
        for rec in it:
            if isinstance(rec, Meta):
                meta = rec
                continue
            held.append(rec)
            if isinstance(rec, Detections):
                self._keep_robot_frame(rec)
            if not isinstance(rec, (Odometry, Detections)):
                continue
            robot = frames.setdefault(rec.robot, FirstFrames())
            if isinstance(rec, Odometry) or robot.fix is None:
                robot.add(rec, self.prior.schema)
            if isinstance(rec, Detections) and robot.fix is None:
                self._try(rec.robot, robot, rec.t, meta)
            done = self._released(rec.t, meta, world)
            if done is not None:
                yield done
                yield from held
                yield from it
                return
        first = self.robots.get(self._first) if self._first is not None else None
        if first is not None and first.fix is not None:  # the log ended while others tried
            yield self._start(meta, world)
        else:
            self.tries.append((np.nan, self.fix.reason if self.fix else "no frames"))
            yield meta if meta is not None else Meta()
        yield from held

    def _released(self, t: float, meta: Meta | None, world: WorldModel) -> Meta | None:
        """The meta to release the records with: the fixed one when the first robot and
        every robot heard of have their fixes (or gave up), the given one when the first
        robot gave up; None while waiting."""
        first = self.robots.get(self._first) if self._first is not None else None
        if first is None:
            return None
        if first.fix is None:
            if first.t0 is not None and t - first.t0 > self.cfg.give_up_after_s:
                return meta if meta is not None else Meta()
            return None
        waiting = [
            r
            for r in self.robots.values()
            if r.fix is None and t - r.t0 <= self.cfg.give_up_after_s
        ]
        return None if waiting else self._start(meta, world)

    def _try(self, name: str, robot: FirstFrames, t: float, meta: Meta | None) -> None:
        """One registration of the robot's latest first frames (every attempt_every_s)."""
        if not robot.due(t, self.cfg.attempt_every_s):
            return
        fix = robot.locate(
            self.relocaliser, self.cfg, t - self.cfg.window_s, check=self._check(robot, t, meta)
        )
        if fix.localised:
            robot.localised(fix, t)
        if name == self._first:
            self.fix = fix
            self.tries.append((robot.last_try, fix.reason))
            self.localised_after = robot.after

    def _check(self, robot: FirstFrames, t: float, meta: Meta | None) -> Check | None:
        """Which saved plants a first-frames plant may be, by its attributes (None: any)."""
        if not (robot.dists and len(self.prior.ids)):
            return None
        start = meta.survey_start if meta is not None and meta.survey_start else 0.0
        # a map without history has no time: its beliefs are as of this survey's start, as
        # the world takes them
        saved = self.prior.t_abs - start if np.isfinite(self.prior.t_abs) else 0.0
        beliefs = self.prior.belief_table(self.config.advanced.semantics, saved)
        compatible, ids = compatibility(beliefs, t), self.prior.ids

        def check(local: dict[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
            return compatible(local, ids[rows])

        return check

    def _start(self, meta: Meta | None, world: WorldModel) -> Meta:
        """The meta with each localised robot's start pose from its fix, the prior given to
        the world; a start pose the meta already gives is only checked against the fix
        (one off it refuses the merge)."""
        meta = meta if meta is not None else Meta()
        robots, checks = dict(meta.robots), []
        for name, robot in self.robots.items():
            if robot.fix is None:
                continue
            start, given = robot.fix.transform, meta.robots.get(name)
            if given is None:
                robots[name] = robot.start()
                continue
            d = np.linalg.norm(given.pose[:2] - start[:2])
            turn = abs(se2.wrap_angle(given.pose[2] - start[2]))
            checks.append(
                f"{name}: start pose off the fix by {d:.2f} m, {np.degrees(turn):.1f} deg"
            )
            if d > self.cfg.start_tolerance[0] or turn > self.cfg.start_tolerance[1]:
                self.start_check = "; ".join(checks) + ": refused, not merged"
                return meta
        self.start_check = "; ".join(checks) or None
        return self._merge(dataclasses.replace(meta, robots=robots), world)

    def _merge(self, meta: Meta, world: WorldModel) -> Meta:
        world.use_prior(self.prior)
        self.merged = True
        return meta

    def _keep_robot_frame(self, frame: Detections) -> None:
        if self._first is None:
            self._first = frame.robot
        if len(self._robot_xy) < 20_000:
            self._robot_xy.extend(d.position() for d in frame.objects)

    # ------------------------------------------------------------------- the end
    def finish(self, world: WorldModel) -> Changes | None:
        """After the world's last step: the saved plants kept, gone and unseen; new ones."""
        if not self.merged:
            return None
        prior, backend = self.prior, world.backend
        ids = prior.ids[world.objects.status[prior.ids] == STATUS_ACTIVE]  # not merged away
        xy = backend.object_positions(ids)
        poses, pose_row, object_id = backend.sightings()
        area = ViewArea.learned(np.array(self._robot_xy).reshape(-1, 2), self.cfg.view_margin)
        new = world.active_ids()
        new = new[new > prior.ids.max()]
        frames = world.objects.n_frames
        fresh = (new, backend.object_positions(new), frames[new])
        self.changes = find_changes(
            ids, xy, frames[ids], fresh, poses, (pose_row, object_id), area, self.cfg
        )
        if len(self.changes.gone):  # not deleted: out of the map, in its history as gone
            world.objects.retire(self.changes.gone, STATUS_GONE)
        return self.changes

    def summary(self) -> dict[str, object]:
        """The run's season section of metrics.json."""
        return {
            "survey": self.prior.survey,
            "localised": self.merged,
            "localised_after_s": self.localised_after,
            "fix": None
            if self.fix is None or not self.fix.localised
            else self.fix.transform.tolist(),
            "tries": [{"driven_s": d, "outcome": r} for d, r in self.tries],
            "robots": {
                name: {
                    "localised_after_s": r.after,
                    "fix": None if r.fix is None else r.fix.transform.tolist(),
                }
                for name, r in self.robots.items()
            },
            "start_check": self.start_check,
            "changes": None if self.changes is None else self.changes.as_dict(),
        }
