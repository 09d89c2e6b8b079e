"""A robot's motion kept whole when a source rejects one of its odometry records: with
`delta` records, dropping one would shift every later pose of the robot by its motion.

A delta rejected for its time only still holds a good motion: it is composed into the
robot's next accepted delta, with its covariance. A delta whose motion cannot be read is
bridged by constant velocity: the next accepted delta is extended back over the lost
interval and its covariance widened by half the bridged motion, so the map's landmarks, not
the guess, decide where the robot was. (A rejected `pose` record costs nothing.)"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from agrislam.geometry.odometry import guessed_motion_covariance
from agrislam.geometry.se2 import compose_increments, wrap_angle
from agrislam.io.sources.sync import interpolate_increment
from agrislam.io.sources.validate import BadRecordError
from agrislam.records import Odometry


@dataclass
class _Robot:
    last_t: float | None = None  # time of its last accepted odometry record
    had_delta: bool = False
    carried: tuple[np.ndarray, np.ndarray] | None = None  # good motion of rejected records
    lost: list[float | None] = field(default_factory=list)  # times of unreadable ones


class OdometryGaps:
    """Per robot: one odometry form after the first delta, and its motion kept whole
    across rejected records (see the module docstring). `default_cov`: the covariance of
    a record without one (the run's `sensor.odom_cov_diag`)."""

    def __init__(self, default_cov: np.ndarray) -> None:
        self.default_cov = np.asarray(default_cov, dtype=float)
        self.robots: dict[str, _Robot] = {}

    def check(self, rec: Odometry) -> None:
        """BadRecordError for a `pose` record after `delta` records of its robot: it has no
        previous odometry-frame pose to take the motion from."""
        state = self.robots.get(rec.robot)
        if rec.pose is not None and state is not None and state.had_delta:
            raise BadRecordError(
                "bad_value",
                f"robot {rec.robot!r}: a 'pose' odometry record after 'delta' records (a "
                "robot keeps to one kind)",
            )

    def rejected(self, robot: str, t: float | None, rec: Odometry | None) -> None:
        """An odometry record of `robot` was rejected: `rec` if its motion was readable
        (a bad time), else None; `t` its time if readable."""
        state = self.robots.get(robot)
        if state is None or state.last_t is None or not state.had_delta:
            return  # not started, or pose records: nothing to keep
        if rec is not None and rec.delta is not None:
            cov = self._cov(rec)
            if state.carried is None:
                state.carried = (rec.delta, cov)
            else:
                state.carried = compose_increments(*state.carried, rec.delta, cov)
        elif rec is None:
            state.lost.append(t)

    def accepted(self, rec: Odometry) -> Odometry:
        """`rec`, with what rejected records of its robot before it held folded in."""
        state = self.robots.setdefault(rec.robot, _Robot())
        last_t, state.last_t = state.last_t, rec.t
        if rec.delta is None:
            return rec
        state.had_delta = True
        if state.lost and last_t is not None:
            rec = self._bridge(rec, last_t, state.lost)
        state.lost = []
        if state.carried is not None:
            delta, cov = compose_increments(*state.carried, rec.delta, self._cov(rec))
            rec = dataclasses.replace(rec, delta=delta, cov=cov)
            state.carried = None
        return rec

    def _bridge(self, rec: Odometry, last_t: float, lost: list[float | None]) -> Odometry:
        """`rec` extended back to `last_t` at its own velocity, its covariance widened."""
        assert rec.delta is not None
        known = [t for t in lost if t is not None and last_t < t < rec.t]
        span = rec.t - last_t
        # the record's delta covers (latest lost time, rec.t); without a readable time, the
        # lost records were as far apart as the others
        f = span / (rec.t - max(known)) if known else len(lost) + 1.0
        if not (math.isfinite(f) and f > 1.0):
            return rec
        whole = interpolate_increment(rec.delta, f)
        bridged = whole - rec.delta  # about the motion of the lost interval
        bridged[2] = wrap_angle(bridged[2])
        cov = self._cov(rec) * f + guessed_motion_covariance(bridged)
        return dataclasses.replace(rec, delta=whole, cov=cov)

    def _cov(self, rec: Odometry) -> np.ndarray:
        return self.default_cov if rec.cov is None else rec.cov
