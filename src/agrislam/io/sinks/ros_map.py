"""The map for ROS tools: an MCAP file (a ROS 2 recording, opens in Foxglove, RViz via
``ros2 bag play``) with the plants as ``visualization_msgs/MarkerArray`` coloured as in
`scene.plant_style`, and every robot's trajectory as ``nav_msgs/Path``.

Topics (frame ``map``): ``/agrislam/plants`` (namespaces ``plants``: one sphere per
object, id = object id; ``uncertainty``: the 2-sigma position ellipse; ``labels``: text;
``rows``: the fitted row lines), ``/agrislam/trajectory/<robot>`` (optimised) and
``/agrislam/dead_reckoning/<robot>``."""

from __future__ import annotations

from collections.abc import Iterator
from itertools import islice
from pathlib import Path

import numpy as np

from agrislam.geometry.se2 import quaternion_from_yaw
from agrislam.io.ros.messages import (
    MARKER_ARRAY,
    PATH,
    MessageFactory,
    open_ros2_writer,
    seconds_to_ns,
)
from agrislam.io.sinks.scene import covariance_ellipses, plant_style, row_segments, snapshot_time
from agrislam.snapshot import MapSnapshot, Trajectory

PLANTS_TOPIC = "/agrislam/plants"
MARKER = {"SPHERE": 2, "CYLINDER": 3, "LINE_LIST": 5, "TEXT_VIEW_FACING": 9}
ACTION = {"ADD": 0, "DELETEALL": 3}
MARKERS_PER_MESSAGE = 20_000  # a MarkerArray's markers at most: its CDR is held whole


class _MarkerBuilder:
    def __init__(self, make: MessageFactory, t: float, frame: str) -> None:
        self.make, self.t, self.frame = make, t, frame
        self.header = make.header(t, frame)  # shared: every marker has the same one

    def color(self, rgba: list[float] | tuple[float, ...]) -> object:
        r, g, b, a = rgba
        return self.make.T["std_msgs/msg/ColorRGBA"](r=r, g=g, b=b, a=a)

    def marker(
        self,
        ns: str,
        ident: int,
        kind: str,
        xyz: tuple[float, float, float] = (0.0, 0.0, 0.0),
        yaw: float = 0.0,
        scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
        rgba: list[float] | tuple[float, ...] = (1.0, 1.0, 1.0, 1.0),
        text: str = "",
        points: list[tuple[float, float, float]] | None = None,
        action: str = "ADD",
    ) -> object:
        T = self.make.T
        pts = [
            T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z))
            for x, y, z in points or []
        ]
        return T["visualization_msgs/msg/Marker"](
            header=self.header,
            ns=ns,
            id=int(ident),
            type=MARKER[kind],
            action=ACTION[action],
            pose=self.make.pose(xyz, quaternion_from_yaw(yaw)),
            scale=self.make.vector3(scale),
            color=self.color(rgba),
            lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=False,
            points=pts,
            colors=[],
            texture_resource="",
            texture=T["sensor_msgs/msg/CompressedImage"](
                header=self.header, format="", data=np.zeros(0, np.uint8)
            ),
            uv_coordinates=[],
            text=text,
            mesh_resource="",
            mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )


MARKER_MSG = "visualization_msgs/msg/Marker"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"


def plant_markers(
    snapshot: MapSnapshot,
    make: MessageFactory,
    attribute: str | None = None,
    t: float = 0.0,
    frame: str = "map",
    diameter: float = 0.15,
    labels: bool = True,
) -> object:
    """The MarkerArray of the plant map (see the module docstring)."""
    markers = _marker_stream(snapshot, make, attribute, t, frame, diameter, labels)
    return make.T[MARKER_ARRAY](markers=list(markers))


def marker_count(snapshot: MapSnapshot, labels: bool) -> int:
    """How many markers `plant_markers` gives: DELETEALL, 2 or 3 per plant, one per row."""
    return 1 + len(snapshot.objects) * (3 if labels else 2) + len(row_segments(snapshot))


