"""ROS message definitions agrislam reads and writes, registered with rosbags. vision_msgs is
in no rosbags type store, so its .msg text is here, in the three layouts recorded bags have
(a bag that embeds its definitions is read with its own):

- ``humble`` (vision_msgs 4.x, ROS 2 Humble on): ``results[].hypothesis.class_id`` and
  ``.score``, box centre ``bbox.center.position.x``, a ``string id`` per detection;
- ``foxy`` (2.x/3.x, ROS 2 Foxy, Galactic): ``results[].id`` (string) and ``.score``, box
  centre ``bbox.center.x`` (Pose2D), tracking fields and the source image or cloud;
- ``noetic`` (0.0.x, ROS 1 Noetic): as ``foxy``, but ``id`` an ``int64``, no tracking."""

from __future__ import annotations

import shutil
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.serde.utils import align  # CDR alignment of a type (not re-exported)
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

Layout = Literal["humble", "foxy", "noetic"]
LAYOUTS: tuple[Layout, ...] = ("humble", "foxy", "noetic")

_BASE_STORE: dict[Layout, Stores] = {
    "humble": Stores.ROS2_HUMBLE,
    "foxy": Stores.ROS2_FOXY,
    "noetic": Stores.ROS1_NOETIC,
}

_BOX3D = """\
geometry_msgs/Pose center
geometry_msgs/Vector3 size
"""

_COMMON = {
    "vision_msgs/msg/BoundingBox3D": _BOX3D,
    "vision_msgs/msg/Detection3DArray": """\
std_msgs/Header header
vision_msgs/Detection3D[] detections
""",
    "vision_msgs/msg/Detection2DArray": """\
std_msgs/Header header
vision_msgs/Detection2D[] detections
""",
}

_HUMBLE = {
    "vision_msgs/msg/ObjectHypothesis": """\
string class_id
float64 score
""",
    "vision_msgs/msg/ObjectHypothesisWithPose": """\
vision_msgs/ObjectHypothesis hypothesis
geometry_msgs/PoseWithCovariance pose
""",
    "vision_msgs/msg/Point2D": """\
float64 x
float64 y
""",
    "vision_msgs/msg/Pose2D": """\
vision_msgs/Point2D position
float64 theta
""",
    "vision_msgs/msg/BoundingBox2D": """\
vision_msgs/Pose2D center
float64 size_x
float64 size_y
""",
    "vision_msgs/msg/Detection3D": """\
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox3D bbox
string id
""",
    "vision_msgs/msg/Detection2D": """\
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox2D bbox
string id
""",
}

_LEGACY_BOX2D = """\
geometry_msgs/Pose2D center
float64 size_x
float64 size_y
"""

_FOXY = {
    "vision_msgs/msg/ObjectHypothesisWithPose": """\
string id
float64 score
geometry_msgs/PoseWithCovariance pose
""",
    "vision_msgs/msg/BoundingBox2D": _LEGACY_BOX2D,
    "vision_msgs/msg/Detection3D": """\
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox3D bbox
sensor_msgs/PointCloud2 source_cloud
bool is_tracking
string tracking_id
""",
    "vision_msgs/msg/Detection2D": """\
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox2D bbox
sensor_msgs/Image source_img
bool is_tracking
string tracking_id
""",
}

_NOETIC = {
    "vision_msgs/msg/ObjectHypothesisWithPose": """\
int64 id
float64 score
geometry_msgs/PoseWithCovariance pose
""",
    "vision_msgs/msg/BoundingBox2D": _LEGACY_BOX2D,
    "vision_msgs/msg/Detection3D": """\
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox3D bbox
sensor_msgs/PointCloud2 source_cloud
""",
    "vision_msgs/msg/Detection2D": """\
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox2D bbox
sensor_msgs/Image source_img
""",
}

VISION_MSGS: dict[Layout, dict[str, str]] = {
    "humble": _COMMON | _HUMBLE,
    "foxy": _COMMON | _FOXY,
    "noetic": _COMMON | _NOETIC,
}
"""layout -> message type -> .msg definition"""

DETECTION3D_ARRAY = "vision_msgs/msg/Detection3DArray"
DETECTION2D_ARRAY = "vision_msgs/msg/Detection2DArray"
ODOMETRY = "nav_msgs/msg/Odometry"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMAGE = "sensor_msgs/msg/Image"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
STRING = "std_msgs/msg/String"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
PATH = "nav_msgs/msg/Path"


def vision_msgs_types(layout: Layout = "humble") -> dict:
    """The rosbags type dictionary of the vision_msgs definitions in `layout`."""
    if layout not in VISION_MSGS:
        raise ValueError(f"unknown vision_msgs layout {layout!r}; known: {', '.join(LAYOUTS)}")
    types: dict = {}
    for name, text in VISION_MSGS[layout].items():
        types.update(get_types_from_msg(text, name))
    return types


_TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"


def typestore(layout: Layout = "humble") -> Typestore:
    """A fresh type store of the layout's ROS distribution with vision_msgs registered
    (and tf2_msgs/TFMessage, which rosbags' Noetic store lacks)."""
    store = get_typestore(_BASE_STORE[layout])
    types = vision_msgs_types(layout)
    if TF_MESSAGE not in store.types:
        types.update(get_types_from_msg(_TF_MESSAGE_MSG, TF_MESSAGE))
    store.register(types)
    return store


def stamp_to_seconds(stamp: Any) -> float:
    """builtin_interfaces/Time (rosbags names ROS 1 times sec/nanosec too) in seconds."""
    return (int(stamp.sec) * 10**9 + int(stamp.nanosec)) / 1e9  # one rounding: ns -> s


def seconds_to_ns(t: float) -> int:
    if not t >= 0.0:
        raise ValueError(f"a ROS time stamp cannot be negative or NaN, got t={t}")
    return round(t * 1e9)


IMAGE_ENCODINGS: dict[str, tuple[str, int]] = {
    "16uc1": ("u2", 1), "mono16": ("u2", 1), "16sc1": ("i2", 1),
    "32fc1": ("f4", 1), "64fc1": ("f8", 1), "32sc1": ("i4", 1),
    "8uc1": ("u1", 1), "mono8": ("u1", 1),
    "rgb8": ("u1", 3), "bgr8": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4),
}  # fmt: skip
"""sensor_msgs/Image encoding -> numpy type code and channels"""


def image_array(msg: Any) -> np.ndarray:
    """A sensor_msgs/Image as an array (H, W) or (H, W, C), colour as RGB."""
    enc = msg.encoding.lower()
    if enc not in IMAGE_ENCODINGS:
        raise ValueError(f"image encoding {msg.encoding!r} is not supported")
    code, channels = IMAGE_ENCODINGS[enc]
    dtype = np.dtype(code).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    row = w * channels * dtype.itemsize
    if step < row or data.size < h * step:
        raise ValueError(f"{h}x{w} {enc} image with step {step} has only {data.size} bytes")
    rows = np.ascontiguousarray(data[: h * step].reshape(h, step)[:, :row])
    arr = rows.view(dtype).reshape(h, w, channels).astype(dtype.newbyteorder("="))
    if enc.startswith("bgr"):
        arr[..., :3] = arr[..., 2::-1]
    return arr[..., 0] if channels == 1 else arr


