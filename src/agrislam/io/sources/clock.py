"""Each robot's clock as a source reads its records: time never goes backwards, and one
record with a wild stamp costs that record only.

A record far ahead of its robot's recent stamps (more than `time_jump_s`, or
`time_jump_factor` times the robot's median interval, whichever is more) is held back
until the robot's next record shows what it was: a jump of the clock (both are released)
or a spike (the held record is rejected alone, as is one no later record confirms)."""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass, field
from statistics import median
from typing import Generic, TypeVar

from agrislam.config.limits import InputLimits

Item = TypeVar("Item")
RECENT = 16  # intervals a robot's typical rate is taken from


@dataclass(frozen=True, slots=True)
class Rejected(Generic[Item]):
    item: Item
    reason: str  # time_backwards or time_jump
    message: str
    key: Hashable = None


@dataclass
class _Clock(Generic[Item]):
    last: float | None = None
    intervals: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT))
    held: tuple[float, Item] | None = None

    def accept(self, t: float) -> None:
        if self.last is not None and t > self.last:
            self.intervals.append(t - self.last)
        self.last = t


class RobotClocks(Generic[Item]):
    """Per-key (robot, or a bag's topic: `noun`) time checks over a stream of (key, t, item).

    `offer` returns the items released in order (an item held earlier may come out with
    the current one) and those rejected; `finish` rejects what is still held."""

    def __init__(self, limits: InputLimits, noun: str = "robot") -> None:
        self.limits, self.noun = limits, noun
        self.clocks: dict[Hashable, _Clock[Item]] = {}

    def offer(self, key: Hashable, t: float, item: Item) -> tuple[list[Item], list[Rejected]]:
        clock = self.clocks.setdefault(key, _Clock())
        released: list[Item] = []
        rejected: list[Rejected] = []
        if clock.held is not None and clock.last is not None and t >= clock.last:
            held_t, held = clock.held
            clock.held = None
            if t >= held_t:  # the robot carries on from the held stamp: a real jump
                clock.accept(held_t)
                released.append(held)
            else:
                rejected.append(Rejected(held, "time_jump", self._spike(key, held_t, t), key))
        if clock.last is not None and t < clock.last:
            rejected.append(
                Rejected(
                    item,
                    "time_backwards",
                    f"{self.noun} {key!r}: t = {t} after t = {clock.last}",
                    key,
                )
            )
        elif clock.last is not None and t - clock.last > self._far(clock):
            clock.held = (t, item)
        else:
            clock.accept(t)
            released.append(item)
        return released, rejected

    def finish(self) -> list[Rejected]:
        """The held records no later record confirmed: rejected as time spikes."""
        out = []
        for key, clock in self.clocks.items():
            if clock.held is not None:
                held_t, held = clock.held
                clock.held = None
                ahead = held_t - (clock.last or 0.0)
                message = (
                    f"{self.noun} {key!r}: t = {held_t} is {ahead:.6g} s after the previous "
                    "record and no later record follows on from it"
                )
                out.append(Rejected(held, "time_jump", message, key))
        return out

    def _far(self, clock: _Clock) -> float:
        typical = median(clock.intervals) if clock.intervals else 0.0
        return max(self.limits.time_jump_s, self.limits.time_jump_factor * typical)

    def _spike(self, key: Hashable, held_t: float, t: float) -> str:
        return (
            f"{self.noun} {key!r}: t = {held_t} is a time spike: the next record is at "
            f"t = {t}, before it"
        )
