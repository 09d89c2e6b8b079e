"""SE(2) arithmetic on (x, y, theta) arrays: composing poses and motion increments,
with first-order covariance propagation. Vectorised where it runs per detection."""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(theta: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) into [-pi, pi)."""
    return (np.asarray(theta) + np.pi) % (2 * np.pi) - np.pi


def rotation(theta: float | np.ndarray) -> np.ndarray:
    """(2, 2) the rotation by `theta`; (k, 2, 2) for k angles."""
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty((*np.shape(theta), 2, 2))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    return out


def turned(xy: np.ndarray, theta: np.ndarray | float) -> np.ndarray:
    """(p, 2) points turned about the origin by `theta` (one angle, or one per point)."""
    return np.einsum("...ij,...j->...i", rotation(theta), xy)


def pair_motions(new: np.ndarray, old: np.ndarray, tolerance: np.ndarray | float) -> np.ndarray:
    """(h, 3) rigid motions (dx, dy, dtheta; the turn about the origin first) that put a
    pair of `new` points on an ordered pair of `old` points as far apart, within
    `tolerance` (one, or one per pair of `new` in `np.triu_indices` order)."""
    i, j = np.triu_indices(len(new), 1)
    a, b = np.nonzero(~np.eye(len(old), dtype=bool))
    seen, there = new[j] - new[i], old[b] - old[a]
    gap = np.abs(np.linalg.norm(seen, axis=1)[:, None] - np.linalg.norm(there, axis=1)[None])
    p, q = np.nonzero(gap <= np.reshape(tolerance, (-1, 1)))
    seen, there = seen[p], there[q]
    turn = wrap_angle(np.arctan2(there[:, 1], there[:, 0]) - np.arctan2(seen[:, 1], seen[:, 0]))
    shift = 0.5 * (old[a[q]] + old[b[q]]) - turned(0.5 * (new[i[p]] + new[j[p]]), turn)
    return np.column_stack([shift, turn])


def compose_points(poses: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(n, 2) the points `xy` (n, 2), given in the frame of one pose (3,) or each in the
    frame of its own of `poses` (n, 3), expressed in the poses' parent frame."""
    return turned(xy, poses[..., 2]) + poses[..., :2]


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (+) b: the pose b, given in the frame of pose a, expressed in a's parent frame."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array(
        [a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2])]
    )


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 (+) b: the motion from pose a to pose b, in the frame of a."""
    c, s = np.cos(a[2]), np.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[2] - a[2])])


def compose_increments(
    d1: np.ndarray, cov1: np.ndarray, d2: np.ndarray, cov2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Two consecutive motion increments as one, with its covariance (first order):
    cov = J1 cov1 J1^T + J2 cov2 J2^T, J the Jacobians of d1 (+) d2."""
    c, s = np.cos(d1[2]), np.sin(d1[2])
    j1 = np.array(
        [[1.0, 0.0, -s * d2[0] - c * d2[1]], [0.0, 1.0, c * d2[0] - s * d2[1]], [0.0, 0.0, 1.0]]
    )
    j2 = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return compose(d1, d2), j1 @ cov1 @ j1.T + j2 @ cov2 @ j2.T


def to_map_frame(
    pose: np.ndarray, xy: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Robot-frame points (m, 2) with covariances (m, 2, 2) into the map frame."""
    r = rotation(pose[2])
    return xy @ r.T + pose[:2], r @ cov @ r.T


def to_robot_frame(pose: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Map-frame points (m, 2) into the frame of the robot at `pose`."""
    return (xy - pose[:2]) @ rotation(pose[2])


def point_jacobian(xy: np.ndarray) -> np.ndarray:
    """(m, 2, 3) how points xy (m, 2) of a frame move when the frame is perturbed by
    xi = (dx, dy, dtheta), xi expressed in the frame the points are given in:
    d(Exp(xi) (+) p) / d xi at xi = 0 = [I, J p] = [[1, 0, -p_y], [0, 1, p_x]].

    The other point Jacobians follow from it, for a pose T = (R, t) and p in its frame:
    - left perturbation Exp(xi) T, at map points m = T (+) p: point_jacobian(m);
    - right perturbation T Exp(xi) (GTSAM's Pose2 tangent): R point_jacobian(p);
    - (dx, dy, dtheta) added to T's (x, y, theta): point_jacobian(R p) (d R / d theta = J R).
    """
    jac = np.zeros((len(xy), 2, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0
    jac[:, 0, 2], jac[:, 1, 2] = -xy[:, 1], xy[:, 0]
    return jac


def pose_uncertainty_at(pose: np.ndarray, pose_cov: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(m, 2, 2) map-frame covariance that a pose's uncertainty gives robot-frame points
    xy (m, 2), with `pose_cov` (3, 3) GTSAM's Pose2 marginal (the tangent of T Exp(xi),
    in the robot's own frame): J cov J^T with J = R point_jacobian(p). Each point may have
    its own pose: `pose` (m, 3) and `pose_cov` (m, 3, 3)."""
    jac = rotation(pose[..., 2]) @ point_jacobian(xy)
    return jac @ pose_cov @ jac.transpose(0, 2, 1)


def quaternion_from_yaw(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by `yaw` about z, as geometry_msgs and Foxglove want it."""
    return (0.0, 0.0, float(np.sin(0.5 * yaw)), float(np.cos(0.5 * yaw)))


def yaw_from_quaternion(q: tuple[float, ...] | np.ndarray) -> float:
    """Heading (rotation about z) of a quaternion (x, y, z, w)."""
    x, y, z, w = (float(v) for v in q)
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def wrap_row_angle(angle: float) -> float:
    """Rows at a and a + pi are the same lines: angle into [-pi/2, pi/2)."""
    return (angle + math.pi / 2) % math.pi - math.pi / 2
