"""The live map: samples from the node go to the recording at once and into a bounded
queue; the mapper takes them in the order they came, decodes them into records and runs
the offline pipeline (`run_survey`) on that stream, so the outputs at the end are those of
`agrislam run`. Between records it publishes the map (as soon as a frame is mapped, at most
`live.publish_rate` Hz and at most a third of the time) and its status.

When the mapper falls behind, the queue does not grow: past `live.queue_size` detection
frames (and images) waiting, the oldest is dropped and counted; odometry, GNSS, tf and meta,
small and what every later frame builds on, wait up to `ESSENTIAL_FACTOR` times that.
Messages are taken in arrival order, never held for a robot that went silent."""

from __future__ import annotations

import json
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.config import AgrislamConfig
from agrislam.io.ros.messages import (
    CAMERA_INFO,
    DETECTION2D_ARRAY,
    DETECTION3D_ARRAY,
    IMAGE,
    ODOMETRY,
    STRING,
    TF_MESSAGE,
    MessageFactory,
)
from agrislam.io.ros.navsat import NAVSAT_FIX
from agrislam.io.sinks.run_folder import RunFolder
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.live.decoder import LiveDecoder
from agrislam.live.map_topics import map_messages
from agrislam.live.node import LiveNode, Received
from agrislam.live.recording import LiveRecording
from agrislam.records import Detections, Record
from agrislam.run.pipeline import RunResult, run_survey
from agrislam.world import StepReport, WorldModel

SUBSCRIBED = (ODOMETRY, DETECTION3D_ARRAY, DETECTION2D_ARRAY, NAVSAT_FIX, CAMERA_INFO, IMAGE)
DROPPABLE = frozenset({DETECTION3D_ARRAY, DETECTION2D_ARRAY, IMAGE})
STATUS_TOPIC = "/agrislam/status"
RECORDING = "live.mcap"
LATENCIES_KEPT = 100_000
ESSENTIAL_FACTOR = 64  # odometry, GNSS, tf, meta queued at most this many times queue_size
STATUS_PERIOD_S = 0.02
# a publication waits at least this many times what the last one took, so that a large
# map's publishing (its snapshot and markers) keeps to a third of the mapper's time
PUBLISHING_SHARE = 3.0  # the status goes out at most this often while messages come


@dataclass
class LiveStats:
    """What the live node did: messages received, taken by the mapper, dropped (by topic);
    frames mapped; how late the mapper ran (s from receipt to decoding) and the
    detection-to-map latencies (s from a frame's receipt to the publication of the map
    that contains it)."""

    received: int = 0
    taken: int = 0
    frames_mapped: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    most_queued: int = 0
    lag_s: float = 0.0
    most_lag_s: float = 0.0
    publications: int = 0
    latencies_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCIES_KEPT))

    def as_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latencies_s, dtype=float)
        return {
            "received": self.received,
            "taken": self.taken,
            "frames_mapped": self.frames_mapped,
            "dropped": dict(self.dropped),
            "most_queued": self.most_queued,
            "lag_s": self.lag_s,
            "most_lag_s": self.most_lag_s,
            "publications": self.publications,
            "latency_median_s": float(np.median(lat)) if lat.size else None,
            "latency_p95_s": float(np.percentile(lat, 95)) if lat.size else None,
        }


class _LiveWorld(WorldModel):
    """The world model, telling the mapper each frame it has mapped."""

    def __init__(self, config: AgrislamConfig, on_frame: Callable[[Detections], None]) -> None:
        super().__init__(config)
        self._on_frame = on_frame

    def step(self, frame: Detections) -> StepReport:
        report = super().step(frame)
        self._on_frame(frame)
        return report


