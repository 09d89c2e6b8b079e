"""How far a robot may have drifted since it last saw an object: the covariance of its
dead-reckoning chain between then and now, mapped onto a point.

The back end's marginals are absolute: after a long survey, the robot's pose and a
plant it saw a second ago are each uncertain by metres, yet known well relative to each
other, and K_n + R_m + pose uncertainty then gates far too wide. The chain between two
poses bounds that relative uncertainty from above and is cheap: with the motion noise
moved to the left of the chain, T_k = Exp(Ad(P_k) eta_k) P_k, the drift of pose j
relative to pose i has covariance C_j - C_i, C the prefix sum of Ad(P) Q Ad(P)^T along
the chain (P the pose after each increment, Q its covariance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agrislam.geometry import se2


def adjoint(pose: np.ndarray) -> np.ndarray:
    """Ad(P) of SE(2) for (x, y, theta) tangent vectors: P Exp(eta) P^-1 = Exp(Ad eta)."""
    ad = np.eye(3)
    ad[:2, :2] = se2.rotation(pose[2])
    ad[:2, 2] = pose[1], -pose[0]
    return ad


@dataclass(slots=True)
class _Chain:
    pose: np.ndarray = field(default_factory=lambda: np.zeros(3))  # dead reckoning now
    drift: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # C now


class OdometryDrift:
    """Each robot's accumulated chain covariance, and where it stood when each object was
    last seen; objects last seen by another robot have no chain to the robot now."""

    def __init__(self) -> None:
        self._chains: dict[str, _Chain] = {}
        self._seen_by: dict[int, str] = {}
        self._seen_drift: dict[int, np.ndarray] = {}

    def start(self, robot: str, pose: np.ndarray) -> None:
        self._chains[robot] = _Chain(np.asarray(pose, dtype=float).copy())

    def advance(self, robot: str, pose: np.ndarray, cov: np.ndarray) -> None:
        """The robot moved to dead-reckoning `pose` by an increment of covariance `cov`."""
        chain = self._chains.setdefault(robot, _Chain())
        chain.pose = np.asarray(pose, dtype=float)
        ad = adjoint(chain.pose)
        chain.drift = chain.drift + ad @ cov @ ad.T

    def seen(self, robot: str, object_ids: np.ndarray) -> None:
        drift = self._chains[robot].drift
        for obj in np.atleast_1d(object_ids).tolist():
            self._seen_by[obj] = robot
            self._seen_drift[obj] = drift

    def merge(self, keep: int, drop: int) -> None:
        """`keep` now stands for `drop` too: it was last seen when `drop` was, if later."""
        robot = self._seen_by.pop(drop, None)
        drift = self._seen_drift.pop(drop, None)
        if robot is None or drift is None:
            return
        mine = self._seen_drift.get(keep)
        if self._seen_by.get(keep) != robot or mine is None or np.trace(drift) > np.trace(mine):
            self._seen_by[keep], self._seen_drift[keep] = robot, drift

    def forget(self, object_ids: np.ndarray) -> None:
        for obj in np.atleast_1d(object_ids).tolist():
            self._seen_by.pop(obj, None)
            self._seen_drift.pop(obj, None)

    def since_seen(
        self, robot: str, object_ids: np.ndarray, robot_xy: np.ndarray, map_heading: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(m, k, 2, 2) map-frame covariance that the robot's drift since it last saw each
        object gives the robot-frame detections robot_xy (m, 2), and (k,) whether that
        chain exists. `map_heading` is the robot's heading in the map frame now."""
        chain = self._chains[robot]
        known = np.array([self._seen_by.get(o) == robot for o in object_ids.tolist()], bool)
        drift = np.stack(
            [
                chain.drift - self._seen_drift[o] if k else np.zeros((3, 3))
                for o, k in zip(object_ids.tolist(), known.tolist(), strict=True)
            ]
        ).reshape(-1, 3, 3)
        # the detections in the dead-reckoning frame, where the chain is expressed
        xy_dr = robot_xy @ se2.rotation(chain.pose[2]).T + chain.pose[:2]
        jac = se2.point_jacobian(xy_dr)  # (m, 2, 3): left perturbation at the points
        cov = np.einsum("mij,kjl,mnl->mkin", jac, drift, jac)
        to_map = se2.rotation(map_heading - chain.pose[2])
        return to_map @ cov @ to_map.T, known
