"""GNSS fixes as factors on the robot pose (issue 13): the antenna at lever arm `l` in the
robot frame sits at t + R(theta) l in the map frame, which the fix measures.

A fix is projected into the map frame of the survey's anchor (geometry/geodesy.py), tied
to the robot's next pose node with the odometry between the fix and that node folded into
the lever arm, weighted by its covariance with a floor per fix type, gated on its
Mahalanobis distance from the predicted antenna, and wrapped in a robust kernel. RTK
float, single fixes and multipath jumps thus cannot pull a map that RTK fixed fixes hold.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import gtsam
import numpy as np

from agrislam.config import GnssConfig
from agrislam.geometry import se2
from agrislam.geometry.geodesy import MapFrame
from agrislam.geometry.noise import gaussian
from agrislam.records import FIX_TYPES, Anchor, GnssFix

KERNELS = ("none", "huber", "cauchy")  # value[5] of a GNSS factor record
# fix types good enough to anchor a survey without a meta anchor
ANCHORING = ("rtk_fixed", "rtk_float", "dgps")


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


def weighted_covariance(cov_map: np.ndarray, fix: str, cfg: GnssConfig) -> np.ndarray:
    """The 2x2 covariance a fix is used with: its own, raised to at least the fix type's
    sigma floor in every direction."""
    floor2 = cfg.fix_sigma[fix] ** 2
    smallest = float(np.linalg.eigvalsh(cov_map)[0])
    return cov_map + max(0.0, floor2 - smallest) * np.eye(2)


def mahalanobis2(residual: np.ndarray, cov: np.ndarray) -> float:
    return float(residual @ np.linalg.solve(cov, residual))


@dataclass(slots=True)
class PendingFix:
    z: np.ndarray  # (2,) antenna in the map frame
    cov: np.ndarray  # (2, 2) weighted covariance there
    lever: np.ndarray  # (2,) antenna in the robot frame
    dead_reckoning: np.ndarray  # (3,) the robot's dead-reckoned pose when the fix came


class GnssFixes:
    """The world's GNSS stage: fixes wait for their robot's next pose node, then become
    factors; `counts` says how many were used and why the others were not."""

    def __init__(self, cfg: GnssConfig) -> None:
        self.cfg = cfg
        self.frame: MapFrame | None = None
        self.pending: dict[str, list[PendingFix]] = {}
        self.counts: Counter[str] = Counter()
        self.gated: Counter[str] = Counter()  # robot -> fixes rejected in a row by the gate

    def receive(
        self, fix: GnssFix, anchor: Anchor | None, dead_reckoning: np.ndarray
    ) -> Anchor | None:
        """Keep a fix for the robot's next pose; returns the anchor (the first good fix's
        when the survey has none)."""
        self.counts["received"] += 1
        if not self.cfg.enabled or fix.fix not in self.cfg.fix_sigma:
            self.counts["rejected_fix_type"] += 1
            return anchor
        if anchor is None:
            if fix.fix not in ANCHORING:
                self.counts["rejected_no_anchor"] += 1
                return None
            anchor = Anchor(fix.lat, fix.lon, fix.alt, 0.0)
        if self.frame is None or self.frame.anchor != anchor:
            self.frame = MapFrame(anchor)
        z = self.frame.to_map(fix.lat, fix.lon, fix.alt)[0, :2]
        cov_en = np.diag([1.0, 1.0]) * self.cfg.fix_sigma[fix.fix] ** 2
        if fix.cov is not None:
            cov_en = np.asarray(fix.cov, dtype=float)[:2, :2]
        cov = weighted_covariance(self.frame.enu_to_map(cov_en), fix.fix, self.cfg)
        lever = np.asarray(self.cfg.antenna if fix.antenna is None else fix.antenna, float)[:2]
        self.pending.setdefault(fix.robot, []).append(
            PendingFix(z, cov, lever, np.asarray(dead_reckoning, dtype=float).copy())
        )
        return anchor

    def attach(
        self, backend, robot: str, dead_reckoning: np.ndarray, pose_cov: np.ndarray | None
    ) -> None:
        """The robot's waiting fixes as factors on its latest pose node: the odometry since
        each fix moves its lever arm; a fix beyond the gate is rejected."""
        fixes = self.pending.pop(robot, [])
        if not fixes:
            return
        pose = backend.current_pose(robot)
        kernel = KERNELS.index(self.cfg.robust_kernel)
        for fix in fixes:
            since = se2.between(dead_reckoning, fix.dead_reckoning)  # fix pose in node frame
            lever = antenna_position(since, fix.lever)
            if self._gated(pose, pose_cov, lever, fix) and (
                self.gated[robot] < self.cfg.gate_reacquire
            ):  # after that many in a row the map, not the fixes, is taken to be wrong
                self.gated[robot] += 1
                self.counts["rejected_gate"] += 1
                continue
            self.gated[robot] = 0
            value = np.array([*fix.z, *lever, self.cfg.robust_k, kernel])
            backend.add_gnss(robot, value, fix.cov)
            self.counts["used"] += 1

    def _gated(
        self, pose: np.ndarray, pose_cov: np.ndarray | None, lever: np.ndarray, fix: PendingFix
    ) -> bool:
        """Whether the fix lies beyond the chi2 gate around the predicted antenna."""
        if self.cfg.gate_chi2 <= 0.0 or pose_cov is None:
            return False
        jac = antenna_jacobian(pose, lever)
        residual = antenna_position(pose, lever) - fix.z
        return mahalanobis2(residual, fix.cov + jac @ pose_cov @ jac.T) > self.cfg.gate_chi2

    def summary(self) -> dict[str, int]:
        """Fixes received, used and rejected (by reason), for metrics.json."""
        waiting = sum(len(v) for v in self.pending.values())
        out = {k: int(v) for k, v in sorted(self.counts.items())}
        if waiting:
            out["rejected_no_pose"] = waiting
        return out


__all__ = ["FIX_TYPES", "GnssFixes", "antenna_jacobian", "antenna_position", "gnss_factor"]
