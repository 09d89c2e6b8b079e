"""The factor of a GNSS fix (sec. 2.6 with a lever arm): the antenna at lever arm `l` in
the robot frame sits at t + R(theta) l in the map frame, which the fix measures."""

from __future__ import annotations

import gtsam
import numpy as np

from agrislam.geometry import se2
from agrislam.geometry.noise import gaussian

KERNELS = ("none", "huber", "cauchy")  # value[5] of a GNSS factor record
# fix types good enough to anchor a survey without a meta anchor


def antenna_position(pose: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """(2,) map-frame antenna of a pose (x, y, theta) with lever arm (lx, ly): t + R l."""
    return se2.compose(pose, np.array([lever[0], lever[1], 0.0]))[:2]


def antenna_jacobian(pose: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """(2, 3) d(antenna)/d(xi) for the pose perturbed as P Exp(xi) (GTSAM's Pose2 tangent):
    [R, R (-ly, lx)^T]."""
    rot = se2.rotation(float(pose[2]))
    return np.column_stack([rot, rot @ np.array([-lever[1], lever[0]])])


def gnss_factor(key: int, value: np.ndarray, cov: np.ndarray) -> gtsam.NonlinearFactor:
    """The factor of a GNSS record: value = (zx, zy, lx, ly, kernel width, kernel index)."""
    z, lever = np.array(value[:2], dtype=float), np.array(value[2:4], dtype=float)
    noise = gaussian(np.asarray(cov, dtype=float))
    kernel = KERNELS[int(value[5])]
    if kernel != "none":
        estimator = {
            "huber": gtsam.noiseModel.mEstimator.Huber,
            "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
        }
        noise = gtsam.noiseModel.Robust.Create(estimator[kernel].Create(float(value[4])), noise)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list | None) -> np.ndarray:
        p = values.atPose2(this.keys()[0])
        pose = np.array([p.x(), p.y(), p.theta()])
        if jacobians is not None:
            jacobians[0] = antenna_jacobian(pose, lever)
        return antenna_position(pose, lever) - z

    return gtsam.CustomFactor(noise, [key], error)
