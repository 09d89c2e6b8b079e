"""A survey as its log starts it, when the log says too little: without a meta it is said in
the run's issues; without a field prior (no meta, or a meta without `field`) its records
wait while the first robot's first frames, by dead reckoning (first_frames.py), say whether
its plants stand in rows (estimation/field_prior.py). Found, the meta goes on with the field
prior learned and the survey is mapped as a crop field; else as point landmarks
(config/effective.py), its records as they came.

A stream adapter of the run (`learn_field`), before the world: what it yields depends on the
records alone, so a run resumed from a checkpoint, reading the log again, is given the same
stream."""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from itertools import chain

from agrislam.config import AgrislamConfig, SeasonConfig, effective
from agrislam.estimation.field_prior import field_of
from agrislam.records import Detections, FieldPrior, Meta, Odometry, Record
from agrislam.season.first_frames import FirstFrames

LEARN_EVERY_S = 5.0  # s of the first robot's driving between two tries
LEARN_FOR_S = 60.0  # s after which a survey not found in rows is mapped as landmarks
NO_META = (
    "no meta record: no schema, start poses, anchor or field prior; the map frame is the "
    "first robot's first pose"
)


def learn_field(
    records: Iterable[Record], config: AgrislamConfig, issues: Counter[str]
) -> Iterator[Record]:
    """`records` with a meta carrying the field prior their first plants show, when the log
    gives none and the config leaves the survey to be mapped as landmarks; a log without a
    meta is counted in `issues`, as is a field learned."""
    it = iter(records)
    first = next(it, None)
    if first is None:
        return
    meta = first if isinstance(first, Meta) else None
    if meta is None:
        issues[NO_META] += 1
        it = chain([first], it)
    if not effective(config, meta.field if meta is not None else None).landmarks:
        yield from chain([meta] if meta is not None else [], it)
        return
    learning = FieldLearning()
    rows = config.advanced.rows.first_fit_ambiguity
    for record in it:
        if learning.hold(record, config.advanced.season, rows):
            break
    else:  # the log ended before the field was decided
        learning.learn(config.advanced.season, rows)
    prior = learning.prior
    if prior is not None:
        issues[
            f"no field prior: the first plants stand in rows {prior.row_spacing:.2f} m apart, "
            f"{prior.min_plant_distance:.2f} m apart in the rows; mapped as a crop field"
        ] += 1
        meta = dataclasses.replace(meta or Meta(), field=prior)
    yield from chain([meta] if meta is not None else [], learning.held, it)


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
        self.prior = field_of(plants[counts >= 2], ambiguous)
        return self.prior is not None
