"""agrislam live over Zenoh on loopback, against the targets of the live mode.

A survey (default: the simulator's default field; `--robots 2`: two robots) is replayed to a
live node in this process at each `--rates` (times real time; frames come every 0.5 s of
survey time, so 5x is 10 Hz) and at 0 (as fast as the node takes it). Per rate it prints
the frames mapped and dropped, the detection-to-map latency (receipt of a frame to the
publication of the map that contains it) median and p95 (target p95 < 100 ms at 10 Hz),
whether the live map equals the offline map of its recording and of the survey (objects and
positions within 1e-6 m), and the process's peak memory growth.

    python benchmarks/bench_live.py [--survey SIM_URI] [--robots 2] [--rates 5 20 50]
"""

from __future__ import annotations

import argparse
import resource
import socket
import tempfile
import threading
from pathlib import Path

import numpy as np

from agrislam.config import AgrislamConfig
from agrislam.io.ros.messages import typestore
from agrislam.io.sinks.run_folder import RunFolder
from agrislam.io.sources import open_source
from agrislam.live.mapper import RECORDING, LiveMapper
from agrislam.live.node import LiveNode
from agrislam.live.recording import LiveRecording
from agrislam.live.replay import recorded_messages, replay
from agrislam.run.pipeline import RunError, run_survey
from agrislam.world import WorldModel


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _same(a, b) -> bool:
    if not np.array_equal(a.objects.ids, b.objects.ids):
        return False
    return bool(np.abs(a.objects.xy - b.objects.xy).max(initial=0.0) <= 1e-6)


def one_rate(survey: str, rate: float, config: AgrislamConfig, offline) -> dict:
    endpoint = _endpoint()
    with tempfile.TemporaryDirectory() as tmp, RunFolder(Path(tmp) / "out") as folder:
        node = LiveNode.open(typestore(), listen=endpoint)
        recording = LiveRecording(folder.path / RECORDING, node.store)
        mapper = LiveMapper(node, config, recording)
        mapper.subscribe()
        out: dict = {}

        def run() -> None:
            try:
                out["run"] = mapper.run(folder)
            except RunError as err:
                out["run"] = err.result
                print(f"the live run stopped: {err}")

        thread = threading.Thread(target=run)
        thread.start()
        robot = LiveNode.open(typestore(), connect=endpoint, name="robot")
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        try:
            done = replay(robot, recorded_messages(survey, config), rate, wait_s=10)
        finally:
            robot.close()
        mapper.stop()
        thread.join()
        recording.close()
        node.close()
        grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
        stats = mapper.stats.as_dict()
        live = out["run"].snapshot
        own = run_survey(open_source(folder.path / RECORDING, config), WorldModel(config))
        return {
            "rate": rate,
            "seconds": done.seconds,
            "frames": out["run"].n_frames,
            "dropped": sum(stats["dropped"].values()),
            "median_ms": 1e3 * (stats["latency_median_s"] or float("nan")),
            "p95_ms": 1e3 * (stats["latency_p95_s"] or float("nan")),
            "most_lag_ms": 1e3 * stats["most_lag_s"],
            "= own": _same(live, own.snapshot),
            "= survey": _same(live, offline),
            "peak_mb+": grown / 1024,
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--survey", default="sim:?seed=1")
    parser.add_argument("--robots", type=int, default=1)
    parser.add_argument("--rates", type=float, nargs="+", default=[5.0, 20.0, 50.0, 0.0])
    args = parser.parse_args()
    survey = args.survey + (f"&robots={args.robots}" if args.robots > 1 else "")
    config = AgrislamConfig()
    offline = run_survey(open_source(survey, config), WorldModel(config)).snapshot
    print(f"survey {survey}: {len(offline.objects.ids)} objects offline")
    for rate in args.rates:
        row = one_rate(survey, rate, config, offline)
        print(
            "  ".join(
                f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
            )
        )


if __name__ == "__main__":
    main()