def _marker_stream(
    snapshot: MapSnapshot,
    make: MessageFactory,
    attribute: str | None,
    t: float,
    frame: str,
    diameter: float,
    labels: bool,
) -> Iterator[object]:
    """The markers of `plant_markers` one by one."""
    objects = snapshot.objects
    style = plant_style(snapshot, attribute)
    build = _MarkerBuilder(make, t, frame)
    yield build.marker("", 0, "SPHERE", action="DELETEALL")  # replace an older map
    xy = np.asarray(objects.xy, dtype=float).reshape(-1, 2)
    size = style.sizes(diameter)
    rgba = style.rgba
    axes, heading = covariance_ellipses(objects.cov) if len(objects) else (np.empty((0, 2)), [])
    for i, ident in enumerate(np.asarray(objects.ids).tolist()):
        x, y = xy[i].tolist()
        s = float(size[i])
        yield build.marker(
            "plants", ident, "SPHERE", (x, y, 0.5 * s), 0.0, (s, s, s), rgba[i].tolist()
        )
        a, b = (max(float(v), 0.01) for v in axes[i])
        yield build.marker(
            "uncertainty",
            ident,
            "CYLINDER",
            (x, y, 0.0),
            float(heading[i]),
            (a, b, 0.005),
            (0.5, 0.5, 0.5, 0.35),
        )
        if labels:
            yield build.marker(
                "labels",
                ident,
                "TEXT_VIEW_FACING",
                (x, y, s + 0.08),
                0.0,
                (0.05, 0.05, 0.05),
                (1.0, 1.0, 1.0, 1.0),
                f"{ident} {style.labels[i]}",
            )
    for r, (p0, p1) in enumerate(row_segments(snapshot)):
        yield build.marker(
            "rows",
            r,
            "LINE_LIST",
            scale=(0.02, 0.0, 0.0),
            rgba=(0.55, 0.4, 0.25, 0.8),
            points=[(p0[0], p0[1], 0.0), (p1[0], p1[1], 0.0)],
        )


def trajectory_path(trajectory: Trajectory, make: MessageFactory, frame: str = "map") -> object:
    return make.T[PATH](
        header=_path_header(trajectory, make, frame), poses=list(_poses(trajectory, make, frame))
    )


def _path_header(trajectory: Trajectory, make: MessageFactory, frame: str) -> object:
    return make.header(float(trajectory.t[-1]) if len(trajectory.t) else 0.0, frame)


def _poses(trajectory: Trajectory, make: MessageFactory, frame: str) -> Iterator[object]:
    T = make.T
    poses = np.asarray(trajectory.poses, dtype=float)
    for t, p in zip(trajectory.t, poses, strict=True):
        yield T[POSE_STAMPED](
            header=make.header(float(t), frame),
            pose=make.pose((p[0], p[1], 0.0), quaternion_from_yaw(float(p[2]))),
        )


def write_map_mcap(
    snapshot: MapSnapshot,
    path: str | Path,
    attribute: str | None = None,
    *,
    frame: str = "map",
    stamp: float | None = None,
    diameter: float = 0.15,
    labels: bool = True,
    overwrite: bool = False,
    markers_per_message: int = MARKERS_PER_MESSAGE,
) -> Path:
    """Write the map as a bare MCAP file (ROS 2, CDR): plants as MarkerArrays coloured by
    `attribute` (default: the first discrete one), trajectories as nav_msgs/Path. The markers
    go out `markers_per_message` to a MarkerArray, in order and at one stamp (only the first
    clears an older map), so that a whole field's CDR is never held at once."""
    path = Path(path)
    if overwrite:
        path.unlink(missing_ok=True)
    make = MessageFactory("humble")
    t = snapshot_time(snapshot) if stamp is None else stamp
    ns = seconds_to_ns(t)
    with open_ros2_writer(path, "mcap", compress=True) as writer:
        conn = writer.add_connection(PLANTS_TOPIC, MARKER_ARRAY, typestore=make.store)
        count = marker_count(snapshot, labels)
        markers = _marker_stream(snapshot, make, attribute, t, frame, diameter, labels)
        empty = make.T[MARKER_ARRAY](markers=[])
        for start in range(0, count, markers_per_message):
            size = min(markers_per_message, count - start)
            part = islice(markers, size)
            writer.write(
                conn, ns, make.serialize_streamed(empty, MARKER_ARRAY, part, size, MARKER_MSG)
            )
        for kind, trajectories in (
            ("trajectory", snapshot.trajectories),
            ("dead_reckoning", snapshot.dead_reckoning),
        ):
            for robot, trajectory in trajectories.items():
                conn = writer.add_connection(
                    f"/agrislam/{kind}/{robot}", PATH, typestore=make.store
                )
                empty = make.T[PATH](header=_path_header(trajectory, make, frame), poses=[])
                poses = _poses(trajectory, make, frame)
                data = make.serialize_streamed(empty, PATH, poses, len(trajectory.t), POSE_STAMPED)
                writer.write(conn, ns, data)
    return path
