"""Odometry that can be doubted: a motion that changes its robot's motion far more than
any change it made so far (a jump of metres, a spin) is not taken on its own word. It is
held, with the robot's latest believed motion carried on in its place, until a frame of
the robot can judge it: the frame's detections are placed after both versions, and the
version they fit the map clearly better wins. A frame that puts no MIN_FIT detections on
the map after either cannot judge: a jump no robot makes (`IMPOSSIBLE` times its fastest
so far) is then doubted at once, another motion believed after MAX_WAIT such frames (a
robot's first turn is far beyond its turns so far too); until judged, the chain and the
graph follow the motion as recorded. Motions held one after another are judged together
(a glitch of a `pose` record is a jump there and one back). A doubted motion enters the
chain and the graph as the guess, with the covariance of a guess (geometry/odometry.py),
so the map's objects place the robot; each is counted in the run's issues.

So is a covariance: a record claiming a sigma `CONTRADICTED` times below the change of its
robot's motion from one record to the next (its jitter: noise twice, and what the robot
really did) is raised to the sigma that jitter would be if it were all noise; both per
square root of a second, as a random walk's (a record cut at a frame's time carries its
share of the covariance). An odometry of 1e-8 m on a robot whose every increment differs
from the last by millimetres would hold the chain rigid, and the plants seen again could
not bend it."""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from agrislam.estimation.noise_calibration import mahalanobis
from agrislam.geometry import se2
from agrislam.geometry.noise import raised
from agrislam.mapping.map_state import MapState

SUSPECT = 2.0  # a change of motion this many times the robot's largest so far is held
IMPOSSIBLE = 10.0  # a translation this many times its fastest is doubted unjudged
NOISE_SIGMAS = 3.0  # what a record's own noise may add to its motion, in its sigmas
MOVES = 10  # records that moved beyond their noise before a robot's motion can judge one
CHI2_2D_99 = 9.21  # a detection this far (squared Mahalanobis) from any object is off the map
DECISIVE = CHI2_2D_99  # the score (`MotionDoubt.fit`) by which one version must win
MAX_REACH = 3.0  # m: the farthest object looked for around a placed detection
MIN_FIT = 2  # detections on the map after the winning version, at least
MAX_WAIT = 10  # frames a motion is held for while none of them can judge it
JITTER = 64  # the latest changes of a robot's motion its jitter is the median of
JITTER_EVERY = 16  # records between two medians
CONTRADICTED = 100.0  # a record claiming a sigma this many times below the jitter is raised
# the median change between two increments' noise, in the sigma of each: a distance in 2D
# (Rayleigh of scale sqrt(2) sigma) and an angle (half-normal of sqrt(2) sigma)
JITTER_MEDIANS = (1.1774 * math.sqrt(2.0), 0.6745 * math.sqrt(2.0))
DOUBTED = "odometry motions doubted: far beyond the robot's motion so far (frontend/doubt.py)"
FLOORED = "odometry covariances far below the robot's jitter raised to it (frontend/doubt.py)"


Motion = tuple[float, float, float, float]  # a record's dx, dy, dtheta and its interval dt


@dataclass(frozen=True)
class Suspect:
    """A motion held in doubt: as recorded with its interval, the sigmas of its record's
    noise (translation, heading), the motion that replaces it if doubted, and whether it
    is a jump no robot makes."""

    motion: Motion
    noise: tuple[float, float]
    instead: np.ndarray
    impossible: bool


