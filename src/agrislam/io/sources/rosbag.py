"""ROS bags as a source: a rosbag2 folder (sqlite3 or MCAP), a bare .mcap file or a ROS 1
.bag read as agrislam records (rosbags; no ROS installation needed), as `sinks.rosbag`
writes them. Bad input never stops the reader: each problem is an issue in its `BagReport`.

What it takes (topics named in `BagSourceConfig` or found by type):

- ``nav_msgs/Odometry``: one robot per topic (its namespace, ``/r2/odom`` -> ``r2``), the
  x/y/yaw covariance block read as `odom_covariance` says (``covariance[0] == -1``: unknown);
- ``tf`` / ``tf_static``: the camera-to-base transform (or the config's ``camera_to_base``);
- ``vision_msgs/Detection3DArray`` (4.x or Foxy/Noetic layout): the box centre (or, with an
  empty box, the hypothesis pose) in the base frame, hypotheses read by `sources.hypotheses`
  (``attr=value`` measurements or a combined label), ``Detection3D.id`` as ``truth_id``;
- ``vision_msgs/Detection2DArray`` with aligned depth, ``CameraInfo`` and optionally an
  instance image: through the RGB-D front end (`sources.rgbd`);
- ``sensor_msgs/NavSatFix``: GNSS fixes (`ros.navsat`);
- ``/agrislam/meta`` and ``/agrislam/truth`` (``std_msgs/String``): a survey log line each.

Records come in time order (header stamps; meta first), after one pass through the bag."""

from __future__ import annotations

import dataclasses
import io
import math
import re
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinitionFormat

from agrislam.config import AgrislamConfig, FieldSchema
from agrislam.geometry.se2 import between
from agrislam.io.perception.camera import (
    rigid_transform,
    rotation_from_quaternion,
)
from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.perception.label_map import LabelMap, UnknownLabelError
from agrislam.io.ros.conventions import (
    POSE_COV_INDEX,
    UNKNOWN_COVARIANCE,
)
from agrislam.io.ros.messages import (
    CAMERA_INFO,
    DETECTION2D_ARRAY,
    DETECTION3D_ARRAY,
    IMAGE,
    ODOMETRY,
    STRING,
    TF_MESSAGE,
    seconds_to_ns,
    stamp_to_seconds,
    typestore,
)
from agrislam.io.ros.navsat import NAVSAT_FIX, gnss_record
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.io.sources.bag_open import check_bag, opened_bag
from agrislam.io.sources.bag_report import BagReport, SkipError
from agrislam.io.sources.clock import Rejected, RobotClocks
from agrislam.io.sources.hypotheses import hypotheses, parse_hypotheses
from agrislam.io.sources.jsonl import LogError, read_log
from agrislam.io.sources.rgbd import ProjectedFrame, RgbdFrames
from agrislam.io.sources.transforms import TransformTree, planar, pose_matrix
from agrislam.io.sources.validate import BadRecordError, check_record
from agrislam.records import (
    Detection,
    Detections,
    GnssFix,
    Meta,
    Odometry,
    Record,
    TruthObject,
    TruthPose,
)

_UNTIMED = 3
_KIND_RANK = {
    Meta: -1, TruthPose: 0, Odometry: 1, GnssFix: 1.5, Detections: 2, TruthObject: _UNTIMED
}  # fmt: skip


