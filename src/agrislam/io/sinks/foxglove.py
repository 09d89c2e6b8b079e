"""The map for Foxglove: an MCAP file of Foxglove's own schemas (foxglove-sdk, an optional
extra), which its 3D panel shows without any ROS message definitions.

Topics (frame ``map``): ``/agrislam/plants`` (SceneUpdate: an entity per object, id =
object id, a sphere coloured as in `scene.plant_style`, its 2-sigma position ellipse, every
attribute's distribution as entity metadata), ``/agrislam/rows`` (SceneUpdate, the row
lines), ``/agrislam/interest`` (Grid of the interest surface, sec. 2.7, field ``interest``),
``/agrislam/trajectory/<robot>`` and ``/agrislam/dead_reckoning/<robot>`` (PosesInFrame)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.geometry.se2 import quaternion_from_yaw
from agrislam.io.sinks.readouts import discrete_columns
from agrislam.io.sinks.scene import covariance_ellipses, plant_style, row_segments, snapshot_time
from agrislam.snapshot import MapSnapshot, Trajectory

FRAME = "map"
ENTITIES_PER_MESSAGE = 10_000  # plants a SceneUpdate holds
GRID_DATA_FIELD = 9  # foxglove.Grid's `data`, its last field (foxglove/Grid.proto)


def _sdk() -> tuple[Any, Any, Any]:
    try:
        import foxglove
        from foxglove import channels, messages
    except ImportError as err:  # optional extra
        raise ImportError(
            "the Foxglove sink needs foxglove-sdk: pip install 'agrislam[foxglove]'"
        ) from err
    return foxglove, channels, messages


def _timestamp(m: Any, t: float) -> Any:
    ns = round(t * 1e9)
    return m.Timestamp(ns // 10**9, ns % 10**9)


def _pose(m: Any, x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> Any:
    qx, qy, qz, qw = quaternion_from_yaw(yaw)
    return m.Pose(
        position=m.Vector3(x=float(x), y=float(y), z=float(z)),
        orientation=m.Quaternion(x=qx, y=qy, z=qz, w=qw),
    )


def _color(m: Any, rgba: Any) -> Any:
    r, g, b, a = (float(v) for v in rgba)
    return m.Color(r=r, g=g, b=b, a=a)


def entity_metadata(snapshot: MapSnapshot) -> Iterator[list[tuple[str, str]]]:
    """Per object, one by one: its measurement count, interest and every attribute's
    distribution ("size" -> "small 0.10, medium 0.20, big 0.70") or mean and std."""
    objects = snapshot.objects
    discrete = list(discrete_columns(snapshot).items())
    continuous = list(objects.continuous.items())
    n_meas, interest = np.asarray(objects.n_meas), np.asarray(objects.interest)
    for i in range(len(objects)):
        out = [("n_meas", str(int(n_meas[i]))), ("interest", f"{float(interest[i]):.3f}")]
        for name, (values, belief) in discrete:
            out.append(
                (name, ", ".join(f"{v} {p:.2f}" for v, p in zip(values, belief[i], strict=True)))
            )
        for name, (mean, var) in continuous:
            out.append((name, f"{float(mean[i]):.4g} ± {float(np.sqrt(var[i])):.2g}"))
        yield out


def plant_entities(
    snapshot: MapSnapshot, attribute: str | None, diameter: float, t: float
) -> Iterator[Any]:
    """The plants' SceneEntities, one by one (see the module docstring)."""
    m = _sdk()[2]
    ts = _timestamp(m, t)
    objects = snapshot.objects
    style = plant_style(snapshot, attribute)
    xy = np.asarray(objects.xy, dtype=float).reshape(-1, 2)
    size = style.sizes(diameter)
    axes, heading = covariance_ellipses(objects.cov) if len(objects) else (np.empty((0, 2)), [])
    metadata = entity_metadata(snapshot)
    for i, ident in enumerate(np.asarray(objects.ids)):
        x, y, s = xy[i, 0], xy[i, 1], float(size[i])
        a, b = (max(float(v), 0.01) for v in axes[i])
        yield m.SceneEntity(
            timestamp=ts,
            frame_id=FRAME,
            id=str(int(ident)),
            metadata=[m.KeyValuePair(key=key, value=v) for key, v in next(metadata)],
            spheres=[
                m.SpherePrimitive(
                    pose=_pose(m, x, y, 0.5 * s),
                    size=m.Vector3(x=s, y=s, z=s),
                    color=_color(m, style.rgba[i]),
                )
            ],
            cylinders=[
                m.CylinderPrimitive(
                    pose=_pose(m, x, y, 0.0, float(heading[i])),
                    size=m.Vector3(x=a, y=b, z=0.005),
                    bottom_scale=1.0,
                    top_scale=1.0,
                    color=m.Color(r=0.5, g=0.5, b=0.5, a=0.35),
                )
            ],
            texts=[
                m.TextPrimitive(
                    pose=_pose(m, x, y, s + 0.08),
                    billboard=True,
                    font_size=12.0,
                    scale_invariant=True,
                    color=m.Color(r=1.0, g=1.0, b=1.0, a=1.0),
                    text=f"{int(ident)} {style.labels[i]}",
                )
            ],
        )


