"""Every message a live run receives, written to an MCAP file (ROS 2 profile, CDR) as it
arrives, with its time of receipt: `agrislam run` reads it like any bag. Chunks go to disk
as they fill, so a run killed outright leaves a file whose whole chunks the bag source
salvages."""

from __future__ import annotations

import threading
from pathlib import Path

from mcap.writer import CompressionType, Writer
from rosbags.typesys.store import Typestore

CHUNK_BYTES = 256 * 1024


class LiveRecording:
    """The recording, open from construction to `close`; safe to write from any thread."""

    def __init__(self, path: str | Path, store: Typestore) -> None:
        self.path = Path(path)
        self.store = store
        self.file = self.path.open("xb")
        self.writer = Writer(self.file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="agrislam live")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.count = 0
        self.lock = threading.Lock()

    def write(self, topic: str, msgtype: str, payload: bytes, received_ns: int) -> None:
        with self.lock:
            channel = self.channels.get(topic)
            if channel is None:
                channel = self._channel(topic, msgtype)
            self.writer.add_message(channel, received_ns, payload, received_ns, self.count)
            self.count += 1

    def _channel(self, topic: str, msgtype: str) -> int:
        schema = self.schemas.get(msgtype)
        if schema is None:
            text, _ = self.store.generate_msgdef(msgtype, ros_version=2)
            schema = self.writer.register_schema(msgtype, "ros2msg", text.encode())
            self.schemas[msgtype] = schema
        channel = self.writer.register_channel(topic, "cdr", schema, {"offered_qos_profiles": ""})
        self.channels[topic] = channel
        return channel

    def close(self) -> None:
        with self.lock:
            if self.file.closed:
                return
            self.writer.finish()
            self.file.close()
