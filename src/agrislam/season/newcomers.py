"""Robots without a start pose that join a survey whose map frame is already set, by the
meta's start poses or by the robot that started the map: the spec's "placed by the mapper
from shared landmarks, or reported as not placed". Each one's records wait while its first
frames, by dead reckoning, are registered in the map being built as a season's robot is in
a saved map (first_frames.py, relocalise.py); once they fit, it starts there and its
records are mapped in their order. Until then none of its detections starts an object; one
never placed is reported with the frames that were not mapped."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.config import FieldSchema, SeasonConfig
from agrislam.mapping.map_state import MapState
from agrislam.records import Detections, GnssFix, Odometry, RobotStart
from agrislam.season.first_frames import Check, FirstFrames, compatibility
from agrislam.season.relocalise import Relocaliser

# the map is registered in again once it holds this many times the objects it held at the
# last registration (and ten more at least): each newcomer's first frames are tried
# again on it, at a cost that grows with the map only as often as the map doubles
GROWTH = 1.25
MIN_FRAMES = 2  # frames an object was seen in before it can place a newcomer

Held = Odometry | Detections | GnssFix


def placed_issue(robot: str) -> str:
    return f"robot {robot!r} has no start pose: placed where its detections fit the map"


def not_placed_issue(robot: str, reason: str) -> str:
    return (
        f"robot {robot!r} has no start pose and its detections fit nowhere on the map "
        f"({reason}): its frames not mapped"
    )


@dataclass
class _Waiting:
    """A newcomer's first frames, its records held back, the outcome of its registration
    that matched most plants and the map it was last tried in (a `_Map.version`)."""

    frames: FirstFrames = field(default_factory=FirstFrames)
    held: list[Held] = field(default_factory=list)
    reason: str = "too few settled objects yet"
    inliers: int = 0
    tried: int = -1


@dataclass(frozen=True)
class _Map:
    """The map being built as newcomers are registered in it: its settled objects' ids and
    their relocaliser; `size` objects in the table when made."""

    version: int
    size: int
    ids: np.ndarray
    relocaliser: Relocaliser


class Newcomers:
    """The robots waiting to be placed, and their placing."""

    def __init__(self) -> None:
        self.waiting: dict[str, _Waiting] = {}
        self._map: _Map | None = None

    def hold(self, record: Held, schema: FieldSchema | None) -> None:
        """Keep a record of a robot that waits to be placed."""
        waiting = self.waiting.setdefault(record.robot, _Waiting())
        waiting.held.append(record)
        if not isinstance(record, GnssFix):
            waiting.frames.add(record, schema)

    def place(
        self,
        map_state: MapState,
        backend: GraphBackend,
        cfg: SeasonConfig,
        t: float,
        robot: str | None = None,
        last: bool = False,
    ) -> list[tuple[str, RobotStart, list[Held]]]:
        """The newcomers whose first frames now fit the map, with their start priors and
        records held: every robot's first window_s of frames is tried in each new
        registration map (`GROWTH`); `robot`, whose record came, its latest window_s every
        attempt_every_s of its driving. `last`: the survey's end, every robot's both tried
        once more in the whole map."""
        reg = self._registration(map_state, backend, cfg, last)
        if reg is None:
            return []
        fresh = last or any(w.tried < reg.version for w in self.waiting.values())
        names = list(self.waiting) if fresh else [robot] if robot in self.waiting else []
        check = _attributes(map_state, reg.ids, t)
        out = []
        for name in names:
            waiting = self.waiting[name]
            frames = waiting.frames
            if not frames.t:
                continue
            first, now = frames.t[0], frames.t[-1]
            due = (name == robot and frames.due(now, cfg.attempt_every_s)) or last
            starting = now - first <= cfg.window_s  # its latest frames are its first
            fix = None
            if waiting.tried < reg.version or (starting and due):
                waiting.tried = reg.version
                fix = frames.locate(reg.relocaliser, cfg, first, first + cfg.window_s, check)
            if (fix is None or not fix.localised) and due and not starting:
                fix = frames.locate(reg.relocaliser, cfg, now - cfg.window_s, check=check)
            if fix is None:
                continue
            if fix.n_inliers >= waiting.inliers:  # the nearest miss says why it failed
                waiting.reason, waiting.inliers = fix.reason, fix.n_inliers
            if fix.localised:
                frames.localised(fix, now)
                out.append((name, frames.start(), waiting.held))
                del self.waiting[name]
        return out

    def first(self) -> tuple[str, list[Held]]:
        """The robot that waited longest, taken out with its records."""
        name = next(iter(self.waiting))
        return name, self.waiting.pop(name).held

    def not_placed(self) -> dict[str, tuple[int, str]]:
        """Each robot still waiting: its frames held and why it was not placed."""
        return {
            name: (sum(isinstance(r, Detections) for r in w.held), w.reason)
            for name, w in self.waiting.items()
        }

    def _registration(
        self, map_state: MapState, backend: GraphBackend, cfg: SeasonConfig, last: bool
    ) -> _Map | None:
        """The map to register in: made again when the object table has grown by GROWTH
        (at the survey's end, by anything); None while it has fewer settled objects than a
        registration needs."""
        size, reg = len(map_state.objects), self._map
        if reg is not None:
            grown = size > reg.size if last else size >= max(GROWTH * reg.size, reg.size + 10)
            if not grown:
                return reg
        objects = map_state.objects
        ids = objects.active_ids()
        ids = ids[~objects.tentative[ids] & (objects.n_frames[ids] >= MIN_FRAMES)]
        if len(ids) < cfg.min_landmarks:
            return None
        var = np.trace(backend.object_covariances(ids), axis1=1, axis2=2) / 2.0
        partial = cfg.model_copy(update={"min_inlier_fraction": cfg.newcomer_inlier_fraction})
        relocaliser = Relocaliser(backend.object_positions(ids), partial, map_var=var)
        version = 0 if reg is None else reg.version + 1
        self._map = _Map(version, size, ids, relocaliser)
        return self._map


def _attributes(map_state: MapState, ids: np.ndarray, t: float) -> Check:
    """Which of the map objects `ids` (by relocaliser row) a first-frames plant may be, by
    the objects' beliefs at t."""
    compatible = compatibility(map_state.beliefs, t)

    def check(local: dict[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
        return compatible(local, ids[rows])

    return check