@dataclass
class MotionSoFar:
    """One robot's motion so far: its fastest translation and the largest change of its
    motion from one record to the next (translation, turn: what its acceleration and
    steering do), both over motions believed; its latest believed motion and the one of
    its latest record; how many of its records moved. Plain floats: every odometry
    record of a survey passes here."""

    speed: float = 0.0  # m/s
    change: tuple[float, float] = (0.0, 0.0)  # m, rad
    moves: int = 0
    latest: Motion | None = None  # believed
    previous: Motion | None = None  # the latest record's
    jitter: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=JITTER))
    floor: tuple[float, float] | None = None  # sigmas its jitter means, per sqrt(s)
    _shaken: int = 0  # changes since the latest median

    def shake(self, motion: Motion) -> None:
        """The change of `motion` from the latest record's, per sqrt(s), into the jitter
        (every JITTER_EVERY records its median renews the floor)."""
        if self.previous is None or motion[3] <= 0.0:
            return
        x, y, theta = _carried(self.previous, motion[3])
        turn = abs(math.remainder(motion[2] - theta, math.tau))
        root = math.sqrt(motion[3])
        self.jitter.append((math.hypot(motion[0] - x, motion[1] - y) / root, turn / root))
        self._shaken += 1
        if self._shaken >= JITTER_EVERY:
            median = np.median(np.array(self.jitter), axis=0) / JITTER_MEDIANS
            self.floor, self._shaken = (float(median[0]), float(median[1])), 0

    def predicted(self, dt: float) -> np.ndarray:
        """(3,) the robot's latest believed motion, carried on over dt."""
        return np.array(_carried(self.latest, dt))

    def surprise(self, motion: Motion, noise: tuple[float, float]) -> float:
        """How many times the largest change so far `motion` changes the robot's motion,
        beyond what its record's `noise` explains: its change from the latest believed
        motion and from the latest record's, whichever is smaller (the record after a held
        one changes back), in translation or turn; 0 before MOVES moves."""
        if self.moves < MOVES or self.latest is None:
            return 0.0
        t, h = _changed(motion, noise, self.latest)
        if self.previous is not None:
            t_previous, h_previous = _changed(motion, noise, self.previous)
            t, h = min(t, t_previous), min(h, h_previous)
        return max(_ratio(t, self.change[0]), _ratio(h, self.change[1]))

    def impossible(self, motion: Motion, noise: tuple[float, float]) -> bool:
        """Whether the motion's translation is IMPOSSIBLE times the fastest so far."""
        beyond = math.hypot(motion[0], motion[1]) - NOISE_SIGMAS * noise[0]
        span = max(motion[3], self.latest[3] if self.latest is not None else 0.0)
        return beyond > IMPOSSIBLE * self.speed * span

    def believe(self, motion: Motion, noise: tuple[float, float]) -> None:
        """A motion of the robot taken as true: its envelope grows to hold it."""
        if motion[3] <= 0.0:
            return
        if self.latest is not None:
            t, h = _changed(motion, noise, self.latest)
            self.change = (max(self.change[0], t), max(self.change[1], h))
        trans = math.hypot(motion[0], motion[1])
        self.moves += trans > NOISE_SIGMAS * noise[0]
        self.speed = max(self.speed, trans / motion[3])
        self.latest = motion


def _carried(motion: Motion | None, dt: float) -> tuple[float, float, float]:
    """A motion carried on over dt (itself for dt = 0; none: no motion)."""
    if motion is None or motion[3] <= 0.0:
        return 0.0, 0.0, 0.0
    f = dt / motion[3] if dt > 0.0 else 1.0
    return motion[0] * f, motion[1] * f, motion[2] * f


def _changed(motion: Motion, noise: tuple[float, float], reference: Motion) -> tuple[float, float]:
    """How much `motion` changes from `reference` carried on over its interval, in
    translation and turn, beyond NOISE_SIGMAS of its record's noise."""
    x, y, theta = _carried(reference, motion[3])
    t = math.hypot(motion[0] - x, motion[1] - y) - NOISE_SIGMAS * noise[0]
    h = abs(math.remainder(motion[2] - theta, math.tau)) - NOISE_SIGMAS * noise[1]
    return max(t, 0.0), max(h, 0.0)


def _sigmas(cov: np.ndarray) -> tuple[float, float]:
    """An odometry covariance's largest translation sigma and its heading sigma."""
    (a, b, _), (_, c, _), (_, _, heading) = np.asarray(cov, dtype=float).tolist()
    return math.sqrt(0.5 * (a + c) + math.hypot(0.5 * (a - c), b)), math.sqrt(heading)


def _ratio(beyond: float, largest: float) -> float:
    if beyond <= 0.0:
        return 0.0
    return beyond / largest if largest > 0.0 else math.inf


