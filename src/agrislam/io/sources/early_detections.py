"""Detections read before their robot's first odometry record: the robot's time line starts
at its odometry. They wait for it off the robot's clock, so that the odometry after them is
not taken for time going backwards; then those stamped at or before it go on, in their
order and ahead of it, for the pose sync to place (at its time) or report as unplaced
(before it), and those stamped after it came out of the robot's time order (a detection
copied ahead of the log, say): rejected, each its own bad line."""

from __future__ import annotations

from typing import Generic, TypeVar

from agrislam.io.sources.clock import Rejected

Item = TypeVar("Item")
REASON = "before_odometry"


class EarlyDetections(Generic[Item]):
    """Per robot, its detections (t, item) read before its first odometry record."""

    def __init__(self) -> None:
        self.waiting: dict[str, list[tuple[float, Item]]] = {}
        self.moving: set[str] = set()  # robots whose first odometry was read

    def hold(self, robot: str, t: float, item: Item) -> None:
        """A detection of a robot without odometry yet: kept until its first odometry."""
        self.waiting.setdefault(robot, []).append((t, item))

    def waits(self, robot: str) -> bool:
        """Whether the robot has had no odometry record yet."""
        return robot not in self.moving

    def odometry(self, robot: str, t: float) -> tuple[list[Item], list[Rejected[Item]]]:
        """The robot's first odometry record, at t, is read: its detections that go ahead of
        it, and those rejected (stamped after it)."""
        self.moving.add(robot)
        ahead, rejected = [], []
        for stamp, item in self.waiting.pop(robot, []):
            if stamp <= t:
                ahead.append(item)
                continue
            message = (
                f"robot {robot!r}: detections at t = {stamp} read before the robot's first "
                f"odometry, at t = {t}: out of its time order"
            )
            rejected.append(Rejected(item, REASON, message, robot))
        return ahead, rejected

    def finish(self) -> list[Item]:
        """The detections of robots that never had odometry, to be reported unplaced."""
        out = [item for held in self.waiting.values() for _, item in held]
        self.waiting.clear()
        return out
