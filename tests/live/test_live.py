"""agrislam live and replay over real Zenoh sessions on loopback: a replayed survey is mapped
live into the map `agrislam run` makes of the live recording and of the survey itself; a
starved mapper drops frames, counts them and keeps its queue bounded while the recording
keeps everything."""

import time

import numpy as np

from agrislam.config import AgrislamConfig
from agrislam.io.ros.messages import DETECTION3D_ARRAY, MARKER_ARRAY, PATH, typestore
from agrislam.io.sources import open_source
from agrislam.live.map_topics import INTEREST_TOPIC, OCCUPANCY_GRID
from agrislam.live.mapper import ESSENTIAL_FACTOR, RECORDING, _LiveWorld
from agrislam.live.node import LiveNode
from agrislam.live.replay import recorded_messages, replay
from agrislam.run.pipeline import run_survey
from agrislam.world import WorldModel
from live.conftest import live_mapper, same_map

SURVEY = "sim:?plants=40&seed=3"


def _offline(source, config):
    return run_survey(open_source(source, config), WorldModel(config)).snapshot


def test_a_replayed_survey_is_mapped_live_as_offline_and_its_recording_too(tmp_path, endpoint):
    config = AgrislamConfig()
    heard: dict[str, list] = {PATH: [], MARKER_ARRAY: [], OCCUPANCY_GRID: []}
    with live_mapper(config, endpoint, tmp_path) as running:
        robot = LiveNode.open(typestore(), connect=endpoint, name="robot")
        for topic, msgtype in (
            ("/agrislam/trajectory/r1", PATH),
            ("/agrislam/plants", MARKER_ARRAY),
            (INTEREST_TOPIC, OCCUPANCY_GRID),
        ):
            robot.subscribe(msgtype, lambda s, m=msgtype: heard[m].append(s), topic)
        done = replay(robot, recorded_messages(SURVEY, config), rate=0.0, wait_s=10)
        time.sleep(0.3)  # the last map publication
        robot.close()
    live = running.run
    assert live.error is None and live.n_frames > 100
    stats = running.mapper.stats
    assert stats.received == done.published == stats.taken and not stats.dropped
    assert stats.frames_mapped == live.n_frames
    # the live map is that of its own recording, and that of the survey replayed
    recorded = _offline(tmp_path / RECORDING, config)
    assert same_map(live.snapshot, recorded)
    assert same_map(live.snapshot, _offline(SURVEY, config))
    assert len(live.snapshot.objects.ids) > 20
    assert (tmp_path / "objects.csv").exists() and (tmp_path / "map.mcap").exists()
    # the map topics came with rmw_zenoh attachments and decode as their types
    store = typestore()
    path = store.deserialize_cdr(heard[PATH][-1].payload, PATH)
    assert len(path.poses) > 100
    markers = store.deserialize_cdr(heard[MARKER_ARRAY][-1].payload, MARKER_ARRAY)
    assert {m.ns for m in markers.markers} >= {"plants", "uncertainty"}
    grid = store.deserialize_cdr(heard[OCCUPANCY_GRID][-1].payload, OCCUPANCY_GRID)
    assert grid.info.width * grid.info.height == len(grid.data) > 0
    assert grid.data.min() >= 0 and grid.data.max() <= 100
    seqs = [s.attachment.sequence_number for s in heard[PATH]]
    assert seqs == list(range(1, len(seqs) + 1))
    assert len(stats.latencies_s) == live.n_frames


def test_a_starved_mapper_drops_frames_counts_them_and_keeps_its_queue_bounded(tmp_path, endpoint):
    config = AgrislamConfig.model_validate({"live": {"queue_size": 16}})

    class Slow(_LiveWorld):
        def step(self, frame):
            time.sleep(0.03)
            return super().step(frame)

    with live_mapper(
        config, endpoint, tmp_path, world=lambda m: Slow(config, m._mapped)
    ) as running:
        robot = LiveNode.open(typestore(), connect=endpoint, name="robot")
        messages = list(recorded_messages(SURVEY, config))
        done = replay(robot, iter(messages), rate=200.0, wait_s=10)
        robot.close()
    stats = running.mapper.stats
    assert sum(stats.dropped.values()) > 20
    assert all("detections" in topic for topic in stats.dropped)  # odometry kept
    assert stats.most_queued <= 16 * ESSENTIAL_FACTOR
    assert stats.received == done.published == stats.taken + sum(stats.dropped.values())
    assert running.run.error is None
    frames = sum(msgtype == DETECTION3D_ARRAY for _, msgtype, _, _ in messages)
    assert running.run.n_frames + sum(stats.dropped.values()) == frames
    # nothing lost: the recording has every message, and maps them all offline
    recorded = _offline(tmp_path / RECORDING, config)
    assert len(recorded.objects.ids) >= len(running.run.snapshot.objects.ids)
    assert np.isfinite(recorded.objects.xy).all()