class MotionDoubt:
    """Each robot's motion so far, the check of each odometry motion against it, and the
    judgement of the motions held (module docstring)."""

    def __init__(self, map_state: MapState, issues: Counter[str]) -> None:
        self.map, self.issues = map_state, issues
        self.robots: dict[str, MotionSoFar] = {}
        self.held: dict[str, list[Suspect]] = {}
        self.born: dict[str, int] = {}  # per robot, the objects there were when it held one
        self.waited: Counter[str] = Counter()  # per robot, frames that could not judge

    def covariance(self, robot: str, cov: np.ndarray, dt: float) -> np.ndarray:
        """The covariance `cov` (3, 3) of an odometry record over dt, its translation or
        heading raised to the robot's jitter over dt if it claims a sigma CONTRADICTED
        times below it (counted)."""
        so_far = self.robots.get(robot)
        if so_far is None or so_far.floor is None or dt <= 0.0:
            return cov
        root = math.sqrt(dt)
        floor, claimed = (so_far.floor[0] * root, so_far.floor[1] * root), _sigmas(cov)
        low = [c * CONTRADICTED < f for c, f in zip(claimed, floor, strict=True)]
        if not any(low):
            return cov
        self.issues[FLOORED] += 1
        cov = np.array(cov, dtype=float)
        if low[0]:
            cov[:2, :2] = raised(cov[:2, :2], floor[0] ** 2)
        if low[1]:
            cov[2, 2] = max(cov[2, 2], floor[1] ** 2)
        return cov

    def check(self, robot: str, delta: np.ndarray, dt: float, cov: np.ndarray) -> Suspect | None:
        """None for a motion believed at once (of covariance `cov`, over dt); else the
        suspect, for `hold`."""
        so_far = self.robots.get(robot) or self.robots.setdefault(robot, MotionSoFar())
        dx, dy, dtheta = np.asarray(delta, dtype=float).tolist()
        motion = (dx, dy, dtheta, float(dt))
        noise = _sigmas(cov)
        surprise = so_far.surprise(motion, noise)
        if dt > 0.0:
            so_far.shake(motion)
            so_far.previous = motion
        if surprise <= SUSPECT:
            so_far.believe(motion, noise)
            return None
        impossible = so_far.impossible(motion, noise)
        return Suspect(motion, noise, so_far.predicted(dt), impossible)

    def hold(self, robot: str, suspect: Suspect) -> None:
        """A suspect of `robot` awaits judgement."""
        if robot not in self.held:
            self.born[robot] = len(self.map.objects)
        self.held.setdefault(robot, []).append(suspect)

    def fit(
        self,
        robot: str,
        pose: np.ndarray,
        versions: tuple[np.ndarray, np.ndarray],
        xy: np.ndarray,
        cov: np.ndarray,
    ) -> tuple[float, float] | None:
        """How badly a frame of `robot` fits the map after each version of the motion
        (`score`), None if it cannot tell (MIN_FIT of its detections on the map after
        neither): `pose` the robot's last pose node in the map, `versions` the motion
        since as recorded and with the held motions replaced, `xy` and `cov` (m, 2),
        (m, 2, 2) the frame's detections in the robot frame. Objects started since the
        robot held a motion do not count: placed after the recorded version, they would
        vouch for it."""
        born = self.born.get(robot, len(self.map.objects))
        fits = [self.score(se2.compose(pose, v), xy, cov, born) for v in versions]
        if max(on_map for _, on_map in fits) < MIN_FIT:
            return None
        return fits[0][0], fits[1][0]

    def judge(self, robot: str, fit: tuple[float, float] | None, looked: bool) -> bool | None:
        """Whether the motions `robot` holds are doubted, after a frame's `fit` (None: the
        frame could not tell; `looked`: it had detections): the version that wins by
        DECISIVE; without a clear winner, an impossible motion is doubted at once, the
        others believed, but only after MAX_WAIT frames with detections that could not
        tell (None until then). The doubted are counted, the believed widen the robot's
        motion so far."""
        held = self.held.get(robot, [])
        impossible = any(s.impossible for s in held)
        if fit is not None and abs(fit[0] - fit[1]) > DECISIVE:
            doubted = fit[1] < fit[0]
        elif fit is None and not impossible:
            self.waited[robot] += looked
            if self.waited[robot] < MAX_WAIT:
                return None
            doubted = False
        else:
            doubted = impossible
        self.held.pop(robot, None)
        self.born.pop(robot, None)
        self.waited.pop(robot, None)
        if doubted:
            self.issues[DOUBTED] += len(held)
        else:
            so_far = self.robots[robot]
            for s in held:
                so_far.believe(s.motion, s.noise)
        return doubted

    def score(
        self, pose: np.ndarray, xy: np.ndarray, cov: np.ndarray, born: int
    ) -> tuple[float, int]:
        """How badly the detections (robot frame), placed from `pose`, fit the objects
        older than id `born`: the sum of each one's squared Mahalanobis distance to its
        nearest, CHI2_2D_99 at most (one off the map, an outlier, costs that much and no
        more); and how many are on the map (nearer than that)."""
        map_xy, map_cov = se2.to_map_frame(pose, xy, cov)
        spread = float(np.sqrt(np.linalg.eigvalsh(map_cov)[:, -1].max()))
        index = self.map.index
        ids = index.query(map_xy, min(math.sqrt(CHI2_2D_99) * spread, MAX_REACH))
        ids = ids[ids < born]
        nearest = np.full(len(xy), CHI2_2D_99)
        if len(ids):
            d = index.position(ids)[None, :, :] - map_xy[:, None, :]
            nearest = np.minimum(mahalanobis(d, map_cov[:, None]).min(axis=1), CHI2_2D_99)
        return float(nearest.sum()), int((nearest < CHI2_2D_99).sum())
