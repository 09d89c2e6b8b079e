"""The field simulator as a source: the same records a recorded survey log yields (Meta,
Odometry, Detections, TruthPose, TruthObject), so the pipeline cannot tell them apart."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from agrislam.config import SECONDS_PER_DAY
from agrislam.geometry.geodesy import MapFrame
from agrislam.records import (
    Anchor,
    Detections,
    FieldPrior,
    Meta,
    Odometry,
    Record,
    RobotStart,
    TruthPose,
)
from agrislam.sim.config import SimConfig
from agrislam.sim.detector import Detector
from agrislam.sim.effects import CameraBias, blind_spells, blinded
from agrislam.sim.field import Field, make_field
from agrislam.sim.gnss import every_nth, robot_fixes, survey_anchor, with_fixes
from agrislam.sim.odometry import OdometryTrack, integrate, noisy_odometry
from agrislam.sim.path import SurveyPath, frame_times, survey_path

# record kinds at one time stamp, in the order they are written
_TRUTH, _ODOM, _FRAME = 0, 1, 2
# independent random streams, so changing one part of the config leaves the others alone
_FIELD, _ODOMETRY, _DETECTOR, _GNSS, _EFFECTS = 11, 12, 13, 14, 15


@dataclass(frozen=True, slots=True)
class RobotSurvey:
    """One robot's drive on one survey day: truth at the odometry and frame times."""

    name: str
    path: SurveyPath
    speed: float
    t0: float  # start of the day's survey, s
    t_odom: np.ndarray  # (m,) odometry record times
    poses_odom: np.ndarray  # (m, 3) true poses there
    odometry: OdometryTrack
    t_frames: np.ndarray  # (f,) camera frame times
    poses_frames: np.ndarray  # (f, 3) true poses there

    def true_pose(self, t: float) -> np.ndarray:
        return self.path.sample(np.array([t - self.t0]), self.speed)[0]


def time_order(times: list[tuple[np.ndarray, ...]]) -> np.ndarray:
    """(time, robot, kind, index) of every record, sorted by time, then robot, then kind:
    `times[k][kind]` are robot k's record times of that kind (kinds in writing order)."""
    ev = np.vstack(
        [
            np.column_stack([t, np.full(len(t), k), np.full(len(t), kind), np.arange(len(t))])
            for k, robot in enumerate(times)
            for kind, t in enumerate(robot)
        ]
    )
    return ev[np.lexsort((ev[:, 2], ev[:, 1], ev[:, 0]))]


