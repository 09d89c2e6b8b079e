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

import numpy as np

from agrislam.geometry import se2

# the parts of an odometry covariance, each scaled by its own factor (a noise calibration's)
TRANSLATION, HEADING, CROSS = 0, 1, 2


def adjoint(pose: np.ndarray) -> np.ndarray:
    """Ad(P) of SE(2) for (x, y, theta) tangent vectors: P Exp(eta) P^-1 = Exp(Ad eta)."""
    ad = np.eye(3)
    ad[:2, :2] = se2.rotation(pose[2])
    ad[:2, 2] = pose[1], -pose[0]
    return ad


def since_seen(
    chain_pose: np.ndarray,
    chain_drift: np.ndarray,
    seen_drift: np.ndarray,
    known: np.ndarray,
    robot_xy: np.ndarray,
    map_heading: float,
) -> np.ndarray:
    """(m, k, 2, 2) map-frame covariance that a robot's drift since it last saw each of k
    objects gives its robot-frame detections robot_xy (m, 2): C_now - C_seen mapped onto
    each detection, zero where the robot has no chain to the object (`known` False).
    `chain_pose`/`chain_drift` are the robot's dead-reckoning pose and C now, `seen_drift`
    (k, 3, 3) C when it saw each object, `map_heading` its heading in the map frame now."""
    drift = np.where(known[:, None, None], chain_drift - seen_drift, 0.0)
    # the detections in the dead-reckoning frame, where the chain is expressed
    xy_dr = robot_xy @ se2.rotation(chain_pose[2]).T + chain_pose[:2]
    jac = se2.point_jacobian(xy_dr)  # (m, 2, 3): left perturbation at the points
    cov = np.einsum("mij,kjl,mnl->mkin", jac, drift, jac)
    to_map = se2.rotation(map_heading - chain_pose[2])
    return to_map @ cov @ to_map.T


def odometry_parts(cov: np.ndarray) -> np.ndarray:
    """(3, 3, 3) a motion increment's covariance (x, y, theta) split into what its
    translation noise, its heading noise and their correlation build; they sum to `cov`."""
    parts = np.zeros((3, 3, 3))
    parts[TRANSLATION, :2, :2] = cov[:2, :2]
    parts[HEADING, 2, 2] = cov[2, 2]
    parts[CROSS] = cov - parts[TRANSLATION] - parts[HEADING]
    return parts
