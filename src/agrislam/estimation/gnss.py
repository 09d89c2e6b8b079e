"""GNSS fixes as factors on the robot pose: each fix projected into the anchor's map frame,
tied to the robot's next pose node through its lever arm, weighted with a floor per fix
type, gated on its innovation (widened when several fixes agree the pose drifted), and
held by a robust kernel as wide as that innovation."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from agrislam.backend.gnss_factor import KERNELS, antenna_jacobian, antenna_position
from agrislam.config import GnssConfig
from agrislam.estimation.noise_calibration import mahalanobis
from agrislam.geometry import se2
from agrislam.geometry.geodesy import MapFrame
from agrislam.records import FIX_TYPES, Anchor, GnssFix

ANCHORING = ("rtk_fixed", "rtk_float", "dgps")


def weighted_covariance(cov_map: np.ndarray, fix: str, cfg: GnssConfig) -> np.ndarray:
    """The 2x2 covariance a fix is used with: its own, raised to at least the fix type's
    sigma floor in every direction."""
    floor2 = cfg.fix_sigma[fix] ** 2
    smallest = float(np.linalg.eigvalsh(cov_map)[0])
    return cov_map + max(0.0, floor2 - smallest) * np.eye(2)


def psd_part(cov: np.ndarray) -> np.ndarray:
    """A symmetric matrix with its negative eigenvalues set to zero."""
    w, v = np.linalg.eigh(cov)
    return (v * np.maximum(w, 0.0)) @ v.T


def kernel_width(fix_cov: np.ndarray, innovation_cov: np.ndarray, k: float) -> float:
    """The robust kernel's width in the fix's own whitened units for a kernel `k` standard
    deviations of the innovation wide: k sqrt(largest eigenvalue of C^-1 S), at least k."""
    ratio = np.linalg.eigvals(np.linalg.solve(fix_cov, innovation_cov)).real.max()
    return k * math.sqrt(max(1.0, float(ratio)))


@dataclass(slots=True)
class Innovation:
    """A fix against the predicted antenna: r = predicted - z, the fix's covariance C and
    the predicted pose's share J P J^T of S = C + J P J^T (P the pose's marginal)."""

    residual: np.ndarray  # (2,)
    fix_cov: np.ndarray  # (2, 2)
    pose_cov: np.ndarray  # (2, 2)

    def agrees(self, before: Innovation, chi2: float) -> bool:
        """Whether this and the previous fix are offset from the predicted antenna alike:
        their offsets differ by less than the gate allows for the two fixes' noise and the
        pose uncertainty gained in between (the odometry's, as the marginal grew)."""
        grown = psd_part(self.pose_cov - before.pose_cov)
        diff = self.residual - before.residual
        return mahalanobis(diff, self.fix_cov + before.fix_cov + grown) <= chi2


@dataclass(slots=True)
class PendingFix:
    z: np.ndarray  # (2,) antenna in the map frame
    cov: np.ndarray  # (2, 2) weighted covariance there
    lever: np.ndarray  # (2,) antenna in the robot frame
    dead_reckoning: np.ndarray  # (3,) the robot's dead-reckoned pose when the fix came


@dataclass(slots=True)
class GateState:
    """A robot's gate: the fixes rejected in a row, the last of them and how many before it
    agreed with each other, and the drift the gate is widened by (module docstring); how
    far it drove since its pose was last held (by its start or a fix taken); its fixes
    taken and refused, and whether its GNSS was rejected as a whole."""

    beyond: int = 0
    last: Innovation | None = None
    agreeing: int = 0
    drift: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    driven: float = 0.0
    at: np.ndarray | None = None  # the dead-reckoned pose at the last pose node
    taken: int = 0
    refused: int = 0
    rejected: bool = False


class GnssFixes:
    """The world's GNSS stage: fixes wait for their robot's next pose node, then become
    factors; `counts` says how many were used and why the others were not."""

    def __init__(self, cfg: GnssConfig, issues: Counter[str] | None = None) -> None:
        self.cfg = cfg
        self.frame: MapFrame | None = None
        self.pending: dict[str, list[PendingFix]] = {}
        self.counts: Counter[str] = Counter()
        self.gates: dict[str, GateState] = {}
        self.issues = Counter() if issues is None else issues  # a GNSS rejected as a whole

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
        each fix moves its lever arm; a fix beyond the gate is rejected, unless it and the
        ones before it show that the pose drifted, as far as it can have drifted. A robot
        whose fixes keep being refused has its GNSS rejected as a whole, and said so."""
        gate = self.gates.setdefault(robot, GateState())
        if gate.at is not None:
            gate.driven += float(np.linalg.norm(dead_reckoning[:2] - gate.at[:2]))
        gate.at = np.asarray(dead_reckoning, dtype=float).copy()
        fixes = self.pending.pop(robot, [])
        if gate.rejected:
            self.counts["rejected_disagreeing"] += len(fixes)
            return
        pose = backend.current_pose(robot) if fixes else None
        kernel = KERNELS.index(self.cfg.robust_kernel)
        for fix in fixes:
            since = se2.between(dead_reckoning, fix.dead_reckoning)  # fix pose in node frame
            lever = antenna_position(since, fix.lever)
            new = self._innovation(pose, pose_cov, lever, fix)
            innovation_cov = self._admit(gate, new, gated=pose_cov is not None)
            if isinstance(innovation_cov, str):
                self.counts[innovation_cov] += 1
                self._refused(robot, gate)
                continue
            width = kernel_width(fix.cov, innovation_cov, self.cfg.robust_k)
            backend.add_gnss(robot, np.array([*fix.z, *lever, width, kernel]), fix.cov)
            self.counts["used"] += 1
            gate.taken, gate.driven = gate.taken + 1, 0.0

    def _refused(self, robot: str, gate: GateState) -> None:
        """One more fix refused: the robot's GNSS rejected as a whole once fixes are refused
        `reject_whole_after` times, four times as often as taken."""
        gate.refused += 1
        if gate.refused >= self.cfg.reject_whole_after and gate.refused > 4 * gate.taken:
            gate.rejected = True
            self.issues[
                f"GNSS fixes of robot {robot!r} disagree with its odometry and the plants "
                f"({gate.refused} refused, {gate.taken} taken): the rest rejected, the map "
                "kept to the odometry and the plants"
            ] += 1

    @staticmethod
    def _innovation(
        pose: np.ndarray, pose_cov: np.ndarray | None, lever: np.ndarray, fix: PendingFix
    ) -> Innovation:
        jac = antenna_jacobian(pose, lever)
        share = np.zeros((2, 2)) if pose_cov is None else jac @ pose_cov @ jac.T
        return Innovation(antenna_position(pose, lever) - fix.z, fix.cov, share)

    def _admit(self, gate: GateState, new: Innovation, gated: bool) -> np.ndarray | str:
        """The innovation covariance a fix is taken with, or why the gate rejects it:
        beyond the chi2 gate (widened by any drift found) unless it is the
        `gate_consistent`-th in a row to agree with the one before, or the
        `gate_reacquire`-th in a row beyond it, and within the drift the robot's driving
        allows (`drift_floor`, `drift_per_m`)."""
        chi2 = self.cfg.gate_chi2
        plain = new.fix_cov + new.pose_cov
        if chi2 <= 0.0 or not gated:  # no gate, or no pose covariance to gate with
            return plain
        if mahalanobis(new.residual, plain) <= chi2:
            gate.beyond, gate.last, gate.agreeing, gate.drift = 0, None, 0, np.zeros((2, 2))
            return plain
        if mahalanobis(new.residual, plain + gate.drift) <= chi2:
            gate.beyond, gate.last, gate.agreeing = 0, None, 0
            return plain + gate.drift
        agrees = gate.last is not None and new.agrees(gate.last, chi2)
        gate.agreeing = gate.agreeing + 1 if agrees else 0
        gate.beyond += 1
        gate.last = new
        drifted = 0 < self.cfg.gate_consistent <= gate.agreeing + 1
        if not drifted and gate.beyond <= self.cfg.gate_reacquire:
            return "rejected_gate"
        reach = self.cfg.drift_floor + self.cfg.drift_per_m * gate.driven
        if float(np.linalg.norm(new.residual)) > reach:
            return "rejected_beyond_drift"  # farther than the pose can have drifted
        # the pose drifted: take the fix, and the next ones as far off as it was
        gate.drift = np.outer(new.residual, new.residual)
        gate.beyond, gate.last, gate.agreeing = 0, None, 0
        return plain + gate.drift

    def summary(self) -> dict[str, int]:
        """Fixes received, used and rejected (by reason), for metrics.json."""
        waiting = sum(len(v) for v in self.pending.values())
        out = {k: int(v) for k, v in sorted(self.counts.items())}
        if waiting:
            out["rejected_no_pose"] = waiting
        return out


__all__ = ["FIX_TYPES", "GnssFixes"]
