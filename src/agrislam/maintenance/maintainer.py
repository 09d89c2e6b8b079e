"""The maintenance stage (sec. 2.6.3): young objects in view confirmed or dropped, objects
closer than d_inter merged, a returning robot's copies of old objects merged into them
(those it started since it left the map kept apart until then), rarely seen uncertain
objects pruned; at the end of a survey, those still unsure judged.
Each step looks only around what changed."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agrislam.association.loop_closure import LoopCloser, Rule
from agrislam.association.range_outliers import RangeOutliers
from agrislam.association.returning import CONSTELLATION_AGREEING, PLACE_SPACINGS, Returns
from agrislam.backend import GraphBackend
from agrislam.config import MaintenanceConfig
from agrislam.estimation.point_spacing import PointSpacing
from agrislam.geometry.placed import FrameMatch
from agrislam.maintenance.existence import Existence
from agrislam.maintenance.merger import Merger
from agrislam.maintenance.pruning import AfterFold, prune_due
from agrislam.mapping.map_state import MapState
from agrislam.snapshot import STATUS_MERGED, STATUS_PRUNED


@dataclass(slots=True)
class MaintenanceResult:
    merged: list[tuple[int, int]] = field(default_factory=list)  # (keep, drop)
    pruned: list[int] = field(default_factory=list)
    loops: int = 0  # loops closed (association/loop_closure.py): their merges are in `merged`


class Maintainer:
    """Confirms, merges and prunes the objects of one survey's map."""

    def __init__(
        self,
        config: MaintenanceConfig,
        map_state: MapState,
        backend: GraphBackend,
        spacing: PointSpacing,
        safeguards: tuple[Merger, LoopCloser, RangeOutliers, Returns],
        first_own: int,
    ) -> None:
        self.config, self.map, self.backend, self.spacing = config, map_state, backend, spacing
        self.merger, self.loops, self.outliers, self.returns = safeguards
        self.existence = Existence(config)
        self.first_own = first_own  # a saved map's plants come first: they are not judged
        self._after_fold = AfterFold()

    def confirm(self, match: FrameMatch) -> np.ndarray:
        """The frame's view of young objects: those its sightings confirm stay, those they
        say are not there are returned, to be pruned."""
        placed, index = match.placed, self.map.index
        self.existence.observe(placed.robot_xy)
        objects = self.map.objects
        self.outliers.saw(match.pose, placed, match.object_ids, index, self.backend, objects)
        return self.existence.look(match.pose, index, match.seen, objects, self.first_own)

    def floor(self, match: FrameMatch) -> np.ndarray:
        """(m,) m of isotropic noise each detection's factor gets: d_inter for a tentative
        object's, whose detections say where it is, not where the robot is."""
        tentative = self.map.objects.tentative[match.object_ids]
        return np.where(tentative, self.spacing.d_inter, 0.0)

    def due(self, seen: np.ndarray, folded: bool) -> np.ndarray:
        """The objects whose row and merge work is due now: those seen, unless this step
        folded a window (then the next step's, with those waiting)."""
        return self.map.objects.active(self._after_fold.ready(seen, folded))

    def maintain(
        self,
        match: FrameMatch,
        touched: np.ndarray,
        dropped: np.ndarray,
        noise_variance: float,
    ) -> MaintenanceResult:
        """Merge near objects and a returning robot's copies (sec. 2.6.3), prune the due
        and the dropped ones."""
        if len(match.object_ids):  # (d_inter is known once there are detections)
            self.merger.saw(match.object_ids, match.placed.xy, 2.0 * self.spacing.d_inter)
        result = self._merge_and_prune(touched, match.t)
        loop = self._close_loop(match, noise_variance)
        result.merged += self._merge(loop)
        result.loops = int(bool(loop))
        result.pruned += self._prune(self.map.objects.active(dropped).tolist())
        return result

    def _close_loop(self, match: FrameMatch, noise_variance: float) -> list[tuple[int, int]]:
        """(old, new) pairs of the frame's robot's loop: its constellation on the map, by a
        small motion as well while it is returning (then it is back), else by a large one."""
        objects, robot, returns = self.map.objects, match.robot_index, self.returns
        away = returns.away(robot)
        if away is None:
            hidden = returns.hidden(objects)
            return self.loops.pairs(robot, match.t, objects, self.backend, noise_variance, hidden)
        own = returns.constellation(robot, objects)
        apart = PLACE_SPACINGS * self.spacing.d_inter
        rule = Rule(CONSTELLATION_AGREEING, 0.0, away.shift, away.turn, apart)
        hidden = returns.hidden(objects, robot)
        loop = self.loops.returned(robot, own, rule, objects, self.backend, noise_variance, hidden)
        if loop:
            returns.back(robot, match.chain)
        return loop

    def finish(self, t: float, poses: Callable[[], list[np.ndarray]]) -> MaintenanceResult:
        """End of the survey: the young uncertain objects still in their grace period go
        (they will not be seen again), then those still tentative that the survey's frame
        poses ((m, 3) per robot, read after that) say are not there, and those made of
        range errors alone."""
        waiting = self._after_fold.ready(np.empty(0), False)
        result = self._merge_and_prune(waiting, t, grace=0.0)
        objects = self.map.objects
        ids = objects.active(np.arange(self.first_own, len(objects)))  # this survey's
        positions = self.backend.object_positions
        absent = self.existence.absent(ids, positions, objects, poses())
        made_of_outliers = self.outliers.made_of_outliers(ids, objects.n_meas)
        result.pruned += self._prune(sorted(set(absent + made_of_outliers)))
        return result

    def _merge_and_prune(
        self, touched: np.ndarray, t: float, grace: float | None = None
    ) -> MaintenanceResult:
        """Merge touched objects closer than d_inter; prune young uncertain ones."""
        cfg, result, objects = self.config, MaintenanceResult(), self.map.objects
        touched = objects.active(touched)
        if cfg.merge and len(touched):
            positions, d_inter = self.backend.object_positions, self.spacing.d_inter
            apart = self.returns.hidden(objects)
            pairs = self.merger.pairs(touched, self.map.index, positions, objects, d_inter, apart)
            result.merged = self._merge(pairs)
        if cfg.prune:
            result.pruned = self._prune(prune_due(objects, t, cfg, grace))
        return result

    def _prune(self, ids: list[int]) -> list[int]:
        """The objects leave the graph and the map."""
        for obj in ids:
            self.backend.remove_object(obj)
        if ids:
            self.map.objects.retire(np.array(ids), STATUS_PRUNED)
        return ids

    def _merge(self, pairs: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """Fold each `drop` into its `keep`: beliefs fused, graph nodes merged."""
        objects = self.map.objects
        for keep, drop in pairs:
            objects.beliefs.fuse(keep, drop)
            self.backend.merge_objects(keep, drop)
            objects.absorb(keep, drop)
            self.merger.merged(keep, drop)
            objects.retire(np.array([drop]), STATUS_MERGED, into=keep)
        return pairs
