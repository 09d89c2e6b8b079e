"""A season as separate survey logs: the field of `Simulator` on each survey
day, grown (App. B), with some plants removed and weeds emerged since the previous day;
each day's robot starts somewhere along its route, at a place the log does not give."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from agrislam.geometry import se2
from agrislam.records import Meta, Record
from agrislam.sim.config import SimConfig
from agrislam.sim.field import Field, _place_weeds
from agrislam.sim.simulator import RobotSurvey, Simulator

SEASON_START = 1_775_030_400.0  # 2026-04-01T08:00:00Z, the first survey day's t = 0
_SEASON = 21  # random stream of the season's changes


class _Offset:
    """A route entered `d0` metres along: the same calls as SurveyPath."""

    def __init__(self, path, d0: float) -> None:
        self.path, self.d0 = path, d0

    def sample(self, times: np.ndarray, speed: float) -> np.ndarray:
        return self.path.at_distance(self.d0 + speed * np.asarray(times, float))

    def duration(self, speed: float) -> float:
        return (self.path.length - self.d0) / speed

    def at_distance(self, d: np.ndarray) -> np.ndarray:
        return self.path.at_distance(self.d0 + np.asarray(d, float))


def subset(field: Field, keep: np.ndarray) -> Field:
    """The field with only the plants `keep` (bool)."""
    names = ("ids", "xy", "length", "growth_rate", "is_weed", "row")
    return replace(
        field,
        **{n: getattr(field, n)[keep] for n in names},
        discrete={k: v[keep] for k, v in field.discrete.items()},
        continuous={k: v[keep] for k, v in field.continuous.items()},
    )


def joined(a: Field, b: Field) -> Field:
    names = ("ids", "xy", "length", "growth_rate", "is_weed", "row")
    return replace(
        a,
        **{n: np.concatenate([getattr(a, n), getattr(b, n)]) for n in names},
        discrete={k: np.concatenate([v, b.discrete[k]]) for k, v in a.discrete.items()},
        continuous={k: np.concatenate([v, b.continuous[k]]) for k, v in a.continuous.items()},
    )


class SeasonSimulator(Simulator):
    """`survey_days` of the config as separate logs; `removed`: share of the plants
    removed between two surveys; `weeds`: weeds emerging between two surveys."""

    def __init__(self, cfg: SimConfig, removed: float = 0.05, weeds: int = 10) -> None:
        super().__init__(cfg)
        rng = self._rng(_SEASON)
        self.fields = [self.field_on(0)]
        for d in range(1, len(self.days)):
            prev = self.fields[-1].grown(self.days[d] - self.days[d - 1])
            keep = rng.random(len(prev)) >= removed
            prev = subset(prev, keep)
            self.fields.append(joined(prev, self._weeds(prev, weeds, d, rng)))
        self.entry = [0.0] + [rng.uniform(0.05, 0.5) * self.paths[0].length for _ in self.days[1:]]

    def _weeds(self, field: Field, n: int, day: int, rng: np.random.Generator) -> Field:
        layout = self.cfg.field
        s, across = field.to_field(field.xy)
        sl = _place_weeds(n, field.row_length, layout, np.column_stack([s, across]), rng)
        k = len(sl)
        spec = self.schema.attributes
        discrete = {}
        for name, values in field.discrete.items():
            vals = spec[name].values
            pick = vals.index("weed") if "weed" in vals else 0
            discrete[name] = (
                np.full(k, pick, dtype=values.dtype) if "weed" in vals else rng.choice(len(vals), k)
            )
        continuous = {
            n: rng.uniform(spec[n].min, spec[n].min + 0.2 * (spec[n].max - spec[n].min), k)
            for n in field.continuous
        }
        return replace(
            field,
            ids=np.array([f"w{day}_{i:03d}" for i in range(k)]),
            xy=field.to_map(sl[:, 0], sl[:, 1]).reshape(-1, 2),
            length=np.full(k, self.cfg.field.length_range[0]),
            growth_rate=np.full(k, float(np.median(field.growth_rate))),
            is_weed=np.ones(k, bool),
            row=np.full(k, -1),
            discrete=discrete,
            continuous=continuous,
        )

    def field_on(self, day: int) -> Field:
        if hasattr(self, "fields") and day < len(self.fields):
            return self.fields[day]
        return super().field_on(day)

    def survey(self, day: int, robot: int, name: str | None = None) -> RobotSurvey:
        paths = self.paths
        entry = self.entry[day] if hasattr(self, "entry") else 0.0
        self.paths = [_Offset(p, entry) for p in paths]
        try:
            return super().survey(day, robot, name)
        finally:
            self.paths = paths

    def meta(self, names: list[str], days: list[int]) -> Meta:
        """No start pose (the robot is somewhere in the field); the survey's start time.
        On the first survey, mapped from nothing in the first robot's frame, a team's other
        robots start where the team knows them to be from the first (unloaded together)."""
        meta = super().meta(names, days)
        robots = {}
        if days == [0] and len(names) > 1:
            first = meta.robots[names[0]].pose
            robots = {
                n: replace(meta.robots[n], pose=se2.between(first, meta.robots[n].pose))
                for n in names[1:]
            }
        return replace(meta, robots=robots, survey_start=SEASON_START, anchor=None)

    def season_logs(self) -> Iterator[tuple[int, Iterator[Record]]]:
        for d in range(len(self.days)):
            yield d, self.day_records(d)


def season_config(cfg: SimConfig, days: list[float]) -> SimConfig:
    return cfg.model_copy(update={"growth": cfg.growth.model_copy(update={"survey_days": days})})