class _BagReader:
    def __init__(self, path: Path, config: AgrislamConfig, bag: BagSourceConfig) -> None:
        self.path, self.config, self.bag = path, config, bag
        self.report = BagReport(str(path))
        self.store = typestore(bag.vision_msgs_layout)
        self.perception = bag.perception or PerceptionConfig.from_config(config)
        self.schema: FieldSchema | None = config.field_schema()
        self.tree = TransformTree()
        self.base_frames: dict[str, str] = {}
        self.clocks: RobotClocks[tuple[float, Any]] = RobotClocks(
            config.advanced.sensor.limits, "topic"
        )
        self.odom_state: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
        self.robot_order: list[str] = []
        self.records: list[tuple[int, str | None, int, int, Record]] = []
        self._label_map: LabelMap | None = None
        self._build_label_map()

    # ----------------------------------------------------------------- setup

    def _build_label_map(self) -> None:
        lm = LabelMap.from_config(self.config.label_map, self.schema)
        self._label_map = lm if (lm and self.bag.split_labels) else None

    def _roles(self, topics: dict[str, str]) -> dict[str, list[str]]:
        """role -> topics, from the config or by message type (and name for images)."""
        bag = self.bag
        of_type = {t: [n for n, m in topics.items() if m == t] for t in set(topics.values())}
        images = [n.lower() for n in of_type.get(IMAGE, [])]
        named_images = {n.lower(): n for n in of_type.get(IMAGE, [])}

        def images_named(pattern: str) -> list[str]:
            return [named_images[n] for n in images if re.search(pattern, n)]

        table: dict[str, tuple[list[str] | None, list[str], tuple[str, ...]]] = {
            "odometry": (bag.odometry_topics, of_type.get(ODOMETRY, []), (ODOMETRY,)),
            "detections": (
                bag.detection_topics,
                of_type.get(DETECTION3D_ARRAY, []) + of_type.get(DETECTION2D_ARRAY, []),
                (DETECTION3D_ARRAY, DETECTION2D_ARRAY),
            ),
            "depth": (bag.depth_topics, images_named("depth"), (IMAGE,)),
            "camera_info": (bag.camera_info_topics, of_type.get(CAMERA_INFO, []), (CAMERA_INFO,)),
            "gnss": (bag.gnss_topics, of_type.get(NAVSAT_FIX, []), (NAVSAT_FIX,)),
            "instance": (bag.instance_topics, images_named("instance"), (IMAGE,)),
            "rgb": (bag.rgb_topics, images_named(r"^(?!.*depth).*(colou?r|rgb)"), (IMAGE,)),
        }
        roles = {role: self._chosen(role, *spec, topics) for role, spec in table.items()}
        roles["tf"] = sorted(t for t in of_type.get(TF_MESSAGE, []) if t in ("/tf", "/tf_static"))
        roles["meta"] = [bag.meta_topic] if topics.get(bag.meta_topic) == STRING else []
        roles["truth"] = [bag.truth_topic] if topics.get(bag.truth_topic) == STRING else []
        if not self.perception.green_filter:
            roles["rgb"] = []
        missing = self.report.add
        if not roles["odometry"]:
            missing("missing_topic", None, None, "no nav_msgs/Odometry topic: no robot motion")
        if not roles["detections"]:
            missing("missing_topic", None, None, "no Detection3DArray/Detection2DArray topic")
        if any(topics[t] == DETECTION2D_ARRAY for t in roles["detections"]):
            for role in ("depth", "camera_info"):
                if not roles[role]:
                    missing(
                        "missing_topic", None, None,
                        f"Detection2DArray needs a {role} topic; none found (name it in config)",
                    )  # fmt: skip
        used = {t for ts in roles.values() for t in ts}
        for name, msgtype in topics.items():
            if msgtype in (DETECTION3D_ARRAY, DETECTION2D_ARRAY, ODOMETRY) and name not in used:
                missing("unused_topic", name, None, f"{msgtype} not selected in the config")
        return roles

    def _chosen(
        self,
        role: str,
        named: list[str] | None,
        found: list[str],
        types: tuple[str, ...],
        topics: dict[str, str],
    ) -> list[str]:
        """The configured topics of a role that exist with a right type, else those found."""
        if named is None:
            return sorted(found)
        out = []
        for t in named:
            if t not in topics:
                self.report.add(
                    "missing_topic", t, None,
                    f"{role} topic named in the config is not in the bag "
                    f"(it has {', '.join(sorted(topics)) or 'no topics'})",
                )  # fmt: skip
            elif topics[t] not in types:
                self.report.add(
                    "unknown_type", t, None,
                    f"{role} topic has type {topics[t]!r}, expected {' or '.join(types)}",
                )  # fmt: skip
            else:
                out.append(t)
        return out

    def robot_of(self, topic: str, odometry: bool = False) -> tuple[str, str | None]:
        """(robot, sensor) of a topic: namespace -> robot, the rest of it -> sensor."""
        parts = topic.strip("/").split("/")[:-1]
        if odometry:
            return (parts[0] if parts else self.bag.robot), None
        robots = self.odom_robots
        if parts and parts[0] in robots:
            return parts[0], "/".join(parts[1:]) or None
        if len(robots) > 1:
            raise SkipError(
                "unknown_robot",
                f"cannot tell which of the robots {sorted(robots)} this topic belongs to "
                "(put it under the robot's namespace)",
            )
        robot = next(iter(robots)) if robots else self.bag.robot
        return robot, "/".join(parts) or None

    # ------------------------------------------------------------------ run

    def read(self) -> list[Record]:
        if not self.path.exists():
            raise FileNotFoundError(f"bag {self.path} not found")

        def damaged(message: str) -> None:
            self.report.add("damaged", None, None, message)

        with opened_bag(self.path, self.store, damaged) as reader:
            topics = {name: info.msgtype for name, info in reader.topics.items()}
            roles = self._roles(topics)
            self.report.roles = roles
            self.role_of = {t: role for role, ts in roles.items() for t in ts}
            self.topic_type = topics
            self.odom_robots = {self.robot_of(t, odometry=True)[0] for t in roles["odometry"]}
            self.rgbd = RgbdFrames(self.bag, self.perception, self, roles, topics)
            conns = [c for c in reader.connections if c.topic in self.role_of]
            stream = reader.messages(connections=conns) if conns else iter(())  # () = all
            for conn, logtime, raw in _until_damaged(stream, damaged):
                self.report.messages[conn.topic] += 1
                try:
                    msg = self._deserialize(reader, conn, raw)
                    self._dispatch(conn.topic, msg, logtime)
                except SkipError as skip:
                    self.report.add(skip.kind, conn.topic, logtime * 1e-9, skip.message)
                except AttributeError as err:  # decoded by a damaged definition of its type
                    message = f"{conn.msgtype} lacks a field of its type: {err}"
                    self.report.add("undecodable", conn.topic, logtime * 1e-9, message)
            self._place_2d(self.rgbd.finish())
        self._late(self.clocks.finish())
        ordered = self._ordered()
        for rec in ordered:
            self.report.records[type(rec).__name__] += 1
        return ordered

    def _deserialize(self, reader: AnyReader, conn: Any, raw: bytes) -> Any:
        try:
            return reader.deserialize(raw, conn.msgtype)
        except Exception as err:  # the bag's own definitions failed: try ours
            try:
                if reader.is2:
                    return self.store.deserialize_cdr(raw, conn.msgtype)
                return self.store.deserialize_ros1(raw, conn.msgtype)
            except Exception:
                hint = ""
                if conn.msgdef.format == MessageDefinitionFormat.NONE:
                    hint = (
                        f" (the bag has no definition of it; decoded with the "
                        f"{self.bag.vision_msgs_layout!r} layout: set vision_msgs_layout)"
                    )
                raise SkipError(
                    "undecodable", f"cannot decode {conn.msgtype}: {err}{hint}"
                ) from None

    def _dispatch(self, topic: str, msg: Any, logtime: int) -> None:
        role = self.role_of[topic]
        if role in ("meta", "truth"):
            self._json_record(topic, msg, logtime)
            return
        if role == "tf":
            for tr in msg.transforms:
                self.tree.set(tr.header.frame_id, tr.child_frame_id, pose_matrix(tr.transform))
            return
        stamp = stamp_to_seconds(msg.header.stamp)
        released, rejected = self.clocks.offer(topic, stamp, (stamp, msg))
        self._late(rejected)
        for stamp, msg in released:
            self._stamped(topic, role, stamp, msg)

    def _late(self, rejected: list[Rejected[tuple[float, Any]]]) -> None:
        """Messages whose stamps go backwards, or spike ahead, on their topic."""
        for r in rejected:
            self.report.add(r.reason, r.key, r.item[0], r.message)  # type: ignore[arg-type]

    def _stamped(self, topic: str, role: str, stamp: float, msg: Any) -> None:
        """A message with a header stamp in its topic's time order."""
        most = self.config.advanced.sensor.limits.max_detections_per_frame
        if role == "detections" and len(msg.detections) > most:
            self.report.add(
                "too_many_detections",
                topic,
                stamp,
                f"{len(msg.detections)} detections in one frame; at most {most} "
                "(advanced.sensor.limits.max_detections_per_frame)",
            )
            return
        try:
            if role == "odometry":
                self._odometry(topic, stamp, msg)
            elif role == "detections" and self.topic_type[topic] == DETECTION3D_ARRAY:
                self._detections_3d(topic, stamp, msg)
            elif role == "detections":
                self._place_2d(self.rgbd.add_frame(topic, stamp, msg))
            elif role == "camera_info":
                self.rgbd.camera_info(topic, msg)
            elif role == "gnss":
                self._gnss(topic, stamp, msg)
            else:  # depth, instance, rgb images
                self.rgbd.add_image(topic, stamp, msg)
                if role == "depth":
                    self._place_2d(self.rgbd.waiting_on(topic))
        except SkipError as skip:
            self.report.add(skip.kind, topic, stamp, skip.message)

    def _emit(self, rec: Record, topic: str | None = None, logtime: int | None = None) -> bool:
        """Keep a record that passes `sources.validate` with its sort key: integer ns (so a
        stamp and a JSON time of the same instant tie), robot, kind, arrival. Untimed
        records sort where they were logged (after the records of that instant), those
        logged at 0 before everything. False (and an issue) for a record that fails."""
        try:
            rec = check_record(rec, self.config.advanced.sensor.limits)
        except BadRecordError as bad:
            self.report.add(bad.reason, topic, getattr(rec, "t", None), bad.message)
            return False
        robot = getattr(rec, "robot", None)
        if robot is not None and robot not in self.robot_order:
            self.robot_order.append(robot)
        if isinstance(rec, Meta | TruthObject):
            ns = logtime if (logtime and isinstance(rec, TruthObject)) else -(2**63)
        else:
            ns = seconds_to_ns(rec.t)  # type: ignore[union-attr]
        self.records.append((ns, robot, _KIND_RANK[type(rec)], len(self.records), rec))
        return True

    def _ordered(self) -> list[Record]:
        """Time order; at equal times robots in meta (else first-seen) order, then truth,
        odometry, detections, as the simulator and the survey log interleave them."""
        rank = {r: i for i, r in enumerate(self.robot_order)}
        keyed = sorted(
            self.records, key=lambda e: (e[0], e[2] == _UNTIMED, rank.get(e[1], -1), e[2], e[3])
        )
        return [e[4] for e in keyed]

    # ------------------------------------------------------------- messages

    def _json_record(self, topic: str, msg: Any, logtime: int) -> None:
        """A survey-log line carried as a String (meta, truth); a bad meta stops the read,
        as in a log: it is the survey's contract."""
        line = io.BytesIO(msg.data.encode("utf-8", "replace"))
        try:
            (rec,) = list(read_log(line, config=self.config))
        except LogError as err:
            if err.fatal:
                where = f"{self.path} {topic}"
                raise LogError(1, err.reason, err.message, where, fatal=True) from None
            self.report.add("bad_record", topic, logtime * 1e-9, str(err))
            return
        except ValueError as err:
            self.report.add("bad_record", topic, logtime * 1e-9, str(err))
            return
        if isinstance(rec, Meta):
            if rec.schema is not None and self.schema is None:
                self.schema = rec.schema
                self._build_label_map()
            self.robot_order[:0] = [r for r in rec.robots if r not in self.robot_order]
        self._emit(rec, topic, logtime)

    def _odometry(self, topic: str, stamp: float, msg: Any) -> None:
        robot, _ = self.robot_of(topic, odometry=True)
        if msg.child_frame_id:
            self.base_frames.setdefault(robot, msg.child_frame_id.lstrip("/"))
        pose = planar(pose_matrix(msg.pose.pose))
        full = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
        prev = self.odom_state.get(robot)  # the last pose kept: a rejected one is skipped over
        cov = self._increment_cov(topic, stamp, full, pose, prev)
        if self.bag.odometry_form == "delta":
            delta = pose if prev is None else between(prev[0], pose)
            rec = Odometry(stamp, robot, delta=delta, cov=cov)
        else:
            rec = Odometry(stamp, robot, pose=pose, cov=cov)
        if self._emit(rec, topic):
            self.odom_state[robot] = (pose, full)

    def _increment_cov(
        self,
        topic: str,
        stamp: float,
        full: np.ndarray,
        pose: np.ndarray,
        prev: tuple[np.ndarray, np.ndarray | None] | None,
    ) -> np.ndarray | None:
        mode = self.bag.odom_covariance
        if mode == "ignore" or full[0, 0] == UNKNOWN_COVARIANCE:
            return None
        cov = full[np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)].copy()
        if not cov.any():  # ROS: all zeros means unknown; said when it claims a certain motion
            if prev is not None and not np.allclose(prev[0], pose, rtol=0.0, atol=1e-12):
                self.report.add(
                    "zero_covariance", topic, stamp,
                    "all-zero pose covariance for a motion; the configured default is used",
                )  # fmt: skip
            return None
        if mode == "absolute":
            if prev is None:
                return cov
            # the increment's covariance: growth of the absolute one, in the previous frame
            c, s = math.cos(prev[0][2]), math.sin(prev[0][2])
            R = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
            before = prev[1][np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)]  # type: ignore[index]
            grown = R @ (cov - before) @ R.T
            w, V = np.linalg.eigh(0.5 * (grown + grown.T))
            if w.min() <= 0.0:  # it did not grow in every direction: no increment to take
                self.report.add(
                    "degenerate_covariance", topic, stamp,
                    "the absolute pose covariance did not grow in every direction since the "
                    "previous message; the configured default is used",
                )  # fmt: skip
                return None
            return (V * w) @ V.T
        return cov

    def _gnss(self, topic: str, stamp: float, msg: Any) -> None:
        """A NavSatFix; the antenna's place from tf when tf connects it to the base."""
        robot, _ = self.robot_of(topic)
        base = self.base_frames.get(robot) or self.bag.base_frame or "base_link"
        T = self.tree.lookup(base, msg.header.frame_id) if msg.header.frame_id else None
        self._emit(gnss_record(msg, stamp, robot, None if T is None else T[:3, 3]), topic)

    def to_base(self, frame: str, robot: str) -> np.ndarray:
        base = self.base_frames.get(robot) or self.bag.base_frame or "base_link"
        frame = frame.lstrip("/")
        if frame in ("", base):
            return np.eye(4)
        T = self.tree.lookup(base, frame)
        if T is not None:
            return T
        if self.bag.camera_to_base is not None:
            x, y, z, *q = self.bag.camera_to_base
            return rigid_transform(rotation_from_quaternion(q), (x, y, z))
        raise SkipError(
            "no_transform",
            f"no transform from frame {frame!r} to the base frame {base!r} "
            "(record tf_static, or set camera_to_base in the config)",
        )

    def _detections_3d(self, topic: str, stamp: float, msg: Any) -> None:
        robot, sensor = self.robot_of(topic)
        objects = []
        for i, det in enumerate(msg.detections):
            frame = msg.header.frame_id or det.header.frame_id
            T = self.to_base(frame, robot)
            hyps = hypotheses(det.results)
            center = det.bbox.center.position
            size = det.bbox.size
            if any((center.x, center.y, center.z, size.x, size.y, size.z)) or not hyps:
                p = np.array([center.x, center.y, center.z])
            else:
                hp = hyps[0][2].pose.position
                p = np.array([hp.x, hp.y, hp.z])
            point = T[:3, :3] @ p + T[:3, 3]
            cov = None
            for _, _, pose in hyps:
                c3 = np.asarray(pose.covariance, dtype=float).reshape(6, 6)[:3, :3]
                if c3.any():
                    cov = (T[:3, :3] @ c3 @ T[:3, :3].T)[:2, :2]
                    break
            try:
                attrs, label, label_p = parse_hypotheses(
                    [(c, s) for c, s, _ in hyps], self.bag.class_names
                )
            except SkipError as skip:
                self.report.add(skip.kind, topic, stamp, f"detection {i}: {skip.message}")
                continue
            truth_id = getattr(det, "id", "") or getattr(det, "tracking_id", "") or None
            obj = self._geometry(point[:2], cov)
            obj = Detection(
                **obj, attributes=attrs, label=label, label_p=label_p, truth_id=truth_id
            )
            objects.append(self._semantics(obj, topic, stamp, i))
        self._emit(Detections(stamp, robot, tuple(objects), sensor), topic)

    def _geometry(self, xy: np.ndarray, cov: np.ndarray | None) -> dict[str, Any]:
        """xy + cov, or range/bearing from the base origin with the along-ray and
        across-ray standard deviations of the covariance."""
        if self.bag.detection_geometry == "xy":
            return {"xy": xy, "cov": cov}
        r, b = float(np.hypot(*xy)), float(math.atan2(xy[1], xy[0]))
        out: dict[str, Any] = {"range": r, "bearing": b}
        if cov is not None and r > 0.0:
            u = np.array([math.cos(b), math.sin(b)])
            v = np.array([-u[1], u[0]])
            out["sigma_range"] = float(math.sqrt(max(u @ cov @ u, 0.0)))
            out["sigma_bearing"] = float(math.sqrt(max(v @ cov @ v, 0.0)) / r)
        return out

    def _semantics(self, obj: Detection, topic: str, stamp: float, i: int) -> Detection:
        if self._label_map is None or obj.label is None:
            return obj
        try:
            return self._label_map.apply(obj)
        except (UnknownLabelError, ValueError) as err:
            self.report.add("unknown_label", topic, stamp, f"detection {i}: {err}; label dropped")
            return dataclasses.replace(obj, label=None, label_p=None)

    def _place_2d(self, frames: Iterable[ProjectedFrame]) -> None:
        """Emit the projected Detection2D frames, their labels split by the schema."""
        for f in frames:
            objects = [self._semantics(obj, f.topic, f.stamp, i) for i, obj in f.objects]
            self._emit(Detections(f.stamp, f.robot, tuple(objects), f.sensor), f.topic)


