"""A recorded survey published on the live topics, as its robots would: a bag's messages
as they are (their CDR, in log-time order), a survey log's or the simulator's records as
the messages `agrislam run` reads back from a bag (sinks/rosbag.py). `rate` times real
time; 0: as fast as the live node takes them, paced by its status so that nothing waits
past its queue."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agrislam.config import AgrislamConfig
from agrislam.io.ros.messages import STRING, MessageFactory
from agrislam.io.sinks.rosbag import survey_messages
from agrislam.io.sources import BAG_SUFFIXES, open_source
from agrislam.io.sources.bag_open import opened_bag
from agrislam.live.mapper import STATUS_TOPIC
from agrislam.live.node import LiveNode, Received


@dataclass
class ReplayResult:
    """Messages published, skipped (a type whose definition is unknown), seconds taken."""

    published: int
    skipped: dict[str, int]
    seconds: float


def recorded_messages(
    source: str | Path, config: AgrislamConfig, sections: Mapping[str, Any] | None = None
) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, log time ns, CDR) of a survey in time order: a bag's own messages, or
    a log's or simulation's records as messages."""
    path = Path(source) if not str(source).startswith("sim:") else None
    if path is not None and (path.is_dir() or path.name.lower().endswith(BAG_SUFFIXES)):
        store = MessageFactory("humble").store
        with opened_bag(path, store, lambda _: None) as reader:
            for conn, logtime, raw in reader.messages():
                yield conn.topic, conn.msgtype, logtime, bytes(raw)
        return
    yield from survey_messages(open_source(source, config, **(sections or {})).records())


class _Pace:
    """The live node's progress as its status topic tells it."""

    def __init__(self) -> None:
        self.taken = 0
        self.queue_size = 1
        self.heard = threading.Event()
        self.changed = threading.Condition()

    def status(self, sample: Received) -> None:
        text = MessageFactory("humble").store.deserialize_cdr(sample.payload, STRING).data
        state = json.loads(text)
        with self.changed:
            self.taken = int(state["taken"]) + sum(state["dropped"].values())
            self.queue_size = int(state["queue_size"])
            self.heard.set()
            self.changed.notify_all()

    def wait_below(self, sent: int, share: float = 0.5, timeout: float = 30.0) -> None:
        """Until the node holds fewer than `share` of its queue of our messages."""
        end = time.monotonic() + timeout
        with self.changed:
            while sent - self.taken >= max(1, int(self.queue_size * share)):
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError("the live node stopped taking messages")
                self.changed.wait(left)


def replay(
    node: LiveNode,
    messages: Iterator[tuple[str, str, int, bytes]],
    rate: float,
    wait_s: float = 10.0,
) -> ReplayResult:
    """Publish `messages` on `node`: at `rate` times real time from the first log time, or
    (rate 0) paced by the live node's status. Waits up to `wait_s` for a subscriber first."""
    if rate < 0:
        raise ValueError(f"--rate must be 0 (as fast as taken) or positive, got {rate}")
    pace = _Pace()
    node.subscribe(STRING, pace.status, STATUS_TOPIC)
    published, skipped = 0, dict[str, int]()
    start = time.monotonic()
    first: int | None = None
    for topic, msgtype, ns, data in messages:
        if msgtype not in node.store.types:
            skipped[msgtype] = skipped.get(msgtype, 0) + 1
            continue
        pub = node.publisher(topic, msgtype)
        if published == 0:
            _wait_for_subscriber(pub, pace, wait_s)
            start, first = time.monotonic(), ns
        if rate > 0:
            ahead = (ns - (first or ns)) * 1e-9 / rate - (time.monotonic() - start)
            if ahead > 0:
                time.sleep(ahead)
        else:
            pace.wait_below(published)
        pub.put(data, ns)
        published += 1
    if pace.heard.is_set():
        pace.wait_below(published, share=0.0)  # until the node took every one
    return ReplayResult(published, skipped, time.monotonic() - start)


def _wait_for_subscriber(pub: Any, pace: _Pace, wait_s: float) -> None:
    end = time.monotonic() + wait_s
    while time.monotonic() < end and not (pub.matched and pace.heard.is_set()):
        time.sleep(0.01)
    if not pub.matched:
        raise TimeoutError(
            f"no subscriber of {pub.topic} within {wait_s} s: is `agrislam live` up?"
        )
