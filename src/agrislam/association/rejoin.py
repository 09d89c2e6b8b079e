"""A robot that lost its way rejoins the map (not in the paper). Pairs of the frame's new
detections matched to pairs of settled objects as far apart fix corrections of its pose;
one that puts at least two more detections on settled objects than the GNN did, with no
distinct rival as good, is taken. A returning robot (association/returning.py) is given
bounds of its own: its drift's reach, and several landmarks agreeing."""

from __future__ import annotations

from collections import Counter
from typing import NamedTuple

import numpy as np

from agrislam.association.gnn import gated_matches
from agrislam.backend import GraphBackend
from agrislam.estimation.noise_calibration import mahalanobis
from agrislam.geometry.placed import PlacedDetections
from agrislam.geometry.se2 import pair_motions, turned
from agrislam.mapping.births import Births
from agrislam.mapping.objects import NO_OBJECTS
from agrislam.mapping.spatial_index import SpatialIndex

LOST_WINDOW_S = 30.0  # objects started this recently are not settled
MAX_SHIFT_M = 1.0  # the largest correction of the robot's position
MAX_TURN_RAD = 0.3  # and of its heading
DISTINCT = (0.2, 0.05)  # (m, rad): corrections nearer than this are one
SPACING_SIGMAS = 3.0  # two detections' distance apart matches two objects' within this
REJOINED = "frames on which a lost robot rejoined the map (association/rejoin.py)"


class Bounds(NamedTuple):
    """What a correction may be: how far it moves the robot, how many detections it must
    put on settled objects at least (beyond two more than the GNN did), and the objects
    that do not count as settled whatever their age."""

    shift: float = MAX_SHIFT_M  # m
    turn: float = MAX_TURN_RAD  # rad
    agreeing: int = 0
    unsettled: np.ndarray = NO_OBJECTS
    # m: corrections moving the frame's detections (median) this far from each other are
    # two places; None: those differing by DISTINCT
    apart: float | None = None


class Rejoiner:
    """Finds the correction that puts a lost robot's frame back on settled objects."""

    def __init__(
        self,
        index: SpatialIndex,
        births: Births,
        issues: Counter[str],
        gate_chi2: float | None = None,
    ) -> None:
        self.index, self.births = index, births
        self.issues = issues  # the run's issues count the frames rejoined
        self.gate_chi2 = gate_chi2  # the association's gate; None: off

    def rejoin(
        self,
        robot_xy: np.ndarray,  # (2,) the robot's position in the map
        placed: PlacedDetections,
        object_ids: np.ndarray,  # (m,) the GNN's choice, -1 new
        t: float,
        backend: GraphBackend,
        bounds: Bounds | None = None,
    ) -> np.ndarray:
        """`object_ids` with the frame put back on settled objects, or as they were."""
        if self.gate_chi2 is None:
            return object_ids
        bounds = bounds or Bounds()
        below = self.births.below(t - LOST_WINDOW_S)

        def settled(ids: np.ndarray) -> np.ndarray:
            return (ids >= 0) & (ids < below) & ~np.isin(ids, bounds.unsettled)

        lost = np.flatnonzero(~settled(object_ids))
        if len(lost) < max(2, bounds.agreeing) or below == 0:
            return object_ids
        det_xy, det_cov = placed.xy, placed.cov
        reach = bounds.shift + bounds.turn * np.linalg.norm(det_xy - robot_xy, axis=1).max()
        ids = self.index.query(det_xy[lost], reach)
        ids = ids[settled(ids)]
        if len(ids) < 2:
            return object_ids
        obj_xy, obj_cov = backend.object_positions(ids), backend.object_covariances(ids)
        corrections = _corrections(robot_xy, det_xy, det_cov, lost, obj_xy, bounds)
        if len(corrections) == 0:
            return object_ids
        cov = det_cov[:, None] + obj_cov[None, :]
        needed = max(int(settled(object_ids).sum()) + 2, bounds.agreeing)
        best = _best(
            corrections, robot_xy, det_xy, obj_xy, cov, self.gate_chi2, needed, bounds.apart
        )
        if best is None:
            return object_ids
        rows, cols = best
        rejoined = object_ids.copy()
        rejoined[np.isin(rejoined, ids[cols])] = -1  # an object goes to one detection
        rejoined[rows] = ids[cols]
        self.issues[REJOINED] += 1
        return rejoined


def _corrections(
    robot_xy: np.ndarray,
    det_xy: np.ndarray,
    det_cov: np.ndarray,
    lost: np.ndarray,
    obj_xy: np.ndarray,
    bounds: Bounds,
) -> np.ndarray:
    """(h, 3) corrections (dx, dy, dtheta), rotation about the robot first, that put a pair
    of the lost detections on a pair of objects as far apart, within the bounds."""
    i, j = np.triu_indices(len(lost), 1)
    seen = det_xy[lost[j]] - det_xy[lost[i]]
    # the spread of the detections' distance apart: both covariances along the line
    u = seen / np.maximum(np.linalg.norm(seen, axis=1), 1e-9)[:, None]
    spread = np.einsum("pi,pij,pj->p", u, det_cov[lost[i]] + det_cov[lost[j]], u)
    motions = pair_motions(
        det_xy[lost] - robot_xy, obj_xy - robot_xy, SPACING_SIGMAS * np.sqrt(spread)
    )
    shift, turn = motions[:, :2], motions[:, 2]
    within = (np.abs(turn) <= bounds.turn) & (np.linalg.norm(shift, axis=1) <= bounds.shift)
    return motions[within]


class _Fit(NamedTuple):
    matched: int  # detections on settled objects within the gate
    cost: float  # their Mahalanobis distances, summed
    rows: np.ndarray  # those detections
    cols: np.ndarray  # and their objects
    correction: np.ndarray  # (dx, dy, dtheta)


def _best(
    corrections: np.ndarray,
    robot_xy: np.ndarray,
    det_xy: np.ndarray,
    obj_xy: np.ndarray,
    cov: np.ndarray,  # (m, k, 2, 2)
    gate_chi2: float,
    needed: int,
    apart: float | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The (detections, objects) the best correction matches within the gate, if it
    matches at least `needed` and no distinct correction (`Bounds.apart`) matches as many."""

    def moved_by(correction: np.ndarray) -> np.ndarray:
        return turned(det_xy - robot_xy, correction[2]) + robot_xy + correction[:2]

    fits = []
    for correction in corrections:
        moved = moved_by(correction)
        cost = mahalanobis(obj_xy[None, :, :] - moved[:, None, :], cov)
        if (cost <= gate_chi2).any(axis=1).sum() < needed:
            continue
        rows, cols = gated_matches(cost, gate_chi2)
        if len(rows) >= needed:
            fits.append(_Fit(len(rows), float(cost[rows, cols].sum()), rows, cols, correction))
    if not fits:
        return None
    fits.sort(key=lambda f: (-f.matched, f.cost))
    top = fits[0]
    top_moved = moved_by(top.correction)
    for other in fits[1:]:
        if other.matched < top.matched:
            break
        if apart is not None:
            gap = np.median(np.linalg.norm(moved_by(other.correction) - top_moved, axis=1))
            distinct = bool(gap > apart)
        else:
            d = other.correction - top.correction
            distinct = np.hypot(*d[:2]) > DISTINCT[0] or abs(d[2]) > DISTINCT[1]
        if distinct:
            return None  # two places fit as well: not sure where it is
    return top.rows, top.cols
