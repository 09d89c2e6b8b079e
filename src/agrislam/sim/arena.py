"""The arena scenario as a source: several robots driving random paths among point landmarks
(some in tight clusters) in a small indoor arena, with fast drifting wheel odometry and a
range-bearing camera, shaped like the UTIAS multi-robot dataset (MRCLAM).

`ArenaSimulator(ArenaConfig()).records()` yields a survey log's records, as `Simulator` does
for a field: one meta, the landmarks' truth, then every robot's odometry, frames and true
poses, interleaved in time order."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from agrislam.config import DiscreteAttribute, FieldSchema
from agrislam.records import (
    Detection,
    Detections,
    DiscreteMeasurement,
    Meta,
    Odometry,
    Record,
    RobotStart,
    TruthObject,
    TruthPose,
)
from agrislam.sim.arena_config import ArenaConfig
from agrislam.sim.effects import CameraBias, blind_spells
from agrislam.sim.landmarks import Landmarks, clustered_landmarks
from agrislam.sim.odometry import OdometryTrack, drifting_odometry
from agrislam.sim.path import frame_times
from agrislam.sim.random_drive import TimedPath, random_drive
from agrislam.sim.range_bearing import (
    Observations,
    observe,
    read_by_chance,
    read_ids,
    unless_blind,
)
from agrislam.sim.simulator import time_order

# independent random streams, so changing one part of the config leaves the others alone
_LANDMARKS, _DRIVE, _ODOMETRY, _CAMERA, _ATTRIBUTE, _PHASE, _EFFECTS = 21, 22, 23, 24, 25, 26, 27
# record kinds at one time stamp, in the order they are written
_TRUTH, _ODOM, _FRAME = 0, 1, 2
SENSOR = "camera"


@dataclass(frozen=True, slots=True)
class ArenaRobot:
    """One robot's drive: truth and odometry at the odometry times, what its frames saw."""

    name: str
    drive: TimedPath
    t_odom: np.ndarray  # (m,) odometry (and true pose) times, s
    poses: np.ndarray  # (m, 3) true poses there
    odometry: OdometryTrack
    t_frames: np.ndarray  # (f,) camera frame times
    poses_frames: np.ndarray  # (f, 3) true poses there
    seen: Observations
    read: np.ndarray | None  # (n,) landmark index each detection's barcode read says
    camera: CameraBias  # its range scale and bearing offset
    blind: np.ndarray  # (k, 2) start and end of the camera's blind spells, s


