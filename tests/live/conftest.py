"""A live node on loopback for the tests: a free port, and a mapper running in a thread
until the test stops it."""

import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agrislam.config import AgrislamConfig
from agrislam.io.ros.messages import typestore
from agrislam.io.sinks.run_folder import RunFolder
from agrislam.live.mapper import RECORDING, LiveMapper
from agrislam.live.node import LiveNode
from agrislam.live.recording import LiveRecording
from agrislam.run.pipeline import RunError, RunResult
from agrislam.snapshot import MapSnapshot


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@dataclass
class Running:
    mapper: LiveMapper
    result: dict[str, Any] = field(default_factory=dict)

    @property
    def run(self) -> RunResult:
        return self.result["run"]


@contextmanager
def live_mapper(
    config: AgrislamConfig, endpoint: str, folder: Path, world: Any = None
) -> Iterator[Running]:
    """A mapper listening on `endpoint`, recording into `folder`, mapping in a thread; its
    run's result once the block ends (it is stopped then and drained)."""
    out = RunFolder(folder).open()
    node = LiveNode.open(typestore(), listen=endpoint, scheme=config.live.namespaces)
    recording = LiveRecording(folder / RECORDING, node.store)
    mapper = LiveMapper(node, config, recording)
    if world is not None:
        mapper.world = world(mapper)
    mapper.subscribe()
    running = Running(mapper)

    def run() -> None:
        try:
            running.result["run"] = mapper.run(out)
        except RunError as err:
            running.result["run"] = err.result

    thread = threading.Thread(target=run)
    thread.start()
    try:
        yield running
    finally:
        mapper.stop()
        thread.join(120)
        recording.close()
        node.close()
        out.close()


def same_map(a: MapSnapshot, b: MapSnapshot, tol: float = 1e-6) -> bool:
    """Same object ids at the same positions (within `tol` m)."""
    ia, ib = np.asarray(a.objects.ids), np.asarray(b.objects.ids)
    if ia.shape != ib.shape or not np.array_equal(ia, ib):
        return False
    return bool(np.abs(np.asarray(a.objects.xy) - np.asarray(b.objects.xy)).max(initial=0) <= tol)
