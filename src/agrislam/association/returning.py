"""A robot back from a long time without seeing the map (not in the paper). Its drift since
it last put a detection on a mapped object may have carried it past the spacing of
neighbouring landmarks: when two places, further apart than association and the merger
set right, lie within its drift's reach and each takes its frame as well, the objects
nearest its first detections may be the other place's. A GNN decision taken then is wrong
from the first frame, and the factors it adds keep the robot there. While it is returning,
its detections go to objects it starts itself (its constellation), hidden from the other
robots and from the merger, until several landmarks agree on one correction of its pose:
a frame of its own (association/rejoin.py) or its constellation
(association/loop_closure.py), each within the reach of its drift.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agrislam.estimation.noise_calibration import NoiseScale
from agrislam.estimation.point_spacing import PointSpacing
from agrislam.geometry.drift import since_seen
from agrislam.geometry.odometry import OdometryChain
from agrislam.geometry.placed import PlacedDetections
from agrislam.mapping.map_state import MapState
from agrislam.mapping.objects import NO_OBJECTS, ObjectTable

RETURN_SIGMAS = 2.0  # a robot may be returning once this many sigmas of its drift ...
PLACE_SPACINGS = 2.0  # ... reach this many d_inter: places nearer are set right by the merger
REACH_SIGMAS = 3.0  # the largest correction of a returning robot's pose, in its drift's sigmas
AGREEING = 3  # distinct landmarks of one frame that must agree on one correction
# objects of its constellation that must: they were placed from poses some seconds apart,
# whose drift lets a triangle of them fit another of the map's
CONSTELLATION_AGREEING = 4
GIVE_UP_S = 60.0  # a robot no correction is clear for this long goes back to the GNN
RETURNED = "returns: robots back from a drift past the landmarks' spacing (returning.py)"
GAVE_UP = "returns given up: no correction was clear in time (association/returning.py)"


@dataclass(slots=True)
class Return:
    """A returning robot: since when, the objects it started since (its constellation) and
    how far its drift may have carried it (REACH_SIGMAS of it, at its last frame)."""

    since: float
    own: list[int] = field(default_factory=list)
    shift: float = 0.0  # m
    turn: float = 0.0  # rad


class Returns:
    """Which robots are returning, what they started since, and when they are back."""

    def __init__(
        self,
        map_state: MapState,
        spacing: PointSpacing,
        issues: Counter[str],
        enabled: bool = True,
    ) -> None:
        self.map, self.spacing, self.issues, self.enabled = map_state, spacing, issues, enabled
        self._anchor: dict[int, np.ndarray] = {}  # robot -> its chain's drift parts on the map
        self._away: dict[int, Return] = {}

    def check(
        self,
        robot: int,
        chain: OdometryChain,
        scale: NoiseScale,
        placed: PlacedDetections,
        heading: float,  # the robot's heading in the map frame
        positions: Callable[[np.ndarray], np.ndarray],  # ids -> (k, 2) the objects' estimates
        t: float,
    ) -> Return | None:
        """The robot's return at this frame, if it is returning. It starts when RETURN_SIGMAS
        of the robot's drift since it was last on the map reach past PLACE_SPACINGS d_inter
        at one of the frame's detections and the mapped objects within that reach take the
        frame as well at two places (`two_places`); it is given up after GIVE_UP_S."""
        d_inter, robot_xy = self.spacing.d_inter, placed.robot_xy
        if not self.enabled or d_inter is None or robot_xy is None or len(robot_xy) == 0:
            return self._away.get(robot)
        anchor = self._anchor.get(robot, np.zeros((3, 3, 3)))
        now, then = scale.odometry(chain.drift), scale.odometry(anchor)
        known = np.ones(1, dtype=bool)
        cov = since_seen(chain.pose, now, then[None], known, robot_xy, heading)[:, 0]
        sigma = float(np.sqrt(np.linalg.eigvalsh(cov)[:, -1].max()))
        away = self._away.get(robot)
        if away is None:
            reach, apart = RETURN_SIGMAS * sigma, PLACE_SPACINGS * d_inter
            if reach <= apart:
                return None
            ids = self.map.index.query(placed.xy, reach)
            ids = ids[~np.isin(ids, self.hidden(self.map.objects))]
            if not two_places(placed.xy, positions(ids), reach, d_inter, apart):
                return None
            away = self._away[robot] = Return(t)
            self.issues[RETURNED] += 1
        elif t - away.since > GIVE_UP_S:
            self.issues[GAVE_UP] += 1
            self.back(robot, chain)
            return None
        away.shift = REACH_SIGMAS * sigma
        away.turn = REACH_SIGMAS * float(np.sqrt(max(now[2, 2] - then[2, 2], 0.0)))
        return away

    def away(self, robot: int) -> Return | None:
        """The robot's return, if it is returning."""
        return self._away.get(robot)

    def on_map(self, robot: int, chain: OdometryChain) -> None:
        """The robot put a detection on a mapped object: its drift counts from here."""
        self._anchor[robot] = chain.drift.copy()

    def back(self, robot: int, chain: OdometryChain) -> None:
        """The robot is on the map again (or gave up): its constellation is released."""
        self._away.pop(robot, None)
        self.on_map(robot, chain)

    def started(self, robot: int, ids: np.ndarray) -> None:
        """Objects the robot started: its constellation's, if it is returning."""
        away = self._away.get(robot)
        if away is not None:
            away.own.extend(ids.tolist())

    def constellation(self, robot: int, objects: ObjectTable) -> np.ndarray:
        """The active objects the returning robot started (merges followed), sorted."""
        away = self._away.get(robot)
        if away is None or not away.own:
            return NO_OBJECTS
        own = np.unique(objects.resolve(np.array(away.own, dtype=np.int64)))
        return objects.active(own)

    def hidden(self, objects: ObjectTable, robot: int | None = None) -> np.ndarray:
        """The objects returning robots (but `robot`) started since they left the map:
        where they put them says nothing of where another robot is, nor of which mapped
        object they are, until the robot is back."""
        others = [self.constellation(r, objects) for r in self._away if r != robot]
        return np.unique(np.concatenate(others)) if others else NO_OBJECTS

    def eligible(self, robot: int, candidates: np.ndarray, objects: ObjectTable) -> np.ndarray:
        """The candidates the robot's detections may go to: its constellation's while it is
        returning, else all but the other returning robots' constellations."""
        if robot in self._away:
            return candidates[np.isin(candidates, self.constellation(robot, objects))]
        if not self._away:
            return candidates
        return candidates[~np.isin(candidates, self.hidden(objects, robot))]


def two_places(
    det_xy: np.ndarray, obj_xy: np.ndarray, reach: float, tolerance: float, apart: float
) -> bool:
    """Whether two shifts of the frame's detections `det_xy` (m, 2), each at most `reach`
    and `apart` or more from each other, put as many of them within `tolerance` of the
    objects `obj_xy` (k, 2) as the best shift does: the frame fits two places. The shifts
    tried put one detection on one object each."""
    if len(obj_xy) == 0:
        return False
    shifts = (obj_xy[None, :, :] - det_xy[:, None, :]).reshape(-1, 2)
    shifts = shifts[np.linalg.norm(shifts, axis=1) <= reach]
    if len(shifts) < 2:
        return False
    moved = det_xy[None, :, :] + shifts[:, None, :]  # (h, m, 2)
    gap = np.linalg.norm(moved[:, :, None, :] - obj_xy[None, None, :, :], axis=3)
    fits = (gap.min(axis=2) <= tolerance).sum(axis=1)  # (h,) detections on an object
    best = shifts[fits == fits.max()]
    return bool((np.linalg.norm(best[:, None] - best[None], axis=2) >= apart).any())
