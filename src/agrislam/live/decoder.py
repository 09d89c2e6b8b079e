"""Messages into records one at a time, as they arrive: the bag source's reading (roles of
topics by type or config, robots by namespace, clocks, tf, the RGB-D front end, validation)
applied to a stream whose topics appear while it runs. Fed the messages of a recording in
its order, it gives the records `agrislam run` reads from that recording, in that order
(but for a stamp far ahead of its topic's, which it passes on at once: see `__init__`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from agrislam.config import AgrislamConfig
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.io.sources.bag_report import BagReport, SkipError
from agrislam.io.sources.clock import RobotClocks
from agrislam.io.sources.rgbd import RgbdFrames
from agrislam.io.sources.rosbag import _BagReader
from agrislam.records import Record


class LiveDecoder(_BagReader):
    """`feed` a message, get the records it completes (usually one, none for a message that
    waits for another: a frame for its depth image, a held time jump)."""

    def __init__(self, config: AgrislamConfig, bag: BagSourceConfig | None = None) -> None:
        super().__init__(Path("live"), config, bag or BagSourceConfig())
        self.topic_type: dict[str, str] = {}
        self.role_of: dict[str, str] = {}
        self.odom_robots: set[str] = set()
        self.rgbd = RgbdFrames(self.bag, self.perception, self, self._roles_quietly(), {})
        # a bag's reader holds a stamp far ahead of its topic's until the next one tells a
        # spike from a jump, and sorts what it held back into place at the end; live, a held
        # frame would come out after later odometry, and gaps are what dropped frames leave
        limits = config.advanced.sensor.limits.model_copy(update={"time_jump_s": math.inf})
        self.clocks = RobotClocks(limits, "topic")

    def _roles_quietly(self) -> dict[str, list[str]]:
        """The roles of the topics seen so far; what is missing is no issue yet (it may come)."""
        report, self.report = self.report, BagReport("live")
        try:
            return self._roles(self.topic_type)
        finally:
            self.report = report

    def add_topic(self, topic: str, msgtype: str) -> bool:
        """A topic seen for the first time: roles, robots and camera pairs again; whether
        it has a role (else its messages are recorded but not mapped)."""
        self.topic_type[topic] = msgtype
        roles = self._roles_quietly()
        self.report.roles = roles
        self.role_of = {t: role for role, ts in roles.items() for t in ts}
        self.odom_robots = {self.robot_of(t, odometry=True)[0] for t in roles["odometry"]}
        self.rgbd._pair(roles, self.topic_type)
        return topic in self.role_of

    def feed(self, topic: str, msgtype: str, payload: bytes, logtime: int) -> list[Record]:
        """One message (its CDR) at `logtime` ns; the records it completes, in time order."""
        if topic not in self.topic_type:
            self.add_topic(topic, msgtype)
        if topic not in self.role_of:
            return []
        self.report.messages[topic] += 1
        try:
            msg: Any = self.store.deserialize_cdr(payload, msgtype)
            self._dispatch(topic, msg, logtime)
        except SkipError as skip:
            self.report.add(skip.kind, topic, logtime * 1e-9, skip.message)
        except Exception as err:  # a payload that is no message of its type
            self.report.add("undecodable", topic, logtime * 1e-9, f"cannot decode {msgtype}: {err}")
        return self._drained()

    def finish(self) -> list[Record]:
        """At the end: frames still waiting for depth, held stamps (as at a bag's end)."""
        self._place_2d(self.rgbd.finish())
        self._late(self.clocks.finish())
        return self._drained()

    def _drained(self) -> list[Record]:
        out = self._ordered()
        self.records.clear()
        for rec in out:
            self.report.records[type(rec).__name__] += 1
        return out