class Simulator:
    """`Simulator(SimConfig()).records()` is the paper's default 400-plant survey."""

    def __init__(self, cfg: SimConfig | None = None) -> None:
        self.cfg = cfg or SimConfig()
        self.schema = self.cfg.field_schema()
        self.field = make_field(self.cfg, self._rng(_FIELD))
        self.paths: list[SurveyPath] = [
            survey_path(self.field, self.cfg, k) for k in range(self.cfg.path.n_robots)
        ]
        self.days = list(self.cfg.growth.survey_days)

    def _rng(self, *key: int) -> np.random.Generator:
        return np.random.default_rng([self.cfg.seed, *key])

    def robot_names(self, day: int | None = None) -> list[str]:
        """r1, r2, ...; in a stream of several survey days each day's robots are new ones
        (r1_d0, r1_d1, ...), each with its own start pose."""
        base = [f"r{k + 1}" for k in range(self.cfg.path.n_robots)]
        return base if day is None else [f"{b}_d{day}" for b in base]

    def field_on(self, day: int) -> Field:
        """The truth on survey day `day` (index into survey_days): grown since the first."""
        return self.field.grown(self.days[day] - self.days[0])

    def survey(self, day: int, robot: int, name: str | None = None) -> RobotSurvey:
        cfg = self.cfg
        path = self.paths[robot]
        t0 = self.days[day] * SECONDS_PER_DAY
        duration = path.duration(cfg.path.speed)
        t_frames = frame_times(duration, cfg.path.frame_rate_hz)
        t_odom = t_frames
        if cfg.path.odom_rate_hz is not None:
            t_odom = frame_times(duration, cfg.path.odom_rate_hz)
            if t_odom[-1] < t_frames[-1]:  # odometry must cover the last frame
                t_odom = np.append(t_odom, t_frames[-1])
        poses_odom = path.sample(t_odom, cfg.path.speed)
        # odometry stamped ahead: its record at t carries the motion made by t + the offset
        offset = cfg.odometry.effects.clock_offset_s
        moved = path.sample(t_odom + offset, cfg.path.speed) if offset else poses_odom
        track = noisy_odometry(moved, t_odom, cfg.odometry, self._rng(_ODOMETRY, day, robot))
        return RobotSurvey(
            name=name or self.robot_names()[robot],
            path=path,
            speed=cfg.path.speed,
            t0=t0,
            t_odom=t0 + t_odom,
            poses_odom=poses_odom,
            odometry=track,
            t_frames=t0 + t_frames,
            poses_frames=path.sample(t_frames, cfg.path.speed),
        )

    def meta(self, names: list[str], days: list[int]) -> Meta:
        cfg = self.cfg
        sigma = np.asarray(cfg.path.start_sigma, float)
        robots = {
            name: RobotStart(pose=self.paths[k].at_distance(0.0)[0], sigma=sigma)
            for name, k in zip(
                names, [k for _ in days for k in range(cfg.path.n_robots)], strict=True
            )
        }
        anchor = None if cfg.anchor is None else Anchor(**cfg.anchor.model_dump())
        prior = FieldPrior(
            row_spacing=cfg.field.row_spacing,
            min_plant_distance=cfg.field.plant_spacing[0],
            row_angle_deg=cfg.field.row_angle_deg if cfg.announce_row_angle else None,
        )
        return Meta(version=1, schema=self.schema, robots=robots, anchor=anchor, field=prior)

    def records(self) -> Iterator[Record]:
        """Every survey day in one stream: one meta, then per day the truth of that day and
        the robots' records in time order."""
        many = len(self.days) > 1
        names = {d: self.robot_names(d if many else None) for d in range(len(self.days))}
        yield self.meta([n for d in names for n in names[d]], list(range(len(self.days))))
        for d in range(len(self.days)):
            yield from self._georeferenced(d, names[d], self._day(d, names[d]))

    def day_records(self, day: int) -> Iterator[Record]:
        """One survey day as a log of its own (its own meta; robots named r1, r2, ...)."""
        names = self.robot_names()
        yield self.meta(names, [day])
        yield from self._georeferenced(day, names, self._day(day, names))

    def _day(self, day: int, names: list[str]) -> Iterator[Record]:
        field = self.field_on(day)
        yield from field.truth_objects()
        detector = Detector(field, self.cfg.detector)
        surveys = [self.survey(day, k, name) for k, name in enumerate(names)]
        rngs = [self._rng(_DETECTOR, day, k) for k in range(len(surveys))]
        cameras, blind = self._cameras(day, surveys)
        ev = time_order(
            [(np.union1d(sv.t_odom, sv.t_frames), sv.t_odom, sv.t_frames) for sv in surveys]
        )
        odom_pose = [integrate(np.zeros(3), sv.odometry.delta) for sv in surveys]
        for t, k, kind, i in ev:
            sv, k, i = surveys[int(k)], int(k), int(i)
            if kind == _TRUTH:
                yield TruthPose(t=float(t), robot=sv.name, pose=sv.true_pose(float(t)))
            elif kind == _ODOM:
                yield self._odometry(sv, i, odom_pose[k][i])
            else:
                pose = sv.poses_frames[i]
                dets = () if blind[k][i] else detector.frame(pose, rngs[k], cameras[k])
                yield Detections(t=float(t), robot=sv.name, objects=dets, sensor="front")

    def _cameras(
        self, day: int, surveys: list[RobotSurvey]
    ) -> tuple[list[CameraBias], list[np.ndarray]]:
        """Each robot's camera (range scale, bearing offset) and which of its frames fall in
        a blind spell, drawn from a stream of their own."""
        fx = self.cfg.detector.effects
        cameras, blind = [], []
        for k, sv in enumerate(surveys):
            rng = self._rng(_EFFECTS, day, k)
            cameras.append(CameraBias.draw(fx, rng))
            spells = blind_spells(float(sv.t_frames[0]), float(sv.t_frames[-1]), fx, rng)
            blind.append(blinded(sv.t_frames, spells))
        return cameras, blind

    def _georeferenced(self, day: int, names: list[str], records: Iterator[Record]):
        """The day's records with the GNSS receiver's fixes among them, if it has one."""
        gnss = self.cfg.gnss
        if gnss is None:
            yield from records
            return
        anchor = self.cfg.anchor
        frame = MapFrame(survey_anchor(None if anchor is None else Anchor(**anchor.model_dump())))
        fixes = []
        for k, name in enumerate(names):
            sv, rng = self.survey(day, k, name), self._rng(_GNSS, day, k)
            at = every_nth(sv.t_odom, gnss.rate_hz)
            fixes += robot_fixes(name, sv.t_odom[at], sv.poses_odom[at], frame, gnss, rng)
        yield from with_fixes(records, fixes, names)

    def _odometry(self, sv: RobotSurvey, i: int, pose: np.ndarray) -> Odometry:
        """The first record of a robot marks where its timeline starts: zero motion, with the
        standing-still uncertainty."""
        floor = self.cfg.odometry.report_scale * np.asarray(self.cfg.odometry.sigma_floor)
        delta, cov = sv.odometry.record(i, np.diag(floor**2))
        if self.cfg.odometry.kind == "pose":
            return Odometry(t=float(sv.t_odom[i]), robot=sv.name, pose=pose, cov=cov)
        return Odometry(t=float(sv.t_odom[i]), robot=sv.name, delta=delta, cov=cov)
