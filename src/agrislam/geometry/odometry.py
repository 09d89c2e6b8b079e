"""One robot's odometry chain as the world model keeps it (DESIGN step 2): the motion
since its last pose node, composed into one increment with its covariance; its
dead-reckoning pose and track; and the drift its chain has accumulated
(geometry/drift.py), which bounds how far it may have wandered since it saw an object.
Covariances are kept as the parts the configured translation and heading noise build
(estimation/noise_calibration.py), so that the noise scales estimated later apply to all
of it. A motion to be judged by the robot's next frames (frontend/doubt.py) is held with
the motion that would replace it: the chain keeps the dead reckoning of both versions
until a frame decides.
"""

from __future__ import annotations

import numpy as np

from agrislam.geometry import se2
from agrislam.geometry.drift import adjoint, odometry_parts
from agrislam.growing import GrowingRows

GUESS_SIGMA = 0.5  # sigma of a motion that is guessed, not measured, as a fraction of its size
MIN_GUESS_SIGMA = (0.01, 0.01, 0.01)  # m, m, rad: the least a guessed motion is uncertain by


def guessed_motion_covariance(motion: np.ndarray) -> np.ndarray:
    """(3, 3) the covariance of a motion increment that is guessed (from the robot's own
    motion), not measured: half its size in each direction, the same across and along,
    at least MIN_GUESS_SIGMA; the map's landmarks, not the guess, then place the robot."""
    motion = np.asarray(motion, dtype=float)
    sigma = np.maximum(GUESS_SIGMA * np.abs(motion), MIN_GUESS_SIGMA)
    sigma[:2] = max(sigma[0], sigma[1], GUESS_SIGMA * float(np.hypot(*motion[:2])))
    return np.diag(sigma**2)


class _Version:
    """The dead reckoning since a motion to be judged, had it (and any other held after
    it) been replaced: its pose, the poses its records would have had, and the
    covariance of the guesses that replaced them."""

    def __init__(self, pose: np.ndarray) -> None:
        self.pose, self.guessed = pose.copy(), np.zeros((3, 3))
        self.poses: list[np.ndarray] = []

    def move(self, delta: np.ndarray, instead: np.ndarray | None) -> None:
        if instead is not None:
            delta = instead
            self.guessed = self.guessed + guessed_motion_covariance(instead)
        self.pose = se2.compose(self.pose, delta)
        self.poses.append(self.pose)


class OdometryChain:
    """Odometry of one robot between pose nodes, and its dead reckoning."""

    def __init__(
        self, start_pose: np.ndarray | None = None, start_sigma: np.ndarray | None = None
    ) -> None:
        self.start_pose = start_pose  # map-frame prior from the survey's meta
        self.start_sigma = start_sigma
        self.started = False  # added to the back end
        self.pose = np.zeros(3)  # dead reckoning now
        # C: prefix sum of Ad(P) Q Ad(P)^T (drift.py), in the parts of Q (calibration.py)
        self.drift = np.zeros((3, 3, 3))
        self._pending: tuple[np.ndarray, np.ndarray] | None = None  # composed delta, parts
        self._node_pose = np.zeros(3)  # dead reckoning at the last pose node
        self._other: _Version | None = None  # with the motions to be judged replaced
        self._odom_pose: np.ndarray | None = None  # last odometry-frame pose, if given
        self._track_t = GrowingRows()
        self._track = GrowingRows((3,))

    def start(self, pose: np.ndarray, t: float) -> None:
        """The chain begins at map-frame `pose` at time t."""
        self.pose, self.started = np.asarray(pose, dtype=float).copy(), True
        self._node_pose = self.pose.copy()
        self._record(t)

    def increment(self, pose: np.ndarray | None, delta: np.ndarray | None) -> np.ndarray | None:
        """The motion since the previous record, from its `delta` or its odometry-frame
        `pose` (None for the first pose: it only marks where the odometry frame starts)."""
        if delta is not None:
            return np.asarray(delta, dtype=float)
        pose = np.asarray(pose, dtype=float)
        previous, self._odom_pose = self._odom_pose, pose
        return None if previous is None else se2.between(previous, pose)

    def move(
        self, t: float, delta: np.ndarray, cov: np.ndarray, instead: np.ndarray | None = None
    ) -> None:
        """Compose a motion increment of configured covariance `cov` into the pending one;
        dead reckoning follows. `instead`: the motion that replaces this one if the
        robot's frames doubt it (`settle`); until then both versions are kept."""
        if instead is not None and self._other is None:
            self._other = _Version(self.pose)
        if self._other is not None:
            self._other.move(delta, instead)
        parts = odometry_parts(cov)
        if self._pending is None:
            self._pending = (delta, parts)
        else:
            self._pending = se2.compose_increments(*self._pending, delta, parts)
        self.pose = se2.compose(self.pose, delta)
        self._record(t)

    @property
    def in_doubt(self) -> tuple[np.ndarray, np.ndarray] | None:
        """While motions await judgement: the motion since the last pose node as recorded
        and with them replaced; else None."""
        if self._other is None:
            return None
        return se2.between(self._node_pose, self.pose), se2.between(
            self._node_pose, self._other.pose
        )

    def settle(self, doubted: bool) -> None:
        """A frame has judged the motions held: kept as recorded, or (`doubted`) replaced,
        the pending increment, the dead reckoning and its track since with them; the
        replaced increment is as uncertain as its guesses besides."""
        other, self._other = self._other, None
        if not doubted or other is None:
            return
        delta = se2.between(self._node_pose, other.pose)
        parts = odometry_parts(other.guessed)
        if self._pending is not None:
            parts = parts + self._pending[1]
        self._pending, self.pose = (delta, parts), other.pose
        self._track.array[-len(other.poses) :] = other.poses

    def take_pending(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The increment since the last pose node and its covariance parts, or None if the
        robot has not moved; the chain's drift grows by it (drift.py: C += Ad(P) Q Ad(P)^T)."""
        pending, self._pending = self._pending, None
        self._node_pose = self.pose.copy()
        if pending is not None:
            ad = adjoint(self.pose)
            self.drift = self.drift + ad @ pending[1] @ ad.T
        return pending

    @property
    def time(self) -> float:
        """The time of the chain's latest record."""
        return float(self._track_t.array[-1])

    def velocity(self) -> np.ndarray:
        """(2,) forward speed (m/s) and turn rate (rad/s) over the last increment recorded;
        zero before there is one."""
        if len(self._track_t) < 2:
            return np.zeros(2)
        (t0, t1), (p0, p1) = self._track_t.array[-2:], self._track.array[-2:]
        if t1 <= t0:
            return np.zeros(2)
        motion = se2.between(p0, p1)
        return np.array([motion[0], motion[2]]) / (t1 - t0)

    def track(self) -> tuple[np.ndarray, np.ndarray]:
        """(m,) times and (m, 3) dead-reckoning poses so far."""
        return self._track_t.array.copy(), self._track.array.copy()

    def _record(self, t: float) -> None:
        self._track_t.append(t)
        self._track.append(self.pose)