class BagSource:
    """A ROS bag (a rosbag2 folder, a bare ``.mcap`` file or a ROS 1 ``.bag``) as a source:
    its records in time order, and the report of the latest pass. `config` gives the schema,
    label map and sensor defaults, `bag` the topics; each `records()` reads the bag on its
    first ``next()``, and its report is complete once the iterator is."""

    def __init__(
        self,
        path: str | Path,
        config: AgrislamConfig | None = None,
        bag: BagSourceConfig | None = None,
    ) -> None:
        self.path = Path(path)
        self.config = config or AgrislamConfig()
        self.bag = bag or BagSourceConfig()
        self._report = BagReport(str(self.path))

    @property
    def name(self) -> str:
        return str(self.path)

    @property
    def report(self) -> BagReport:
        return self._report

    def check(self) -> None:
        """UnreadableBagError (a ValueError) if the bag cannot be opened at all."""
        check_bag(self.path, typestore(self.bag.vision_msgs_layout))

    def records(self) -> Iterator[Record]:
        reader = _BagReader(self.path, self.config, self.bag)
        self._report = reader.report
        return _read(reader)


def _read(reader: _BagReader) -> Iterator[Record]:
    yield from reader.read()


def _until_damaged(
    stream: Iterator[tuple[Any, int, bytes]], damaged: Callable[[str], None]
) -> Iterator[tuple[Any, int, bytes]]:
    """The bag's messages up to the first one its file cannot give (damage past the
    point a bag opens at): what came before is kept, the damage reported."""
    n = 0
    while True:
        try:
            item = next(stream)
        except StopIteration:
            return
        except Exception as err:
            damaged(
                f"the bag cannot be read past its message {n} ({err}); the messages before it "
                "are used"
            )
            return
        n += 1
        yield item
