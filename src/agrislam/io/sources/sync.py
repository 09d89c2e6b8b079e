"""Robot poses at detection times: a stream adapter after which every Detections record
is preceded by an Odometry record of its robot at its time, as a `delta`. A frame between
two odometry records splits their motion along the SE(2) geodesic and their covariance in
proportion to time, so the pieces compose back to the original motion and covariance."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from agrislam.geometry.se2 import between, wrap_angle
from agrislam.records import Detections, Odometry, Record

BEFORE_FIRST = "before the robot's first odometry"
AFTER_LAST = "after the robot's last odometry"


def se2_log(d: np.ndarray) -> np.ndarray:
    """Twist (vx, vy, w) whose exponential is the increment d = (x, y, theta)."""
    th = float(d[2])
    a, b = _v_terms(th)  # V = [[a, -b], [b, a]]
    rho = np.array([a * d[0] + b * d[1], -b * d[0] + a * d[1]]) / (a * a + b * b)
    return np.array([rho[0], rho[1], th])


def se2_exp(xi: np.ndarray) -> np.ndarray:
    """Increment reached by driving the twist xi for unit time."""
    a, b = _v_terms(float(xi[2]))
    return np.array([a * xi[0] - b * xi[1], b * xi[0] + a * xi[1], wrap_angle(xi[2])])


def _v_terms(th: float) -> tuple[float, float]:
    """sin(th)/th and (1 - cos(th))/th, by their series near zero."""
    if abs(th) < 1e-6:
        return 1.0 - th * th / 6.0, th / 2.0
    return np.sin(th) / th, (1.0 - np.cos(th)) / th


def interpolate_increment(delta: np.ndarray, f: float) -> np.ndarray:
    """The part of the motion `delta` done after fraction f of its interval."""
    return se2_exp(f * se2_log(delta))


@dataclass
class _Robot:
    t: float | None = None  # time of its last odometry record
    pose: np.ndarray | None = None  # last odometry-frame pose, for `pose` records
    pending: list[Detections] = field(default_factory=list)  # frames after the last odometry


class PoseSync:
    """Iterate `records` with odometry at every detection time (see the module docstring).

    A robot's first `pose` record becomes a zero `delta` (it only marks where the robot's
    odometry frame and timeline start); a first `delta` record passes as it is. A frame
    earlier than a robot's first odometry, or later than its last, cannot be placed: it is
    listed in `unplaced` with the reason once iteration ends. `default_cov` fills in
    odometry without a covariance before splitting (else such pieces keep cov None). Records
    of different robots may interleave; a held-back frame is released when its robot's next
    odometry arrives."""

    def __init__(self, records: Iterable[Record], default_cov: np.ndarray | None = None) -> None:
        self.records = records
        self.default_cov = None if default_cov is None else np.asarray(default_cov, float)
        self.unplaced: list[tuple[Detections, str]] = []
        self.n_interpolated = 0

    def __iter__(self) -> Iterator[Record]:
        robots: dict[str, _Robot] = {}
        for rec in self.records:
            if isinstance(rec, Odometry):
                yield from self._odometry(robots.setdefault(rec.robot, _Robot()), rec)
            elif isinstance(rec, Detections):
                state = robots.setdefault(rec.robot, _Robot())
                if state.t is not None and rec.t == state.t:
                    yield rec  # its pose is the last odometry record's
                else:
                    state.pending.append(rec)
            else:
                yield rec
        for state in robots.values():
            self.unplaced += [
                (d, AFTER_LAST if state.t is not None else BEFORE_FIRST) for d in state.pending
            ]
            state.pending.clear()

    def _odometry(self, state: _Robot, rec: Odometry) -> Iterator[Record]:
        if state.t is None:
            yield self._first(rec)
            early = [d for d in state.pending if d.t < rec.t]
            self.unplaced += [(d, BEFORE_FIRST) for d in early]
            yield from (d for d in state.pending if d.t == rec.t)
            state.pending = [d for d in state.pending if d.t > rec.t]
        else:
            yield from self._split(state, rec)
        state.t = rec.t
        state.pose = rec.pose

    def _split(self, state: _Robot, rec: Odometry) -> Iterator[Record]:
        """The increment since the last odometry, cut at the times of the frames in between."""
        assert state.t is not None
        if rec.delta is not None:
            delta = rec.delta
        elif state.pose is not None:
            delta = between(state.pose, rec.pose)
        else:  # a pose record after delta records: no previous odometry-frame pose known
            raise ValueError(
                f"robot {rec.robot!r} at t = {rec.t}: a 'pose' odometry record follows 'delta' "
                "records; a robot must use one kind"
            )
        cov = rec.cov if rec.cov is not None else self.default_cov
        inside = [d for d in state.pending if d.t < rec.t]
        state.pending = [d for d in state.pending if d.t >= rec.t]
        span = rec.t - state.t
        done, f_done = np.zeros(3), 0.0
        for k, det in enumerate(inside):
            if k == 0 or det.t != inside[k - 1].t:
                f = (det.t - state.t) / span
                here = interpolate_increment(delta, f)
                yield self._piece(rec, det.t, between(done, here), cov, f - f_done)
                done, f_done = here, f
                self.n_interpolated += 1
            yield det
        yield self._piece(rec, rec.t, between(done, delta), cov, 1.0 - f_done)
        at_end = [d for d in state.pending if d.t == rec.t]
        state.pending = [d for d in state.pending if d.t > rec.t]
        yield from at_end

    def _first(self, rec: Odometry) -> Odometry:
        """A robot's first record: a `delta` one as it is (the motion since its start pose); a
        `pose` one marks the start of its odometry frame: zero motion."""
        if rec.delta is not None:
            return rec
        cov = rec.cov if rec.cov is not None else self.default_cov
        return Odometry(t=rec.t, robot=rec.robot, delta=np.zeros(3), cov=cov)

    @staticmethod
    def _piece(
        rec: Odometry, t: float, delta: np.ndarray, cov: np.ndarray | None, share: float
    ) -> Odometry:
        return Odometry(t=t, robot=rec.robot, delta=delta, cov=None if cov is None else cov * share)


def synchronise(records: Iterable[Record], default_cov: np.ndarray | None = None) -> PoseSync:
    """`PoseSync(records)`: odometry at every detection time."""
    return PoseSync(records, default_cov)