def streamed_bytes(head: Any, alone: Callable[[Any], Any], items: Iterable[Any]) -> bytearray:
    """The protobuf of message `head` with `items` in its (last) repeated field, encoded
    item by item (`alone(item)`: a message holding only that item): a repeated field's
    encoding is its items' encodings one after the other, so this is byte for byte the
    whole message's `encode()` without every item held at once."""
    out = bytearray(head.encode())
    for item in items:
        out += alone(item).encode()
    return out


def scene_update_bytes(entities: Iterable[Any]) -> bytearray:
    """The protobuf of a SceneUpdate of `entities`, encoded entity by entity."""
    m = _sdk()[2]
    return streamed_bytes(m.SceneUpdate(), lambda e: m.SceneUpdate(entities=[e]), entities)


def poses_in_frame_bytes(trajectory: Trajectory, ts: Any) -> bytearray:
    """The protobuf of a trajectory's PosesInFrame, encoded pose by pose: a whole field's
    drive is too many poses to hold as messages at once."""
    m = _sdk()[2]
    poses = (
        _pose(m, p[0], p[1], 0.0, float(p[2])) for p in np.asarray(trajectory.poses, dtype=float)
    )
    head = m.PosesInFrame(timestamp=ts, frame_id=FRAME, poses=[])
    return streamed_bytes(head, lambda p: m.PosesInFrame(poses=[p]), poses)


def _channel(foxglove: Any, topic: str, message: Any, context: Any) -> Any:
    """A channel of `message`'s schema that takes the encoded bytes."""
    schema = message.get_schema()
    return foxglove.Channel(topic, message_encoding=schema.encoding, schema=schema, context=context)


def write_foxglove_mcap(
    snapshot: MapSnapshot,
    path: str | Path,
    attribute: str | None = None,
    *,
    diameter: float = 0.15,
    stamp: float | None = None,
    overwrite: bool = False,
    entities_per_message: int = ENTITIES_PER_MESSAGE,
) -> Path:
    """Write the map as an MCAP file of Foxglove schemas (see the module docstring). The
    plants go out `entities_per_message` to a SceneUpdate, at one time, so that a whole field's
    entities are never held at once."""
    foxglove, channels, m = _sdk()
    path = Path(path)
    t = snapshot_time(snapshot) if stamp is None else stamp
    ts, log_time = _timestamp(m, t), round(t * 1e9)
    plants = plant_entities(snapshot, attribute, diameter, t)
    rows = [
        m.SceneEntity(
            timestamp=ts,
            frame_id=FRAME,
            id=f"row{r}",
            lines=[
                m.LinePrimitive(
                    type=m.LinePrimitiveLineType.LineList,
                    pose=_pose(m, 0.0, 0.0),
                    thickness=0.02,
                    points=[m.Point3(x=float(p[0]), y=float(p[1]), z=0.0) for p in seg],
                    color=m.Color(r=0.55, g=0.4, b=0.25, a=0.8),
                )
            ],
        )
        for r, seg in enumerate(row_segments(snapshot))
    ]
    context = foxglove.Context()
    with foxglove.open_mcap(path, allow_overwrite=overwrite, context=context):
        channel = _channel(foxglove, "/agrislam/plants", m.SceneUpdate, context)
        for _ in range(0, max(len(snapshot.objects), 1), entities_per_message):  # empty: one
            part = scene_update_bytes(islice(plants, entities_per_message))
            channel.log(bytes(part), log_time=log_time)
        if rows:
            rows_channel = channels.SceneUpdateChannel("/agrislam/rows", context=context)
            rows_channel.log(m.SceneUpdate(entities=rows), log_time=log_time)
        if snapshot.interest_surface is not None:
            grid = _channel(foxglove, "/agrislam/interest", m.Grid, context)
            grid.log(interest_grid_bytes(snapshot, ts), log_time=log_time)
        for kind, trajectories in (
            ("trajectory", snapshot.trajectories),
            ("dead_reckoning", snapshot.dead_reckoning),
        ):
            for robot, tr in trajectories.items():
                channel = _channel(foxglove, f"/agrislam/{kind}/{robot}", m.PosesInFrame, context)
                channel.log(bytes(poses_in_frame_bytes(tr, ts)), log_time=log_time)
    return path


def interest_grid_bytes(snapshot: MapSnapshot, ts: Any) -> bytes:
    """The protobuf of the interest surface as a float32 Grid, row-major from the (x0, y0)
    corner. The cells (millions on a whole field) are copied once, into the message: they
    are `data`, the Grid's last field, appended to the encoding of the rest."""
    m = _sdk()[2]
    surface = snapshot.interest_surface
    assert surface is not None
    values = np.ascontiguousarray(surface.values, dtype="<f4")
    nx = values.shape[1]
    head = m.Grid(
        timestamp=ts,
        frame_id=FRAME,
        pose=_pose(m, surface.x0, surface.y0),
        column_count=nx,
        cell_size=m.Vector2(x=surface.resolution, y=surface.resolution),
        row_stride=4 * nx,
        cell_stride=4,
        fields=[
            m.PackedElementField(
                name="interest", offset=0, type=m.PackedElementFieldNumericType.Float32
            )
        ],
    )
    data = memoryview(values).cast("B")
    key = _varint(GRID_DATA_FIELD << 3 | 2)  # a length-delimited field
    return b"".join((head.encode(), key, _varint(len(data)), data))


def _varint(n: int) -> bytes:
    """Protobuf's base-128 varint of a non-negative int."""
    out = bytearray()
    while True:
        low, n = n & 0x7F, n >> 7
        out.append(low | (0x80 if n else 0))
        if not n:
            return bytes(out)