class ArenaSimulator:
    """`ArenaSimulator(ArenaConfig()).records()`: the 15-minute, 5-robot arena run."""

    def __init__(self, cfg: ArenaConfig | None = None) -> None:
        self.cfg = cfg or ArenaConfig()
        self.landmarks: Landmarks = clustered_landmarks(self.cfg.arena, self._rng(_LANDMARKS))
        self.schema = self._schema()

    def _rng(self, *key: int) -> np.random.Generator:
        return np.random.default_rng([self.cfg.seed, *key])

    def _schema(self) -> FieldSchema | None:
        attr = self.cfg.attribute
        if not attr.enabled:
            return None
        values = DiscreteAttribute(values=list(self.landmarks.ids))
        return FieldSchema(attributes={attr.name: values})

    def robot_names(self) -> list[str]:
        return [f"r{k + 1}" for k in range(self.cfg.driving.n_robots)]

    @cached_property
    def robots(self) -> list[ArenaRobot]:
        return [self.robot(k) for k in range(self.cfg.driving.n_robots)]

    def robot(self, k: int) -> ArenaRobot:
        """Robot k's whole drive, every part from its own random stream."""
        cfg = self.cfg
        drive = random_drive(
            cfg.driving,
            cfg.arena.size,
            self.landmarks.xy,
            cfg.driving.duration_s,
            self._rng(_DRIVE, k),
        )
        t_odom = frame_times(cfg.driving.duration_s, cfg.odometry.rate_hz)
        poses = drive.sample(t_odom)
        # odometry stamped ahead: its record at t carries the motion made by t + the offset
        offset = cfg.odometry.effects.clock_offset_s
        moved = drive.sample(t_odom + offset) if offset else poses
        track = drifting_odometry(moved, t_odom, cfg.odometry, self._rng(_ODOMETRY, k))
        # the camera runs on its own clock: a random phase against the odometry
        phase = self._rng(_PHASE, k).uniform(0.0, 1.0 / cfg.camera.frame_rate_hz)
        t_frames = frame_times(t_odom[-1] - phase, cfg.camera.frame_rate_hz, phase)
        poses_frames = drive.sample(t_frames)
        effects = self._rng(_EFFECTS, k)
        camera = CameraBias.draw(cfg.camera.effects, effects)
        blind = blind_spells(0.0, float(t_odom[-1]), cfg.camera.effects, effects)
        seen = observe(
            poses_frames, self.landmarks.xy, cfg.camera, self._rng(_CAMERA, k), camera, effects
        )
        seen = read_by_chance(unless_blind(seen, t_frames, blind), cfg.camera.p_detect, effects)
        read = None
        if cfg.attribute.enabled:
            rng = self._rng(_ATTRIBUTE, k)
            read = read_ids(seen.label, len(self.landmarks), cfg.attribute, rng)
        return ArenaRobot(
            self.robot_names()[k],
            drive,
            t_odom,
            poses,
            track,
            t_frames,
            poses_frames,
            seen,
            read,
            camera,
            blind,
        )

    def meta(self) -> Meta:
        """No field prior (this is no crop field), a schema only with the attribute, the
        start poses of every robot or of the first only."""
        d = self.cfg.driving
        sigma = np.asarray(d.start_sigma, float)
        known = self.robots if d.start_poses == "all" else self.robots[:1]
        robots = {r.name: RobotStart(pose=r.poses[0].copy(), sigma=sigma) for r in known}
        return Meta(version=1, schema=self.schema, robots=robots)

    def truth_objects(self) -> list[TruthObject]:
        name = self.cfg.attribute.name
        return [
            TruthObject(id=i, xy=xy, attributes={name: i} if self.schema is not None else {})
            for i, xy in zip(self.landmarks.ids, self.landmarks.xy, strict=True)
        ]

    def records(self) -> Iterator[Record]:
        """One meta, the landmarks' truth, then the robots' records in time order (at one
        time: truth, odometry, frame)."""
        yield self.meta()
        yield from self.truth_objects()
        robots = self.robots
        frames = [self._written_frames(r) for r in robots]
        ev = time_order(
            [(r.t_odom, r.t_odom, r.t_frames[f]) for r, f in zip(robots, frames, strict=True)]
        )
        standstill = self._standstill_cov()
        for t, k, kind, i in ev:
            robot, i = robots[int(k)], int(i)
            if kind == _TRUTH:
                yield TruthPose(t=float(t), robot=robot.name, pose=robot.poses[i])
            elif kind == _ODOM:
                delta, cov = robot.odometry.record(i, standstill)
                cov = cov if self.cfg.odometry.report_covariance else None
                yield Odometry(t=float(t), robot=robot.name, delta=delta, cov=cov)
            else:
                f = int(frames[int(k)][i])
                yield Detections(
                    t=float(t), robot=robot.name, objects=self._detections(robot, f), sensor=SENSOR
                )

    def _written_frames(self, robot: ArenaRobot) -> np.ndarray:
        """Indices of the frames written: all of them, or those that saw something."""
        if self.cfg.camera.empty_frames:
            return np.arange(len(robot.t_frames))
        return np.unique(robot.seen.frame)

    def _standstill_cov(self) -> np.ndarray:
        """The reported covariance of one odometry period standing still."""
        o = self.cfg.odometry
        sigma = np.asarray(o.sigma_per_sqrt_s) * np.asarray(o.report_sigma_factor)
        return np.diag(sigma**2 / o.rate_hz)

    def _detections(self, robot: ArenaRobot, f: int) -> tuple[Detection, ...]:
        cam, seen = self.cfg.camera, robot.seen
        ids = self.landmarks.ids
        sigma_range, sigma_bearing = cam.reported_sigmas or (cam.sigma_range, cam.sigma_bearing)
        out = []
        for j in seen.in_frame(f):
            attributes = {}
            if robot.read is not None:
                value = ids[int(robot.read[j])]
                attributes = {
                    self.cfg.attribute.name: DiscreteMeasurement(value, self.cfg.attribute.p)
                }
            out.append(
                Detection(
                    range=float(seen.range[j]),
                    bearing=float(seen.bearing[j]),
                    sigma_range=sigma_range,
                    sigma_bearing=sigma_bearing,
                    attributes=attributes,
                    truth_id=ids[int(seen.label[j])],
                )
            )
        return tuple(out)
