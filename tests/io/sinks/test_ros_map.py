"""The map as MCAP for ROS tools (MarkerArray + Path) and for Foxglove (SceneUpdate), each
read back with an independent reader."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.colors import to_rgba
from rosbags.highlevel import AnyReader

from agrislam.geometry.se2 import yaw_from_quaternion
from agrislam.io.sinks.ros_map import write_map_mcap
from agrislam.io.sinks.scene import covariance_ellipses, plant_style
from agrislam.snapshot import MapSnapshot

COLOURS = ["blue", "cyan", "green", "orange", "pink", "red", "yellow"]  # conftest's schema


def read_ros(path: Path) -> dict[str, Any]:
    """The last message of each topic (the plants' topic: its one MarkerArray)."""
    with AnyReader([path]) as reader:
        return {
            conn.topic: reader.deserialize(raw, conn.msgtype) for conn, _, raw in reader.messages()
        }


def by_ns(markers: list[Any], ns: str) -> list[Any]:
    return [m for m in markers if m.ns == ns]


def test_covariance_ellipse_by_hand() -> None:
    a = np.deg2rad(30.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    cov = R @ np.diag([0.04, 0.01]) @ R.T
    axes, heading = covariance_ellipses(cov[None])
    np.testing.assert_allclose(axes, [[0.8, 0.4]])  # 2 x 2 sigma: 2 * 2 * (0.2, 0.1)
    assert np.mod(heading[0], np.pi) == pytest.approx(a)


def test_marker_array_and_paths(tmp_path: Path, sample_snapshot: MapSnapshot) -> None:
    snap = sample_snapshot
    path = write_map_mcap(snap, tmp_path / "map.mcap", "colour")
    msgs = read_ros(path)
    assert set(msgs) == {
        "/agrislam/plants",
        "/agrislam/trajectory/spot",
        "/agrislam/trajectory/husky",
        "/agrislam/dead_reckoning/spot",
        "/agrislam/dead_reckoning/husky",
    }
    markers = msgs["/agrislam/plants"].markers
    assert markers[0].action == 3  # DELETEALL first: the file replaces an older map
    plants = by_ns(markers, "plants")
    objects = snap.objects
    assert [m.id for m in plants] == list(objects.ids)
    belief = objects.discrete["colour"]
    for i in (0, 7, 29):
        m = plants[i]
        assert m.header.frame_id == "map" and m.type == 2
        np.testing.assert_allclose([m.pose.position.x, m.pose.position.y], objects.xy[i])
        top = int(np.argmax(belief[i]))
        p = belief[i, top]
        sure = (p - 1 / 7) / (1 - 1 / 7)  # 0 for uniform, 1 for certain
        r, g, b, _ = to_rgba(COLOURS[top])
        np.testing.assert_allclose(
            [m.color.r, m.color.g, m.color.b, m.color.a], [r, g, b, 0.15 + 0.85 * sure]
        )
        assert m.scale.x == pytest.approx(0.15 * (0.5 + 0.5 * sure))
    ellipses = by_ns(markers, "uncertainty")
    axes, _ = covariance_ellipses(objects.cov)
    np.testing.assert_allclose([[e.scale.x, e.scale.y] for e in ellipses], axes)
    labels = by_ns(markers, "labels")
    assert labels[0].text.startswith(f"{objects.ids[0]} colour: ")
    rows = by_ns(markers, "rows")
    assert [(r.points[0].y, r.points[1].y) for r in rows] == [(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)]
    spot = msgs["/agrislam/trajectory/spot"]
    traj = snap.trajectories["spot"].poses
    assert len(spot.poses) == len(traj)
    last = spot.poses[-1].pose
    np.testing.assert_allclose([last.position.x, last.position.y], traj[-1, :2])
    q = last.orientation
    assert yaw_from_quaternion((q.x, q.y, q.z, q.w)) == pytest.approx(traj[-1, 2])
    drift = msgs["/agrislam/dead_reckoning/husky"].poses[-1].pose.position
    np.testing.assert_allclose([drift.x, drift.y], snap.dead_reckoning["husky"].poses[-1, :2])


def test_messages_written_item_by_item_are_the_whole_messages(
    tmp_path: Path, sample_snapshot: MapSnapshot
) -> None:
    """The MarkerArray and Paths are serialised marker by marker and pose by pose (no
    100,000 marker objects at once): byte for byte the whole message's serialisation."""
    from agrislam.io.ros.messages import MARKER_ARRAY, PATH, MessageFactory
    from agrislam.io.sinks.ros_map import plant_markers, snapshot_time, trajectory_path

    snap = sample_snapshot
    path = write_map_mcap(snap, tmp_path / "map.mcap", "colour")
    make = MessageFactory("humble")
    t = snapshot_time(snap)
    whole = {
        "/agrislam/plants": make.serialize(plant_markers(snap, make, "colour", t), MARKER_ARRAY)
    }
    for kind, trajectories in (
        ("trajectory", snap.trajectories),
        ("dead_reckoning", snap.dead_reckoning),
    ):
        for robot, trajectory in trajectories.items():
            whole[f"/agrislam/{kind}/{robot}"] = make.serialize(
                trajectory_path(trajectory, make), PATH
            )
    with AnyReader([path]) as reader:
        written = {conn.topic: bytes(raw) for conn, _, raw in reader.messages()}
    assert written == whole
    with pytest.raises(ValueError, match="2 visualization_msgs/msg/Marker items, 3 announced"):
        markers = plant_markers(snap, make).markers[:2]
        make.serialize_streamed(
            make.T[MARKER_ARRAY](markers=[]),
            MARKER_ARRAY,
            markers,
            3,
            "visualization_msgs/msg/Marker",
        )


def test_a_large_map_goes_out_in_several_marker_arrays(
    tmp_path: Path, sample_snapshot: MapSnapshot
) -> None:
    """Markers split over MarkerArrays of at most `markers_per_message`, in order, at one
    stamp: together the one MarkerArray a small map gets; only the first clears."""
    one = tmp_path / "one.mcap"
    split = tmp_path / "split.mcap"
    write_map_mcap(sample_snapshot, one, "colour")
    write_map_mcap(sample_snapshot, split, "colour", markers_per_message=7)
    with AnyReader([split]) as reader:
        parts = [
            (stamp, reader.deserialize(raw, conn.msgtype).markers)
            for conn, stamp, raw in reader.messages()
            if conn.topic == "/agrislam/plants"
        ]
    whole = read_ros(one)["/agrislam/plants"].markers
    assert len(parts) == -(-len(whole) // 7) > 1
    assert {stamp for stamp, _ in parts} == {parts[0][0]}
    assert all(len(markers) == 7 for _, markers in parts[:-1])
    markers = [m for _, part in parts for m in part]
    assert [(m.ns, m.id, m.action) for m in markers] == [(m.ns, m.id, m.action) for m in whole]
    assert [m.action for m in markers].count(3) == 1


def test_mcap_is_a_plain_ros2_recording(tmp_path: Path, sample_snapshot: MapSnapshot) -> None:
    from mcap.reader import make_reader

    path = write_map_mcap(sample_snapshot, tmp_path / "map.mcap", labels=False)
    with path.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        kinds = {
            (c.topic, c.message_encoding, summary.schemas[c.schema_id].encoding)
            for c in summary.channels.values()
        }
    assert ("/agrislam/plants", "cdr", "ros2msg") in kinds
    markers = read_ros(path)["/agrislam/plants"].markers
    assert not by_ns(markers, "labels")
    with pytest.raises(FileExistsError):
        write_map_mcap(sample_snapshot, path)
    write_map_mcap(sample_snapshot, path, "length", overwrite=True)
    assert (
        by_ns(read_ros(path)["/agrislam/plants"].markers, "labels")[0].text.split()[1] == "length:"
    )


def test_continuous_and_no_attribute(snapshot_factory: Callable[..., MapSnapshot]) -> None:
    snap = snapshot_factory()
    style = plant_style(snap, "length")
    mean, var = snap.objects.continuous["length"]
    # opacity from how far the std has shrunk below the prior's (uniform on [0, 0.6])
    sure = np.clip(1 - np.sqrt(var / (0.6**2 / 12)), 0, 1)
    np.testing.assert_allclose(style.rgba[:, 3], 0.15 + 0.85 * sure)
    assert style.labels[0] == f"length: {mean[0]:.3g} ± {np.sqrt(var[0]):.2g}"
    bare = plant_style(snapshot_factory(schema=False))
    assert bare.attribute is None and bare.labels[0].startswith("h ")
    with pytest.raises(ValueError, match="'health' is not in the map"):
        plant_style(snap, "health")


# ---------------------------------------------------------------------------- Foxglove


def foxglove_messages(path: Path) -> list[tuple[str, int, str, Any]]:
    """(topic, log time, schema name, message) of every message, decoded with the protobuf
    schema stored in the MCAP itself."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader

    out = []
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
            pool = descriptor_pool.DescriptorPool()
            for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                pool.Add(fd)
            cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
            out.append((channel.topic, message.log_time, schema.name, cls.FromString(message.data)))
    return out


def read_foxglove(path: Path) -> dict[str, Any]:
    """The last message of each topic: (schema name, message)."""
    return {topic: (name, msg) for topic, _, name, msg in foxglove_messages(path)}


def test_foxglove_scene(tmp_path: Path, sample_snapshot: MapSnapshot) -> None:
    pytest.importorskip("foxglove")
    from agrislam.io.sinks.foxglove import write_foxglove_mcap

    snap = sample_snapshot
    path = write_foxglove_mcap(snap, tmp_path / "scene.mcap", "size")
    msgs = read_foxglove(path)
    assert {topic: name for topic, (name, _) in msgs.items()} == {
        "/agrislam/plants": "foxglove.SceneUpdate",
        "/agrislam/rows": "foxglove.SceneUpdate",
        "/agrislam/interest": "foxglove.Grid",
        "/agrislam/trajectory/spot": "foxglove.PosesInFrame",
        "/agrislam/trajectory/husky": "foxglove.PosesInFrame",
        "/agrislam/dead_reckoning/spot": "foxglove.PosesInFrame",
        "/agrislam/dead_reckoning/husky": "foxglove.PosesInFrame",
    }
    entities = msgs["/agrislam/plants"][1].entities
    objects = snap.objects
    assert [e.id for e in entities] == [str(i) for i in objects.ids]
    style = plant_style(snap, "size")
    for i in (0, 13):
        e = entities[i]
        sphere = e.spheres[0]
        np.testing.assert_allclose([sphere.pose.position.x, sphere.pose.position.y], objects.xy[i])
        c = sphere.color
        np.testing.assert_allclose([c.r, c.g, c.b, c.a], style.rgba[i])
        meta = {kv.key: kv.value for kv in e.metadata}
        size = objects.discrete["size"][i]
        assert meta["size"] == f"small {size[0]:.2f}, medium {size[1]:.2f}, big {size[2]:.2f}"
        assert meta["n_meas"] == str(objects.n_meas[i]) and "length" in meta and "colour" in meta
    grid = msgs["/agrislam/interest"][1]
    surface = snap.interest_surface
    assert grid.column_count == surface.values.shape[1]
    values = np.frombuffer(grid.data, dtype="<f4").reshape(surface.values.shape)
    np.testing.assert_allclose(values, surface.values, rtol=1e-6)
    assert len(msgs["/agrislam/rows"][1].entities) == 3
    poses = msgs["/agrislam/trajectory/husky"][1].poses
    np.testing.assert_allclose(
        [poses[-1].position.x, poses[-1].position.y], snap.trajectories["husky"].poses[-1, :2]
    )
    with pytest.raises(FileExistsError):
        write_foxglove_mcap(snap, path)  # no silent overwrite
    write_foxglove_mcap(snap, path, overwrite=True)


def test_foxglove_plants_of_a_large_map_go_out_in_several_scene_updates(
    tmp_path: Path, sample_snapshot: MapSnapshot
) -> None:
    pytest.importorskip("foxglove")
    from agrislam.io.sinks.foxglove import write_foxglove_mcap

    path = write_foxglove_mcap(sample_snapshot, tmp_path / "s.mcap", entities_per_message=7)
    parts = [
        (t, m.entities) for topic, t, _, m in foxglove_messages(path) if topic == "/agrislam/plants"
    ]
    ids = [str(i) for i in sample_snapshot.objects.ids]
    assert len(parts) == -(-len(ids) // 7) > 1 and len({t for t, _ in parts}) == 1
    assert [e.id for _, entities in parts for e in entities] == ids


def test_foxglove_plants_and_trajectories_encoded_item_by_item(
    tmp_path: Path, sample_snapshot: MapSnapshot
) -> None:
    """The plants' SceneUpdate is encoded entity by entity and a trajectory pose by pose
    (no 100,000 of them held at once): byte for byte the SDK's encoding of the whole
    message, on a channel with the schema the SDK's own channel gives it."""
    pytest.importorskip("foxglove")
    from foxglove import messages as m
    from mcap.reader import make_reader

    from agrislam.io.sinks.foxglove import _pose, _timestamp, plant_entities, write_foxglove_mcap

    snap = sample_snapshot
    path = write_foxglove_mcap(snap, tmp_path / "scene.mcap", "size", stamp=12.5)
    whole = m.SceneUpdate(entities=list(plant_entities(snap, "size", 0.15, 12.5))).encode()
    with path.open("rb") as f:
        found = {
            channel.topic: (schema, channel, message)
            for schema, channel, message in make_reader(f).iter_messages()
        }
    schema, channel, message = found["/agrislam/plants"]
    _, rows_channel, _ = found["/agrislam/rows"]  # written by the SDK's SceneUpdateChannel
    assert message.data == whole and message.log_time == 12_500_000_000
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove.SceneUpdate",
        "protobuf",
        "protobuf",
    )
    assert schema.data == m.SceneUpdate.get_schema().data
    assert channel.schema_id == rows_channel.schema_id and channel.metadata == rows_channel.metadata
    schema, _, message = found["/agrislam/dead_reckoning/husky"]
    poses = [_pose(m, p[0], p[1], 0.0, p[2]) for p in snap.dead_reckoning["husky"].poses]
    whole = m.PosesInFrame(timestamp=_timestamp(m, 12.5), frame_id="map", poses=poses)
    assert message.data == whole.encode() and len(poses) > 1
    assert schema.data == m.PosesInFrame.get_schema().data
    schema, _, message = found["/agrislam/interest"]
    grid = read_foxglove(path)["/agrislam/interest"][1]  # decoded by protobuf, encoded again
    assert message.data == grid.SerializeToString() and len(grid.data) > 2**7  # a 2-byte length
    assert schema.data == m.Grid.get_schema().data


def test_protobuf_varint() -> None:
    pytest.importorskip("foxglove")
    from agrislam.io.sinks.foxglove import _varint

    assert [_varint(n) for n in (0, 1, 127, 128, 300, 2**14)] == [
        b"\x00",
        b"\x01",
        b"\x7f",
        b"\x80\x01",
        b"\xac\x02",
        b"\x80\x80\x01",
    ]
