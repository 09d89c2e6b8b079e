"""The association stage (sec. 2.4): candidates gated through the spatial index, the
association matrix over the frame's detections and them, the GNN; then the safeguards
beyond the paper (a returning robot keeps to objects of its own until landmarks agree where
it is, a lost robot rejoins the map, a gross range error goes to its landmark) and the
detections left unassigned start new objects."""

from __future__ import annotations

from collections import Counter

import numpy as np

from agrislam.association.gnn import (
    accepted_nis,
    assign,
    association_matrix,
    innovation_covariance,
    max_association_distance,
    rivals_on_one_metric,
)
from agrislam.association.range_outliers import RANGE_ERRORS, RangeOutliers
from agrislam.association.rejoin import Bounds, Rejoiner
from agrislam.association.returning import AGREEING, PLACE_SPACINGS, Returns
from agrislam.backend import GraphBackend
from agrislam.config import AssociationConfig
from agrislam.estimation.estimators import Estimators
from agrislam.frontend.frontend import FrontEnd
from agrislam.geometry.drift import since_seen
from agrislam.geometry.odometry import OdometryChain
from agrislam.geometry.placed import FrameMatch, PlacedDetections
from agrislam.mapping.map_state import MapState
from agrislam.records import Detection


class Associator:
    """A frame's detections to objects, new ones started for the rest."""

    def __init__(
        self,
        config: AssociationConfig,
        map_state: MapState,
        backend: GraphBackend,
        frontend: FrontEnd,
        estimators: Estimators,
        safeguards: tuple[Rejoiner, RangeOutliers, Returns],
        tentative: bool,
        issues: Counter[str],
    ) -> None:
        self.config, self.map, self.backend = config, map_state, backend
        self.frontend, self.estimators = frontend, estimators
        self.spacing = estimators.spacing
        self.rejoiner, self.outliers, self.returns = safeguards
        self.tentative = tentative  # new objects wait for confirmation (maintenance/existence.py)
        self.issues = issues

    def associate(
        self, robot: str, detections: list[Detection], placed: PlacedDetections, t: float
    ) -> FrameMatch:
        """Where each detection of the robot's frame goes; the range errors of mapped
        landmarks are reported as theirs and not mapped."""
        chain, robot_index = self.frontend.robots[robot], self.frontend.robot_index(robot)
        object_ids, nis, rejoined = self._gnn(robot, robot_index, chain, placed, t)
        pose, objects = self.backend.current_pose(robot), self.map.objects
        index = self.map.index
        on_ray = self.outliers.of_new_objects(
            pose, placed, object_ids, index, self.backend, objects
        )
        mapped = (on_ray < 0) | (not self.outliers.trusted)
        if not mapped.all():  # gross range errors: reported as their objects, not mapped
            self.issues[RANGE_ERRORS] += int((~mapped).sum())
            detections = [d for d, m in zip(detections, mapped, strict=True) if m]
            placed, object_ids, nis = placed.subset(mapped), object_ids[mapped], nis[mapped]
        unassigned = np.flatnonzero(object_ids < 0)
        new_ids = self.map.add(placed.xy[unassigned], t, self.tentative, self.backend)
        object_ids[unassigned] = new_ids
        self.returns.started(robot_index, new_ids)
        self.outliers.born(object_ids[on_ray[mapped] >= 0], t, objects)
        ids, reach = (object_ids, new_ids, on_ray, mapped), self.reach(placed)
        return FrameMatch(
            robot, robot_index, chain, t, pose, detections, placed, *ids, reach, nis, rejoined
        )

    def reach(self, placed: PlacedDetections) -> float:
        """The farthest an object may be from a detection and still be associated (none
        before the first detections set d_inter)."""
        cfg = self.config
        if self.spacing.d_inter is None:
            return 0.0
        measured = (len(m) for m in placed.measurements)
        n_measured = max(measured, default=0) if cfg.use_semantics else 0
        sigma = cfg.gate_sigma_max * np.sqrt(cfg.gate_chi2)  # the Mahalanobis term's reach
        return max_association_distance(self.spacing.d_inter, sigma, cfg.w_sem, n_measured)

    def _gnn(
        self,
        robot: str,
        robot_index: int,
        chain: OdometryChain,
        placed: PlacedDetections,
        t: float,
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """GNN over the association matrix of gated candidates (sec. 2.4), then the lost
        robot's rejoin: each detection's object (-1 = new), the NIS of those the GNN put on
        objects (NaN for the others) and whether the frame rejoined the map. A returning
        robot's candidates are its own new objects (association/returning.py)."""
        cfg, d_inter, backend = self.config, self.spacing.d_inter, self.backend
        if len(placed) == 0:
            return np.empty(0, dtype=int), np.empty(0), False
        heading, scale = backend.current_pose(robot)[2], self.estimators.noise.scale
        positions = backend.object_positions
        self.returns.check(robot_index, chain, scale, placed, heading, positions, t)
        candidates = self.map.index.query(placed.xy, self.reach(placed))
        candidates = self.returns.eligible(robot_index, candidates, self.map.objects)
        if len(candidates) == 0:
            ids, nis = np.full(len(placed), -1), np.full(len(placed), np.nan)
            return self._rejoin(robot, robot_index, chain, placed, ids, nis, t)
        object_cov = backend.object_covariances(candidates)  # may solve: then positions
        object_xy = backend.object_positions(candidates)
        innovation = own = None
        if cfg.innovation_gate:
            # what the robot's drift since it last saw each candidate adds (geometry/drift.py)
            then = self.map.objects.last_seen(candidates, robot_index)
            now, before = scale.odometry(chain.drift), scale.odometry(then.drift)
            drift = since_seen(chain.pose, now, before, then.known, placed.robot_xy, heading)
            own = innovation_covariance(placed, object_cov, drift, then.known)
            innovation = rivals_on_one_metric(own, placed.xy, object_xy, d_inter)
        beliefs = self.map.beliefs
        matrix = association_matrix(
            placed, candidates, object_xy, object_cov, beliefs, cfg, d_inter, t, innovation
        )
        chosen = assign(matrix)
        ids = np.where(chosen >= 0, candidates[np.maximum(chosen, 0)], -1)
        nis = accepted_nis(placed, chosen, object_xy, object_cov, own)
        return self._rejoin(robot, robot_index, chain, placed, ids, nis, t)

    def _rejoin(
        self,
        robot: str,
        robot_index: int,
        chain: OdometryChain,
        placed: PlacedDetections,
        ids: np.ndarray,
        nis: np.ndarray,
        t: float,
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """The GNN's choice `ids` put back on settled objects if a correction of the robot's
        pose says so (association/rejoin.py): within a metre for a robot on the map, within
        its drift's reach and with AGREEING landmarks for a returning one, which is then
        back; a robot whose frame went to mapped objects counts its drift from here."""
        returns = self.returns
        away = returns.away(robot_index)
        unsettled = returns.hidden(self.map.objects)  # a returning robot's own ones too
        if away is None:
            bounds = Bounds(unsettled=unsettled)
        else:
            apart = PLACE_SPACINGS * self.spacing.d_inter
            bounds = Bounds(away.shift, away.turn, AGREEING, unsettled, apart)
        xy = self.backend.current_pose(robot)[:2]
        rejoined = self.rejoiner.rejoin(xy, placed, ids, t, self.backend, bounds)
        moved = rejoined != ids
        nis[moved] = np.nan  # placed by the rejoin, not the GNN
        if (away is None and (rejoined >= 0).any()) or moved.any():
            returns.back(robot_index, chain)
        return rejoined, nis, bool(moved.any())