@contextmanager
def open_ros2_writer(
    path: str | Path, storage: Literal["mcap", "sqlite3"] = "mcap", compress: bool = False
) -> Iterator[Writer]:
    """A rosbags rosbag2 Writer (version 9) for `path`, which must not exist: a path ending in
    ``.mcap`` becomes a bare MCAP file (written as a rosbag2 folder, its one file then moved
    into place), any other a rosbag2 folder of `storage`; `compress`: zstd-compressed chunks."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists already, not overwriting")
    bare = path.suffix == ".mcap"
    if bare and storage != "mcap":
        raise ValueError(f"{path}: a .mcap file needs storage='mcap', got {storage!r}")
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3

    def writer(folder: Path) -> Writer:
        w = Writer(folder, version=9, storage_plugin=plugin)
        if compress and storage == "mcap":
            w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        return w

    if not bare:
        with writer(path) as w:
            yield w
        return
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.stem}-") as tmp:
        folder = Path(tmp) / path.stem
        with writer(folder) as w:
            yield w
        (mcap,) = folder.glob("*.mcap")
        shutil.move(str(mcap), path)


class MessageFactory:
    """Builds the messages the project writes, in one vision_msgs layout and its ROS
    distribution (Noetic for ``noetic``), and serialises them for that distribution."""

    def __init__(self, layout: Layout = "humble") -> None:
        self.layout = layout
        self.store = typestore(layout)
        self.ros1 = layout == "noetic"
        self.T = self.store.types

    def serialize(self, msg: Any, msgtype: str) -> bytes:
        if self.ros1:
            return bytes(self.store.serialize_ros1(msg, msgtype))
        return bytes(self.store.serialize_cdr(msg, msgtype))

    def serialize_streamed(
        self, msg: Any, msgtype: str, items: Iterable[Any], count: int, item_type: str
    ) -> bytearray:
        """The CDR of `msg` whose last field is a sequence, given empty in `msg`, of the
        `count` `item_type`s `items` (a MarkerArray's markers, a Path's poses): byte for
        byte what `serialize` gives with the items in that field, without every item held
        as an object at once (100,000 plants' markers)."""
        if self.ros1:
            raise ValueError("serialize_streamed writes CDR (ROS 2) only")
        item = self.store.get_msgdef(item_type)
        little = sys.byteorder == "little"
        pack = item.serialize_cdr_le if little else item.serialize_cdr_be
        out = bytearray(self.store.serialize_cdr(msg, msgtype, little_endian=little))
        if out[-4:] != bytes(4):
            raise ValueError(f"serialize_streamed: {msgtype} does not end in an empty sequence")
        out[-4:] = count.to_bytes(4, "little" if little else "big")
        pos, n = len(out) - 4, 0  # within the payload (after the 4-byte encapsulation header)
        first = align((Nodetype.NAME, item_type), self.store)  # as rosbags' sequences do
        for one in items:
            pos = (pos + first - 1) & -first
            base = pos & ~7  # CDR aligns relative to the payload: keep pos modulo 8
            end = item.getsize_cdr(pos, one, self.store)
            chunk = bytearray(end - base)
            pack(memoryview(chunk), pos - base, one, self.store)
            out += bytes(pos - len(out) + 4)  # the alignment before the item
            out += memoryview(chunk)[pos - base :]
            pos, n = end, n + 1
        if n != count:
            raise ValueError(f"serialize_streamed: {n} {item_type} items, {count} announced")
        return out

    # ------------------------------------------------------------ geometry

    def time(self, t: float) -> Any:
        ns = seconds_to_ns(t)
        return self.T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)

    def header(self, t: float, frame: str) -> Any:
        extra = {"seq": 0} if self.ros1 else {}
        return self.T["std_msgs/msg/Header"](stamp=self.time(t), frame_id=frame, **extra)

    def vector3(self, v: Any) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def pose(self, xyz: Any, q: Any = (0.0, 0.0, 0.0, 1.0)) -> Any:
        return self.T["geometry_msgs/msg/Pose"](
            position=self.T["geometry_msgs/msg/Point"](
                x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])
            ),
            orientation=self.T["geometry_msgs/msg/Quaternion"](
                x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
            ),
        )

    def pose_with_covariance(
        self, xyz: Any, cov6: Any = None, q: Any = (0.0, 0.0, 0.0, 1.0)
    ) -> Any:
        cov = np.zeros(36) if cov6 is None else np.asarray(cov6, dtype=np.float64).ravel()
        return self.T["geometry_msgs/msg/PoseWithCovariance"](
            pose=self.pose(xyz, q), covariance=cov
        )

    def odometry(self, t: float, frame: str, child: str, xyz: Any, q: Any, cov6: Any) -> Any:
        zero = self.vector3((0.0, 0.0, 0.0))
        return self.T["nav_msgs/msg/Odometry"](
            header=self.header(t, frame),
            child_frame_id=child,
            pose=self.pose_with_covariance(xyz, cov6, q),
            twist=self.T["geometry_msgs/msg/TwistWithCovariance"](
                twist=self.T["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                covariance=np.zeros(36),
            ),
        )

    def tf_message(self, transforms: list[tuple[float, str, str, np.ndarray]]) -> Any:
        """tf2_msgs/TFMessage of (t, parent, child, 4x4 T_parent_child)."""
        out = []
        for t, parent, child, T in transforms:
            q = _quaternion_from_rotation(np.asarray(T)[:3, :3])
            tr = self.T["geometry_msgs/msg/Transform"](
                translation=self.vector3(np.asarray(T)[:3, 3]),
                rotation=self.T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            out.append(
                self.T["geometry_msgs/msg/TransformStamped"](
                    header=self.header(t, parent), child_frame_id=child, transform=tr
                )
            )
        return self.T[TF_MESSAGE](transforms=out)

    # ----------------------------------------------------------- vision_msgs

    def hypothesis(self, class_id: str | int, score: float, pose: Any) -> Any:
        """ObjectHypothesisWithPose: 4.x nests ObjectHypothesis(class_id); Foxy has a
        string id, Noetic an int64 id."""
        cls = self.T["vision_msgs/msg/ObjectHypothesisWithPose"]
        if self.layout == "humble":
            h = self.T["vision_msgs/msg/ObjectHypothesis"](
                class_id=str(class_id), score=float(score)
            )
            return cls(hypothesis=h, pose=pose)
        cid = int(class_id) if self.layout == "noetic" else str(class_id)
        return cls(id=cid, score=float(score), pose=pose)

    def _tracking(self, kind: str, t: float, frame: str, ident: str) -> dict[str, Any]:
        """The layout's extra fields: 4.x ``id``; Foxy/Noetic the source data (empty),
        Foxy also ``is_tracking``/``tracking_id``."""
        if self.layout == "humble":
            return {"id": ident}
        extra: dict[str, Any] = {}
        if kind == "3d":
            extra["source_cloud"] = self.T["sensor_msgs/msg/PointCloud2"](
                header=self.header(t, frame), height=0, width=0, fields=[], is_bigendian=False,
                point_step=0, row_step=0, data=np.zeros(0, dtype=np.uint8), is_dense=True,
            )  # fmt: skip
        else:
            extra["source_img"] = self.image(t, frame, np.zeros((0, 0), dtype=np.uint8), "mono8")
        if self.layout == "foxy":
            extra.update(is_tracking=bool(ident), tracking_id=ident)
        return extra

    def detection3d(
        self,
        t: float,
        frame: str,
        center: Any,
        hypotheses: list[tuple[str | int, float]],
        cov3: Any = None,
        ident: str = "",
        size: Any = (0.0, 0.0, 0.0),
    ) -> Any:
        """One Detection3D at `center` (header frame) with the covariance in every
        hypothesis pose."""
        cov6 = np.zeros((6, 6))
        if cov3 is not None:
            c = np.asarray(cov3, dtype=float)
            cov6[: c.shape[0], : c.shape[1]] = c
        pose = self.pose_with_covariance(center, cov6)
        bbox = self.T["vision_msgs/msg/BoundingBox3D"](
            center=self.pose(center), size=self.vector3(size)
        )
        return self.T["vision_msgs/msg/Detection3D"](
            header=self.header(t, frame),
            results=[self.hypothesis(c, s, pose) for c, s in hypotheses],
            bbox=bbox,
            **self._tracking("3d", t, frame, ident),
        )

    def detection2d(
        self,
        t: float,
        frame: str,
        box: Any,
        hypotheses: list[tuple[str | int, float]],
        ident: str = "",
    ) -> Any:
        """One Detection2D for box (x0, y0, x1, y1): the 4.x centre is ``center.position``,
        the older one a geometry_msgs/Pose2D."""
        x0, y0, x1, y1 = (float(v) for v in box)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        if self.layout == "humble":
            center = self.T["vision_msgs/msg/Pose2D"](
                position=self.T["vision_msgs/msg/Point2D"](x=cx, y=cy), theta=0.0
            )
        else:
            center = self.T["geometry_msgs/msg/Pose2D"](x=cx, y=cy, theta=0.0)
        bbox = self.T["vision_msgs/msg/BoundingBox2D"](
            center=center, size_x=x1 - x0, size_y=y1 - y0
        )
        pose = self.pose_with_covariance((0.0, 0.0, 0.0))
        return self.T["vision_msgs/msg/Detection2D"](
            header=self.header(t, frame),
            results=[self.hypothesis(c, s, pose) for c, s in hypotheses],
            bbox=bbox,
            **self._tracking("2d", t, frame, ident),
        )

    def detection_array(self, t: float, frame: str, detections: list[Any], kind: str = "3d") -> Any:
        msgtype = DETECTION3D_ARRAY if kind == "3d" else DETECTION2D_ARRAY
        return self.T[msgtype](header=self.header(t, frame), detections=detections)

    # ------------------------------------------------------------- sensors

    def image(self, t: float, frame: str, array: np.ndarray, encoding: str) -> Any:
        """sensor_msgs/Image of an array in the given encoding (colour given as RGB)."""
        code, channels = IMAGE_ENCODINGS[encoding.lower()]
        a = np.asarray(array).astype(np.dtype(code).newbyteorder("<"))
        if encoding.lower().startswith("bgr"):
            a = a.copy()
            a[..., :3] = a[..., 2::-1]
        h, w = a.shape[:2]
        data = np.frombuffer(a.tobytes(), dtype=np.uint8)
        return self.T[IMAGE](
            header=self.header(t, frame), height=h, width=w, encoding=encoding,
            is_bigendian=0, step=w * channels * a.dtype.itemsize, data=data,
        )  # fmt: skip

    def camera_info(
        self, t: float, frame: str, k: Any, width: int, height: int, d: Any = ()
    ) -> Any:
        K = np.asarray(k, dtype=np.float64).ravel()
        P = np.zeros(12)
        P[[0, 1, 2, 4, 5, 6, 10]] = K[[0, 1, 2, 3, 4, 5, 8]]
        roi = self.T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        arrays = {"d": np.asarray(d, dtype=np.float64), "k": K, "r": np.eye(3).ravel(), "p": P}
        if self.ros1:
            arrays = {name.upper(): value for name, value in arrays.items()}
        return self.T[CAMERA_INFO](
            header=self.header(t, frame), height=height, width=width,
            distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **arrays,
        )  # fmt: skip


def _quaternion_from_rotation(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (Shepperd's method)."""
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = ((R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s)
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (R[j, i] + R[i, j]) / s
        v[k] = (R[k, i] + R[i, k]) / s
        q = (v[0], v[1], v[2], (R[k, j] - R[j, k]) / s)
    return tuple(float(x) for x in q)  # type: ignore[return-value]
