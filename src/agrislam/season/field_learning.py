"""A survey whose log gives no field prior (no meta, or a meta without `field`): its records
wait while the first robot's first frames, by dead reckoning (first_frames.py), say whether
its plants stand in rows (estimation/field_prior.py). The world then builds its stages for
the field so learned, or as point landmarks if the plants are not in rows within
LEARN_FOR_S of driving, and maps the records held in their order."""

from __future__ import annotations

from dataclasses import dataclass, field

from agrislam.config import SeasonConfig
from agrislam.estimation.field_prior import learn_field
from agrislam.records import Detections, FieldPrior, Odometry, Record
from agrislam.season.first_frames import FirstFrames

LEARN_EVERY_S = 5.0  # s of the first robot's driving between two tries
LEARN_FOR_S = 60.0  # s after which a survey not found in rows is mapped as landmarks


@dataclass
class FieldLearning:
    """The records held, every robot's first frames, the robot that detected first and
    the field prior learned (None: not in rows, or not yet)."""

    held: list[Record] = field(default_factory=list)
    frames: dict[str, FirstFrames] = field(default_factory=dict)
    first: str | None = None
    prior: FieldPrior | None = None
    t0: float | None = None  # the survey's first record's time

    def hold(self, record: Record, cfg: SeasonConfig, ambiguous: float) -> bool:
        """Keep a record; True once the field is decided (`prior`): in rows, or not within
        LEARN_FOR_S of the survey's start. `ambiguous`: how far a rival row angle may come
        (the row fit's first_fit_ambiguity)."""
        self.held.append(record)
        if not isinstance(record, (Odometry, Detections)):
            return False
        self.t0 = record.t if self.t0 is None else self.t0
        frames = self.frames.setdefault(record.robot, FirstFrames())
        frames.add(record, None)
        if self.first is None and isinstance(record, Detections) and record.objects:
            self.first = record.robot
        first = isinstance(record, Detections) and record.robot == self.first
        if first and frames.due(record.t, LEARN_EVERY_S) and self.learn(cfg, ambiguous):
            return True
        return record.t - self.t0 > LEARN_FOR_S

    def learn(self, cfg: SeasonConfig, ambiguous: float) -> bool:
        """One try on the first robot's plants seen twice; whether they are in rows."""
        if self.first is None:
            return False
        _, _, (plants, counts, _) = self.frames[self.first].plants(cfg)
        self.prior = learn_field(plants[counts >= 2], ambiguous)
        return self.prior is not None