class LiveMapper:
    """One live run on `node`: `subscribe`, then `run` maps until `stop` is called (from a
    signal handler or another thread) and the queue is drained."""

    def __init__(
        self,
        node: LiveNode,
        config: AgrislamConfig,
        recording: LiveRecording | None = None,
        bag: BagSourceConfig | None = None,
    ) -> None:
        self.node, self.config, self.recording = node, config, recording
        self.bag = bag or BagSourceConfig()
        self.live, self.options = config.live, config.advanced.live
        self.decoder = LiveDecoder(config, self.bag)
        self.make = MessageFactory("humble")
        self.world = _LiveWorld(config, self._mapped)
        self.stats = LiveStats()
        self.queue: deque[tuple[Received, float]] = deque()
        self.frames_queued = 0  # detection frames and images in the queue
        self.ready = threading.Condition()
        self.stopping = threading.Event()
        self.period = 1.0 / self.live.publish_rate
        self.gap = self.period  # to the next publication: longer when publishing costs more
        self.last_publication = -float("inf")
        self.waiting: dict[tuple[str, float], float] = {}  # frame -> when it came
        self.unpublished: list[float] = []  # when each frame mapped since came
        self.announced: set[str] = set()
        self.last_status = -float("inf")

    # ----------------------------------------------------------------- input

    def subscribe(self) -> None:
        """Subscribe to every robot's (or the configured robots') inputs, tf, meta, truth."""
        patterns = [f"{r}/**" for r in self.live.robots] if self.live.robots else ["**"]
        for msgtype in SUBSCRIBED:
            for pattern in patterns:
                self.node.subscribe(msgtype, self.receive, pattern)
        for topic in ("/tf", "/tf_static"):
            self.node.subscribe(TF_MESSAGE, self.receive, topic)
        for topic in (self.bag.meta_topic, self.bag.truth_topic):
            self.node.subscribe(STRING, self.receive, topic)
            self.announced.add(topic)
        self.announced.update(("/tf", "/tf_static"))

    def receive(self, sample: Received) -> None:
        """A sample (on Zenoh's thread): recorded, then queued; the queue kept bounded."""
        if self.stopping.is_set():
            return
        if self.recording is not None:
            self.recording.write(sample.topic, sample.msgtype, sample.payload, sample.received_ns)
        with self.ready:
            self.stats.received += 1
            droppable = sample.msgtype in DROPPABLE
            if droppable and self.frames_queued >= self.live.queue_size:
                self._drop(next(i for i, (s, _) in enumerate(self.queue) if s.msgtype in DROPPABLE))
            elif len(self.queue) >= ESSENTIAL_FACTOR * self.live.queue_size:
                self._drop(0)
            self.queue.append((sample, time.perf_counter()))
            self.frames_queued += droppable
            self.stats.most_queued = max(self.stats.most_queued, len(self.queue))
            self.ready.notify()

    def _drop(self, at: int) -> None:
        dropped, _ = self.queue[at]
        del self.queue[at]
        self.frames_queued -= dropped.msgtype in DROPPABLE
        self.stats.dropped[dropped.topic] += 1

    def stop(self) -> None:
        """End the run: no more samples are taken; those queued are still mapped."""
        self.stopping.set()
        with self.ready:
            self.ready.notify()

    # ----------------------------------------------------------------- mapping

    def run(self, folder: RunFolder | Path | None) -> RunResult:
        """Map until stopped; then the outputs of `agrislam run` into `folder`."""
        try:
            return run_survey(self.records(), self.world, folder, self._publish_if_due)
        finally:
            self._status()

    def records(self) -> Iterator[Record]:
        """The records of the samples, in the order they came, until stopped and drained."""
        while True:
            item = self._next()
            now = time.perf_counter()
            if now - self.last_status > STATUS_PERIOD_S:
                self._status()
            if item is None:
                if self.stopping.is_set():
                    break
                self._publish_if_due()
                continue
            sample, came = item
            self.stats.lag_s = now - came
            self.stats.most_lag_s = max(self.stats.most_lag_s, self.stats.lag_s)
            self._announce(sample)
            for rec in self.decoder.feed(
                sample.topic, sample.msgtype, sample.payload, sample.received_ns
            ):
                if isinstance(rec, Detections):
                    self.waiting[(rec.robot, rec.t)] = came
                yield rec
        yield from self.decoder.finish()
        self._publish()

    def _next(self) -> tuple[Received, float] | None:
        with self.ready:
            if not self.queue and not self.stopping.is_set():
                due = self.last_publication + self.gap - time.perf_counter()
                self.ready.wait(max(due, 0.0) if self.unpublished else 0.2)
            if not self.queue:
                return None
            self.stats.taken += 1
            item = self.queue.popleft()
            self.frames_queued -= item[0].msgtype in DROPPABLE
            return item

    def _announce(self, sample: Received) -> None:
        """A topic taken through a pattern gets its subscriber's liveliness token."""
        if sample.topic not in self.announced:
            self.announced.add(sample.topic)
            self.node.subscribe_token(sample.topic, sample.msgtype)

    def _mapped(self, frame: Detections) -> None:
        came = self.waiting.pop((frame.robot, frame.t), None)
        self.stats.frames_mapped += 1
        if came is not None:
            self.unpublished.append(came)

    # ----------------------------------------------------------------- output

    def _publish_if_due(self) -> None:
        if self.unpublished and time.perf_counter() >= self.last_publication + self.gap:
            self._publish()

    def _publish(self) -> None:
        """The map, paths and interest grid as they are now, then the status."""
        if self.stats.frames_mapped == 0:
            return
        start = time.perf_counter()
        snapshot = self.world.snapshot()
        t = float(max((tr.t[-1] for tr in snapshot.trajectories.values() if len(tr.t)), default=0))
        frame, labels = self.options.map_frame, self.options.marker_labels
        for topic, msgtype, data in map_messages(snapshot, self.make, t, frame, labels):
            self.node.publisher(topic, msgtype, block=False).put(data)
        done = time.perf_counter()
        self.last_publication = done
        self.gap = max(self.period, PUBLISHING_SHARE * (done - start))
        self.stats.latencies_s.extend(done - came for came in self.unpublished)
        self.unpublished.clear()
        self.stats.publications += 1
        self._status()

    def _status(self) -> None:
        """The node's counts as JSON on the status topic (what a replay paces itself by)."""
        text = json.dumps({**self.stats.as_dict(), "queue_size": self.live.queue_size})
        msg = self.make.T[STRING](data=text)
        self.node.publisher(STATUS_TOPIC, STRING, block=False).put(self.make.serialize(msg, STRING))
        self.last_status = time.perf_counter()


def run_live(
    config: AgrislamConfig,
    folder: RunFolder,
    listen: str | None = None,
    connect: str | None = None,
    on_start: Callable[[LiveMapper], None] | None = None,
    bag: BagSourceConfig | None = None,
) -> tuple[RunResult, LiveStats]:
    """A live run: the node opened, every sample recorded into the folder's live.mcap,
    the map made until `LiveMapper.stop`, the outputs written; `on_start` gets the mapper
    once it listens (to stop it from a signal handler or a thread)."""
    live = config.live
    node = LiveNode.open(
        MessageFactory("humble").store,
        listen,
        connect,
        name=config.advanced.live.node_name,
        domain=live.domain_id,
        scheme=live.namespaces,
    )
    recording = LiveRecording(folder.path / RECORDING, node.store)
    try:
        mapper = LiveMapper(node, config, recording, bag)
        mapper.subscribe()
        if on_start is not None:
            on_start(mapper)
        result = mapper.run(folder)
        return result, mapper.stats
    finally:
        recording.close()
        node.close()
