"""Reading bags agrislam did not write: both vision_msgs layouts (ROS 2 4.x, Foxy, ROS 1
Noetic), Detection2D + depth through the RGB-D front end, and every kind of bad input."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import get_types_from_msg

from agrislam.config import AgrislamConfig
from agrislam.geometry.se2 import quaternion_from_yaw
from agrislam.io.perception.camera import camera_mount, rigid_transform
from agrislam.io.perception.synthetic import FacingDisc, instance_box, render_depth
from agrislam.io.ros.messages import (
    CAMERA_INFO,
    DETECTION2D_ARRAY,
    DETECTION3D_ARRAY,
    IMAGE,
    ODOMETRY,
    TF_MESSAGE,
    MessageFactory,
    open_ros2_writer,
)
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.io.sources.bag_report import BagReport
from agrislam.io.sources.rosbag import BagSource
from agrislam.records import Detections, DiscreteMeasurement, Odometry, Record

CROPS = AgrislamConfig.model_validate({"schema": "crops_weeds"})
Write = Callable[[str, str, Any, float], None]


@contextmanager
def bag(path: Path, make: MessageFactory, storage: str = "mcap") -> Iterator[Write]:
    """A writer of (topic, msgtype, message, log time) into a ROS 1 or ROS 2 bag."""
    conns: dict[str, Any] = {}

    def writer_of(w: Any) -> Write:
        def write(topic: str, msgtype: str, msg: Any, t: float) -> None:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=make.store)
            data = msg if isinstance(msg, bytes) else make.serialize(msg, msgtype)
            w.write(conns[topic], round(t * 1e9), data)

        return write

    if make.ros1:
        with Ros1Writer(path) as w:
            yield writer_of(w)
    else:
        with open_ros2_writer(path, storage) as w:  # type: ignore[arg-type]
            yield writer_of(w)


def odom(make: MessageFactory, t: float, x: float, y: float, yaw: float, cov3: Any = None) -> Any:
    cov6 = np.zeros((6, 6))
    cov6[np.ix_([0, 1, 5], [0, 1, 5])] = np.diag([1e-4, 1e-4, 1e-5]) if cov3 is None else cov3
    return make.odometry(t, "odom", "base_link", (x, y, 0.0), quaternion_from_yaw(yaw), cov6)


def read(
    path: Path, config: AgrislamConfig | None = None, **bag_cfg: Any
) -> tuple[list[Record], BagReport]:
    source = BagSource(path, config, BagSourceConfig(**bag_cfg))
    return list(source.records()), source.report


def kinds(report: BagReport) -> list[tuple[str, str | None, float | None]]:
    return [
        (i.kind, i.topic, None if i.stamp is None else round(i.stamp, 6)) for i in report.issues
    ]


# ------------------------------------------------------------------ Detection3DArray

YAW = 0.5
CAM_T = rigid_transform(
    np.array([[np.cos(YAW), -np.sin(YAW), 0], [np.sin(YAW), np.cos(YAW), 0], [0, 0, 1]]),
    (0.3, 0.0, 0.5),
)


@pytest.mark.parametrize(
    ("layout", "name", "storage"),
    [("humble", "h.mcap", "mcap"), ("foxy", "foxy_bag", "sqlite3"), ("noetic", "n.bag", "")],
)
def test_detection3d_in_every_layout(tmp_path: Path, layout: str, name: str, storage: str) -> None:
    make = MessageFactory(layout)  # type: ignore[arg-type]
    numeric = layout == "noetic"
    hyps_a = (
        [(2, 0.8), (5, 0.15)]
        if numeric
        else [("crop_small_healthy", 0.8), ("weed_small_healthy", 0.15)]
    )
    hyps_b = [(7, 0.6)] if numeric else [("size=big", 0.6)]
    a = make.detection3d(
        0.25, "camera_link", (1.0, 0.2, -0.5), hyps_a, np.diag([0.04, 0.01, 0.09]), "p7"
    )
    b = make.detection3d(0.25, "camera_link", (2.0, -0.3, -0.5), hyps_b)
    # an empty box: the position is the hypothesis pose's
    b.bbox = make.T["vision_msgs/msg/BoundingBox3D"](
        center=make.pose((0.0, 0.0, 0.0)), size=make.vector3((0.0, 0.0, 0.0))
    )
    path = tmp_path / name
    with bag(path, make, storage) as write:
        write(
            "/tf_static",
            TF_MESSAGE,
            make.tf_message([(0.0, "base_link", "camera_link", CAM_T)]),
            0.0,
        )
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write(
            "/camera/detections",
            DETECTION3D_ARRAY,
            make.detection_array(0.25, "camera_link", [a, b]),
            0.25,
        )
        write("/odom", ODOMETRY, odom(make, 0.5, 0.2, 0.0, 0.01), 0.5)
    names = {"2": "crop_small_healthy", "5": "weed_small_healthy", "7": "size=big"}
    got, report = read(path, CROPS, class_names=names if numeric else {})
    assert report.issues == []
    assert [type(r).__name__ for r in got] == ["Odometry", "Detections", "Odometry"]
    dets = got[1]
    assert isinstance(dets, Detections)
    assert (dets.t, dets.robot, dets.sensor) == (0.25, "r1", "camera")
    da, db = dets.objects
    c, s = np.cos(YAW), np.sin(YAW)
    # camera (1.0, 0.2) turned by the mount yaw, plus the mount offset 0.3 m forward
    np.testing.assert_allclose(da.xy, [0.3 + c * 1.0 - s * 0.2, s * 1.0 + c * 0.2], atol=1e-12)
    np.testing.assert_allclose(
        da.cov,
        [[c * c * 0.04 + s * s * 0.01, c * s * 0.03], [c * s * 0.03, s * s * 0.04 + c * c * 0.01]],
        atol=1e-12,
    )
    assert da.attributes == {
        "type": DiscreteMeasurement("crop", 0.8),
        "size": DiscreteMeasurement("small", 0.8),
        "health": DiscreteMeasurement("healthy", 0.8),
    }
    assert da.truth_id == (None if numeric else "p7")
    np.testing.assert_allclose(db.xy, [0.3 + c * 2.0 + s * 0.3, s * 2.0 - c * 0.3], atol=1e-12)
    assert db.cov is None and db.label is None
    assert db.attributes == {"size": DiscreteMeasurement("big", 0.6)}
    assert got[2].pose is not None and got[2].pose[2] == pytest.approx(0.01)  # type: ignore[union-attr]


# ---------------------------------------------------- Detection2DArray + depth + CameraInfo

K = [300.0, 0.0, 160.0, 0.0, 300.0, 120.0, 0.0, 0.0, 1.0]
OPTICAL = camera_mount([0.3, 0.0, 0.6], pitch=0.35)
PLANTS = [
    FacingDisc(np.array([1.5, 0.25, 0.12]), 0.1),
    FacingDisc(np.array([1.3, -0.35, 0.1]), 0.08),
]
DET_TOPIC, DEPTH_TOPIC = "/camera/detections", "/camera/aligned_depth_to_color/image_raw"
INFO_TOPIC, INSTANCE_TOPIC = "/camera/color/camera_info", "/camera/instance/image"
FRAME = "camera_color_optical_frame"
CLASS_IDS = {"crop_small": 0, "crop_big": 1, "weed_big": 2}


def rgbd_bag(path: Path, make: MessageFactory, storage: str = "mcap") -> None:
    from agrislam.io.perception.camera import PinholeCamera

    cam = PinholeCamera.from_camera_info(K, 320, 240, camera_to_base=OPTICAL)
    depth, instance = render_depth(cam, PLANTS)
    instance[5:25, 5:25] = 3  # a third detection where the sensor returned nothing
    depth[5:25, 5:25] = 0.0
    depth_mm = np.round(depth * 1000).astype(np.uint16)
    boxes = [instance_box(instance, k) for k in (1, 2, 3)]
    hyps: list[list[tuple[str | int, float]]] = [
        [("crop_small", 0.8)],
        [("weed_big", 0.7), ("crop_big", 0.2)],
        [("crop_small", 0.9)],
    ]
    if make.layout == "noetic":  # int64 class ids, named through class_names
        hyps = [[(CLASS_IDS[c], p) for c, p in h] for h in hyps]  # type: ignore[index]

    def frame(t: float) -> Any:
        return make.detection_array(
            t,
            FRAME,
            [make.detection2d(t, FRAME, b, h) for b, h in zip(boxes, hyps, strict=True)],
            "2d",
        )

    with bag(path, make, storage) as write:
        write("/tf_static", TF_MESSAGE, make.tf_message([(0.0, "base_link", FRAME, OPTICAL)]), 0.0)
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write(INFO_TOPIC, CAMERA_INFO, make.camera_info(0.05, FRAME, np.zeros(9), 320, 240), 0.05)
        write(DEPTH_TOPIC, IMAGE, make.image(0.1, FRAME, depth_mm, "16UC1"), 0.1)
        write(DET_TOPIC, DETECTION2D_ARRAY, frame(0.1), 0.1)  # before any usable CameraInfo
        write(INFO_TOPIC, CAMERA_INFO, make.camera_info(0.2, FRAME, K, 320, 240), 0.2)
        write(DET_TOPIC, DETECTION2D_ARRAY, frame(0.3), 0.3)  # before its depth image
        write(
            INSTANCE_TOPIC, IMAGE, make.image(0.3, FRAME, instance.astype(np.uint8), "mono8"), 0.3
        )
        write(DEPTH_TOPIC, IMAGE, make.image(0.3, FRAME, depth_mm, "16UC1"), 0.31)
        write(DET_TOPIC, DETECTION2D_ARRAY, frame(0.4), 0.4)  # no depth image at 0.4
        write(DEPTH_TOPIC, IMAGE, make.image(0.5, FRAME, depth_mm, "16UC1"), 0.5)
        write("/odom", ODOMETRY, odom(make, 0.6, 0.2, 0.0, 0.0), 0.6)


@pytest.mark.parametrize("layout", ["humble", "foxy", "noetic"])
def test_detection2d_with_depth_through_the_front_end(tmp_path: Path, layout: str) -> None:
    path = tmp_path / ("rgbd.bag" if layout == "noetic" else "rgbd.mcap")
    rgbd_bag(path, MessageFactory(layout))  # type: ignore[arg-type]
    names = {str(i): c for c, i in CLASS_IDS.items()} if layout == "noetic" else {}
    got, report = read(path, CROPS, class_names=names)
    assert report.roles["depth"] == [DEPTH_TOPIC] and report.roles["instance"] == [INSTANCE_TOPIC]
    assert kinds(report) == [
        ("bad_camera_info", INFO_TOPIC, 0.05),
        ("no_camera_info", DET_TOPIC, 0.1),
        ("no_depth", DET_TOPIC, 0.3),
        ("no_depth", DET_TOPIC, 0.4),
    ]
    assert "focal length" in report.issues[0].message
    assert report.issues[2].message.startswith("detection 2: 0 valid depth pixels of 400")
    assert "no depth image" in report.issues[3].message
    (dets,) = [r for r in got if isinstance(r, Detections)]
    assert (dets.t, dets.robot, dets.sensor) == (0.3, "r1", "camera")
    crop, weed = dets.objects
    np.testing.assert_allclose(crop.xy, PLANTS[0].center[:2], atol=3e-3)
    np.testing.assert_allclose(weed.xy, PLANTS[1].center[:2], atol=3e-3)
    assert crop.attributes == {
        "type": DiscreteMeasurement("crop", 0.8),
        "size": DiscreteMeasurement("small", 0.8),
    }
    assert weed.attributes["type"] == DiscreteMeasurement("weed", 0.7)
    assert np.linalg.eigvalsh(crop.cov)[1] > 5 * np.linalg.eigvalsh(crop.cov)[0]  # depth >> lateral
    assert [r.t for r in got if isinstance(r, Odometry)] == [0.0, 0.6]


def test_bag_without_message_definitions_needs_its_layout(tmp_path: Path) -> None:
    """rosbag2 sqlite3 bags of Humble and before carry no definitions: the configured
    layout decodes them."""
    make = MessageFactory("foxy")
    det = make.detection3d(0.25, "base_link", (1.0, 0.0, 0.0), [("crop_small", 0.9)], ident="x1")
    with bag(tmp_path / "old", make, "sqlite3") as write:
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write("/det", DETECTION3D_ARRAY, make.detection_array(0.25, "base_link", [det]), 0.25)
    with sqlite3.connect(next((tmp_path / "old").glob("*.db3"))) as db:
        db.execute("DELETE FROM message_definitions")
    got, report = read(tmp_path / "old")
    assert kinds(report) == [("undecodable", "/det", 0.25)]
    assert "set vision_msgs_layout" in report.issues[0].message
    got, report = read(tmp_path / "old", vision_msgs_layout="foxy")
    assert report.issues == []
    (obj,) = got[1].objects  # type: ignore[union-attr]
    assert (obj.label, obj.label_p, obj.truth_id) == ("crop_small", 0.9, "x1")


def test_detection2d_without_instance_image_uses_the_box(tmp_path: Path) -> None:
    rgbd_bag(tmp_path / "rgbd.mcap", MessageFactory("humble"))
    got, report = read(tmp_path / "rgbd.mcap", CROPS, instance_topics=[])
    (dets,) = [r for r in got if isinstance(r, Detections)]
    np.testing.assert_allclose(dets.objects[0].xy, PLANTS[0].center[:2], atol=5e-3)
    assert ("no_depth", DET_TOPIC, 0.3) in kinds(report)


# ------------------------------------------------------------------------ bad input


def simple_bag(
    path: Path,
    make: MessageFactory,
    extra: Callable[[Write], None] | None = None,
    frame: str = "base_link",
) -> None:
    det = make.detection3d(0.25, frame, (1.0, 0.0, 0.0), [("crop_small", 0.9)])
    with bag(path, make) as write:
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write(
            "/camera/detections", DETECTION3D_ARRAY, make.detection_array(0.25, frame, [det]), 0.25
        )
        if extra:
            extra(write)
        write("/odom", ODOMETRY, odom(make, 0.5, 0.2, 0.0, 0.0), 0.5)


def test_missing_topics_are_named_and_the_rest_is_read(tmp_path: Path) -> None:
    simple_bag(tmp_path / "b.mcap", MessageFactory())
    got, report = read(
        tmp_path / "b.mcap", odometry_topics=["/wheel_odom"], depth_topics=["/depth"]
    )
    assert [(i.kind, i.topic) for i in report.issues] == [
        ("missing_topic", "/wheel_odom"),
        ("missing_topic", "/depth"),
        ("missing_topic", None),  # then there is no odometry at all
        ("unused_topic", "/odom"),
    ]
    assert "not in the bag (it has /camera/detections, /odom)" in report.issues[0].message
    assert [type(r).__name__ for r in got] == ["Detections"]


def test_unknown_message_types_are_named(tmp_path: Path) -> None:
    make = MessageFactory()
    make.store.register(get_types_from_msg("float64 x\nfloat64 y\n", "my_msgs/msg/Plant"))
    plant = make.T["my_msgs/msg/Plant"](x=1.0, y=2.0)
    simple_bag(tmp_path / "b.mcap", make, lambda w: w("/plants", "my_msgs/msg/Plant", plant, 0.3))
    got, report = read(tmp_path / "b.mcap", detection_topics=["/plants", "/camera/detections"])
    assert [(i.kind, i.topic) for i in report.issues] == [("unknown_type", "/plants")]
    assert "'my_msgs/msg/Plant'" in report.issues[0].message
    assert [type(r).__name__ for r in got] == ["Odometry", "Detections", "Odometry"]


def test_undecodable_message_is_skipped(tmp_path: Path) -> None:
    simple_bag(
        tmp_path / "b.mcap",
        MessageFactory(),
        lambda w: w("/camera/detections", DETECTION3D_ARRAY, b"\x00\x01\x00\x00garbage", 0.3),
    )
    got, report = read(tmp_path / "b.mcap")
    assert kinds(report) == [("undecodable", "/camera/detections", 0.3)]
    assert [type(r).__name__ for r in got] == ["Odometry", "Detections", "Odometry"]


def test_out_of_order_stamps_are_named(tmp_path: Path) -> None:
    make = MessageFactory()
    with bag(tmp_path / "b.mcap", make) as write:
        for t, logged in ((0.0, 0.0), (0.4, 0.1), (0.2, 0.2), (0.6, 0.3)):
            write("/odom", ODOMETRY, odom(make, t, t, 0.0, 0.0), logged)
    got, report = read(tmp_path / "b.mcap")
    assert kinds(report)[-1] == ("time_backwards", "/odom", 0.2)
    assert "t = 0.2 after t = 0.4" in report.issues[-1].message
    assert [r.t for r in got] == [0.0, 0.4, 0.6]  # type: ignore[union-attr]


def test_detection_frame_without_transform(tmp_path: Path) -> None:
    simple_bag(tmp_path / "b.mcap", MessageFactory(), frame="mystery")
    got, report = read(tmp_path / "b.mcap")
    assert kinds(report) == [("no_transform", "/camera/detections", 0.25)]
    assert "'mystery' to the base frame 'base_link'" in report.issues[0].message
    assert [type(r).__name__ for r in got] == ["Odometry", "Odometry"]
    # the configured mount fills in for the missing tf
    got, report = read(tmp_path / "b.mcap", camera_to_base=(0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0))
    assert report.issues == []
    np.testing.assert_allclose(got[1].objects[0].xy, [1.5, 0.0])  # type: ignore[union-attr]


def test_unknown_label_keeps_the_position(tmp_path: Path) -> None:
    make = MessageFactory()
    det = make.detection3d(0.25, "base_link", (1.0, 0.0, 0.0), [("plant_small_healthy", 0.9)])
    with bag(tmp_path / "b.mcap", make) as write:
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write("/det", DETECTION3D_ARRAY, make.detection_array(0.25, "base_link", [det]), 0.25)
    got, report = read(tmp_path / "b.mcap", CROPS)
    assert kinds(report) == [("unknown_label", "/det", 0.25)]
    assert "'plant'" in report.issues[0].message
    obj = got[1].objects[0]  # type: ignore[union-attr]
    assert obj.label is None and obj.attributes == {} and obj.xy[0] == 1.0


def test_robots_by_namespace_and_ambiguous_topics(tmp_path: Path) -> None:
    make = MessageFactory()
    det = make.detection_array(
        0.25, "base_link", [make.detection3d(0.25, "base_link", (1.0, 0.0, 0.0), [])]
    )
    with bag(tmp_path / "b.mcap", make) as write:
        for robot in ("r1", "r2"):
            write(f"/{robot}/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0), 0.0)
        write("/r2/camera/detections", DETECTION3D_ARRAY, det, 0.25)
        write("/camera/detections", DETECTION3D_ARRAY, det, 0.25)
    got, report = read(tmp_path / "b.mcap")
    assert kinds(report) == [("unknown_robot", "/camera/detections", 0.25)]
    (dets,) = [r for r in got if isinstance(r, Detections)]
    assert (dets.robot, dets.sensor) == ("r2", "camera")


def test_odometry_covariance_modes(tmp_path: Path) -> None:
    make = MessageFactory()
    half = np.pi / 2
    with bag(tmp_path / "b.mcap", make) as write:
        write("/odom", ODOMETRY, odom(make, 0.0, 0.0, 0.0, 0.0, np.diag([0.1, 0.1, 0.01])), 0.0)
        write("/odom", ODOMETRY, odom(make, 1.0, 1.0, 0.0, half, np.diag([0.3, 0.2, 0.02])), 1.0)
        write("/odom", ODOMETRY, odom(make, 2.0, 1.0, 1.0, half, np.diag([0.5, 0.6, 0.05])), 2.0)
        write("/odom", ODOMETRY, odom(make, 3.0, 1.0, 2.0, half, np.zeros((3, 3))), 3.0)
    got, report = read(tmp_path / "b.mcap", odom_covariance="absolute")
    # growth of the absolute covariance, turned into the previous robot frame:
    # (0.2, 0.1, 0.01) at heading 0, then (0.2, 0.4, 0.03) seen from heading pi/2 -> (0.4, 0.2)
    np.testing.assert_allclose(got[1].cov, np.diag([0.2, 0.1, 0.01]), atol=1e-12)  # type: ignore[union-attr]
    np.testing.assert_allclose(got[2].cov, np.diag([0.4, 0.2, 0.03]), atol=1e-12)  # type: ignore[union-attr]
    # all zeros: unknown (the ROS convention), the default; a zero covariance would stop the
    # solver, and one that shrank gives no increment either ("degenerate_covariance")
    assert got[3].cov is None  # type: ignore[union-attr]
    assert ("zero_covariance", "/odom", 3.0) in kinds(report)
    got, report = read(tmp_path / "b.mcap")  # increment: as recorded, but not a zero for a motion
    np.testing.assert_allclose(got[1].cov, np.diag([0.3, 0.2, 0.02]))  # type: ignore[union-attr]
    assert got[3].cov is None  # type: ignore[union-attr]
    assert [k for k in kinds(report) if k[1]] == [("zero_covariance", "/odom", 3.0)]
    got, _ = read(tmp_path / "b.mcap", odom_covariance="ignore", odometry_form="delta")
    assert all(r.cov is None for r in got)  # type: ignore[union-attr]
    np.testing.assert_allclose(got[2].delta, [1.0, 0.0, 0.0], atol=1e-12)  # type: ignore[union-attr]


def test_a_bag_without_the_expected_topics(tmp_path: Path) -> None:
    make = MessageFactory()
    with bag(tmp_path / "b.mcap", make) as write:
        write("/chatter", "std_msgs/msg/String", make.T["std_msgs/msg/String"](data="hi"), 0.0)
    got, report = read(tmp_path / "b.mcap")
    assert got == []
    assert [i.message for i in report.issues] == [
        "no nav_msgs/Odometry topic: no robot motion",
        "no Detection3DArray/Detection2DArray topic",
    ]
    assert "2 issues" in report.summary()


def test_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / "x.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(ValueError, match="not an MCAP bag, or a damaged one"):
        list(BagSource(tmp_path / "x.mcap").records())
    with pytest.raises(FileNotFoundError, match="nothere"):
        list(BagSource(tmp_path / "nothere.mcap").records())
