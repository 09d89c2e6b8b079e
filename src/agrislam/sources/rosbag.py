"""ROS bags as a source: a rosbag2 folder (sqlite3 or MCAP), a bare .mcap file, or a ROS 1
.bag read as agrislam records (rosbags; no ROS installation needed). `sinks.rosbag` writes
a survey as a bag this reads back.

What the reader takes (topics named in `BagSourceConfig` or found by type):

- ``nav_msgs/Odometry``: one robot per topic (its namespace, ``/r2/odom`` -> ``r2``, else
  the configured robot name). The pose becomes ``Odometry.pose`` (or ``delta``); the
  x/y/yaw block of the pose covariance is the covariance of the motion since the previous
  message (``odom_covariance="increment"``, what drivers with a fixed covariance publish),
  or the difference of consecutive absolute covariances (``"absolute"``, as an EKF
  publishes), or ignored (``"ignore"``). ``covariance[0] == -1`` means unknown.
- ``tf`` / ``tf_static``: the camera-to-base transform (or ``camera_to_base`` in the config).
- ``vision_msgs/Detection3DArray`` in the vision_msgs 4.x or the older Foxy/Noetic layout:
  the box centre (or, with an empty box, the hypothesis pose) in the header frame,
  transformed to the base frame; the x/y block of the hypothesis pose covariance when
  present; hypotheses as below.
- ``vision_msgs/Detection2DArray`` plus an aligned depth ``sensor_msgs/Image`` and its
  ``CameraInfo`` (and optionally an instance image whose pixel value k marks detection
  k - 1 of the array with the same stamp): projected by the RGB-D front end.
- ``/agrislam/meta`` and ``/agrislam/truth`` (``std_msgs/String``): a survey log line each
  (shared/spec/log-format.md), as ``write_survey_bag`` records meta and ground truth.

Hypotheses: a ``class_id`` of the form ``attr=value`` is a discrete measurement of that
attribute with p = score; ``attr=value;var=v`` a continuous one; any other ``class_id`` is
a combined detector label (the best-scoring one wins) that the label map splits. Numeric
ids (Noetic ``int64 id``) are named through ``class_names``. ``Detection3D.id`` carries
the record's ``truth_id``.

Bad input never stops the reader: every problem becomes a `BagIssue` naming the topic and
stamp in the returned `BagReport`, and the rest of the bag is read. Records are yielded in
time order (header stamps; meta first), after the bag has been read through once: records
are small, images are turned into detections as they stream past.
"""

from __future__ import annotations

import dataclasses
import io
import math
import re
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import MessageDefinitionFormat

from agrislam.config import AgrislamConfig, FieldSchema
from agrislam.geometry.se2 import between
from agrislam.perception.camera import (
    PinholeCamera,
    rigid_transform,
    rotation_from_quaternion,
)
from agrislam.perception.config import PerceptionConfig
from agrislam.perception.detector import ImageDetection, RgbdDetector
from agrislam.perception.label_map import LabelMap, UnknownLabelError
from agrislam.records import (
    Detection,
    Detections,
    Measurement,
    Meta,
    Odometry,
    Record,
    TruthObject,
    TruthPose,
)
from agrislam.ros.conventions import (
    META_TOPIC,
    POSE_COV_INDEX,
    TRUTH_TOPIC,
    UNKNOWN_COVARIANCE,
    is_measurement_class_id,
    measurement_of_class_id,
)
from agrislam.ros.messages import (
    CAMERA_INFO,
    DETECTION2D_ARRAY,
    DETECTION3D_ARRAY,
    IMAGE,
    ODOMETRY,
    STRING,
    TF_MESSAGE,
    Layout,
    image_array,
    seconds_to_ns,
    stamp_to_seconds,
    typestore,
)
from agrislam.sources.jsonl import LogError, read_log


class BagSourceConfig(BaseModel):
    """Which topics of a bag mean what, and how to read them."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    robot: str = Field("r1", description="robot of topics without a robot namespace")
    odometry_topics: list[str] | None = Field(None, description="default: every nav_msgs/Odometry")
    detection_topics: list[str] | None = Field(
        None, description="Detection3DArray / Detection2DArray topics; default: all of them"
    )
    depth_topics: list[str] | None = Field(
        None, description="default: Images with 'depth' in the name"
    )
    camera_info_topics: list[str] | None = Field(None, description="default: every CameraInfo")
    instance_topics: list[str] | None = Field(
        None,
        description="instance images (pixel k = detection k-1); default: 'instance' in the name",
    )
    rgb_topics: list[str] | None = Field(
        None, description="colour images for the green filter; default: 'color'/'rgb' in the name"
    )
    meta_topic: str = META_TOPIC
    truth_topic: str = TRUTH_TOPIC
    base_frame: str | None = Field(
        None, description="robot base frame; default: the odometry child_frame_id, else base_link"
    )
    camera_to_base: tuple[float, float, float, float, float, float, float] | None = Field(
        None, description="x y z qx qy qz qw of frames tf does not connect to the base"
    )
    odom_covariance: Literal["increment", "absolute", "ignore"] = "increment"
    odometry_form: Literal["pose", "delta"] = "pose"
    detection_geometry: Literal["xy", "range_bearing"] = "xy"
    class_names: dict[str, str] = Field(
        default_factory=dict, description="numeric class id -> class name"
    )
    split_labels: bool = Field(True, description="split combined labels with the label map")
    sync_tolerance: float = Field(0.02, ge=0.0, description="s between detections and depth")
    vision_msgs_layout: Layout = Field(
        "humble", description="layout for bags that carry no message definitions"
    )
    perception: PerceptionConfig | None = Field(
        None, description="RGB-D front end; default: from the run's sensor settings"
    )


# ---------------------------------------------------------------------------- report


@dataclass(frozen=True, slots=True)
class BagIssue:
    kind: str  # missing_topic, unknown_type, undecodable, time_backwards, no_depth, ...
    topic: str | None
    stamp: float | None
    message: str

    def __str__(self) -> str:
        where = self.topic or "bag"
        if self.stamp is not None:
            where += f" @ {self.stamp:.6f}"
        return f"{where}: {self.kind}: {self.message}"


@dataclass
class BagReport:
    """What a bag read found: topics used per role, messages, records, issues, filtered
    detections (beyond the range cut-off: by design, not bad input)."""

    path: str
    roles: dict[str, list[str]] = field(default_factory=dict)
    messages: Counter[str] = field(default_factory=Counter)
    records: Counter[str] = field(default_factory=Counter)
    filtered: Counter[str] = field(default_factory=Counter)
    issues: list[BagIssue] = field(default_factory=list)
    max_issues: int = 10_000

    @property
    def counts(self) -> Counter[str]:
        return Counter(i.kind for i in self.issues)

    def add(self, kind: str, topic: str | None, stamp: float | None, message: str) -> None:
        if len(self.issues) < self.max_issues:
            self.issues.append(BagIssue(kind, topic, stamp, message))

    def summary(self) -> str:
        recs = ", ".join(f"{n} {k}" for k, n in sorted(self.records.items())) or "no records"
        head = f"{self.path}: {recs}"
        if self.filtered:
            head += "; filtered " + ", ".join(f"{n} {k}" for k, n in self.filtered.items())
        if not self.issues:
            return head + "; no issues"
        lines = [f"{head}; {len(self.issues)} issues:"]
        lines += [f"  {i}" for i in self.issues[:20]]
        if len(self.issues) > 20:
            lines.append(f"  ... {len(self.issues) - 20} more")
        return "\n".join(lines)


class _SkipError(Exception):
    """One message (or detection) cannot be used; the reason goes into the report."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind, self.message = kind, message


# ----------------------------------------------------------------------- conversions


def _pose_matrix(pose: Any) -> np.ndarray:
    """geometry_msgs/Pose (or Transform) as a 4x4 transform."""
    p = getattr(pose, "position", None) or pose.translation
    q = getattr(pose, "orientation", None) or pose.rotation
    return rigid_transform(rotation_from_quaternion((q.x, q.y, q.z, q.w)), (p.x, p.y, p.z))


def _planar(T: np.ndarray) -> np.ndarray:
    """x, y, yaw of a 4x4 transform."""
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])


def _parse_hypotheses(
    hyps: list[tuple[str, float]], class_names: dict[str, str]
) -> tuple[dict[str, Measurement], str | None, float | None]:
    """Attributes (best score per attribute) and the best combined label of hypotheses."""
    attributes: dict[str, Measurement] = {}
    best: dict[str, float] = {}
    label, label_p = None, None
    for class_id, score in hyps:
        class_id = class_names.get(class_id, class_id)
        if not is_measurement_class_id(class_id):
            if label is None or (not math.isnan(score) and score > (label_p or -1.0)):
                label, label_p = class_id, (None if math.isnan(score) else score)
            continue
        try:
            name, m = measurement_of_class_id(class_id, score)
        except ValueError as err:
            raise _SkipError("bad_hypothesis", str(err)) from None
        if score > best.get(name, -1.0):
            attributes[name], best[name] = m, score
    return attributes, label, label_p


def _hypotheses(results: Any) -> list[tuple[str, float, Any]]:
    """(class_id, score, PoseWithCovariance) of vision_msgs results in either layout:
    4.x ``hypothesis.class_id`` or Foxy/Noetic ``id`` (string or int64)."""
    out = []
    for r in results:
        h = getattr(r, "hypothesis", r)
        class_id = h.class_id if hasattr(h, "class_id") else str(h.id)
        out.append((class_id, float(h.score), r.pose))
    return out


def _box_2d(bbox: Any) -> np.ndarray:
    """(x0, y0, x1, y1) of a BoundingBox2D: 4.x ``center.position.x``, older ``center.x``."""
    c = getattr(bbox.center, "position", bbox.center)
    hx, hy = 0.5 * float(bbox.size_x), 0.5 * float(bbox.size_y)
    return np.array([c.x - hx, c.y - hy, c.x + hx, c.y + hy], dtype=float)


# ------------------------------------------------------------------------- transforms


class TransformTree:
    """The latest transform of every frame to its parent (tf/tf_static)."""

    def __init__(self) -> None:
        self.parent: dict[str, tuple[str, np.ndarray]] = {}

    def set(self, parent: str, child: str, T: np.ndarray) -> None:
        self.parent[child.lstrip("/")] = (parent.lstrip("/"), T)

    def _to_root(self, frame: str) -> tuple[str, np.ndarray]:
        T = np.eye(4)
        seen = {frame}
        while frame in self.parent:
            frame, T_parent = self.parent[frame][0], self.parent[frame][1] @ T
            T = T_parent
            if frame in seen:
                raise ValueError(f"tf has a cycle through {frame!r}")
            seen.add(frame)
        return frame, T

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """T_target_source (maps points in `source` to `target`), None if not connected."""
        root_s, T_rs = self._to_root(source.lstrip("/"))
        root_t, T_rt = self._to_root(target.lstrip("/"))
        if root_s != root_t:
            return None
        return np.linalg.solve(T_rt, T_rs)


# ----------------------------------------------------------------------------- reader


_UNTIMED = 3
_KIND_RANK = {Meta: -1, TruthPose: 0, Odometry: 1, Detections: 2, TruthObject: _UNTIMED}


def _common_prefix(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a, b, strict=False):
        if x != y:
            break
        n += 1
    return n


class _BagReader:
    def __init__(self, path: Path, config: AgrislamConfig, bag: BagSourceConfig) -> None:
        self.path, self.config, self.bag = path, config, bag
        self.report = BagReport(str(path))
        self.store = typestore(bag.vision_msgs_layout)
        self.perception = bag.perception or PerceptionConfig.from_config(config)
        self.schema: FieldSchema | None = config.field_schema()
        self.tree = TransformTree()
        self.base_frames: dict[str, str] = {}
        self.last_stamp: dict[str, float] = {}
        self.odom_state: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
        self.images: dict[str, deque[tuple[float, np.ndarray, str]]] = {}
        self.cameras: dict[str, tuple[PinholeCamera, str]] = {}
        self.pending: dict[str, list[tuple[float, Any]]] = {}
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

    def _robot_of(self, topic: str, odometry: bool = False) -> tuple[str, str | None]:
        """(robot, sensor) of a topic: namespace -> robot, the rest of it -> sensor."""
        parts = topic.strip("/").split("/")[:-1]
        if odometry:
            return (parts[0] if parts else self.bag.robot), None
        robots = self.odom_robots
        if parts and parts[0] in robots:
            return parts[0], "/".join(parts[1:]) or None
        if len(robots) > 1:
            raise _SkipError(
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
        try:
            reader = AnyReader([self.path], default_typestore=self.store)
            reader.open()
        except AnyReaderError as err:
            raise ValueError(f"{self.path}: not a readable ROS bag: {err}") from None
        try:
            topics = {name: info.msgtype for name, info in reader.topics.items()}
            roles = self._roles(topics)
            self.report.roles = roles
            self.role_of = {t: role for role, ts in roles.items() for t in ts}
            self.topic_type = topics
            self.odom_robots = {self._robot_of(t, odometry=True)[0] for t in roles["odometry"]}
            self._pair_cameras(roles)
            conns = [c for c in reader.connections if c.topic in self.role_of]
            stream = reader.messages(connections=conns) if conns else iter(())  # () = all
            for conn, logtime, raw in stream:
                self.report.messages[conn.topic] += 1
                try:
                    msg = self._deserialize(reader, conn, raw)
                except _SkipError as skip:
                    self.report.add(skip.kind, conn.topic, logtime * 1e-9, skip.message)
                    continue
                self._dispatch(conn.topic, msg, logtime)
            for topic in list(self.pending):
                self._resolve_pending(topic, final=True)
        finally:
            reader.close()
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
                raise _SkipError(
                    "undecodable", f"cannot decode {conn.msgtype}: {err}{hint}"
                ) from None

    def _dispatch(self, topic: str, msg: Any, logtime: int) -> None:
        role = self.role_of[topic]
        if role in ("meta", "truth"):
            self._json_record(topic, msg, logtime)
            return
        if role == "tf":
            for tr in msg.transforms:
                self.tree.set(tr.header.frame_id, tr.child_frame_id, _pose_matrix(tr.transform))
            return
        stamp = stamp_to_seconds(msg.header.stamp)
        last = self.last_stamp.get(topic)
        if last is not None and stamp < last:
            self.report.add(
                "time_backwards",
                topic,
                stamp,
                f"stamp is {last - stamp:.6f} s before the previous one",
            )
            return
        self.last_stamp[topic] = stamp
        try:
            if role == "odometry":
                self._odometry(topic, stamp, msg)
            elif role == "detections" and self.topic_type[topic] == DETECTION3D_ARRAY:
                self._detections_3d(topic, stamp, msg)
            elif role == "detections":
                self.pending.setdefault(topic, []).append((stamp, msg))
                self._resolve_pending(topic)
            elif role == "camera_info":
                self._camera_info(topic, stamp, msg)
            else:  # depth, instance, rgb images
                buf = self.images.setdefault(topic, deque(maxlen=64))
                try:
                    array = image_array(msg)
                except ValueError as err:
                    raise _SkipError("bad_image", str(err)) from None
                buf.append((stamp, array, msg.header.frame_id))
                if role == "depth":
                    for det_topic, depth_topic in self.depth_of.items():
                        if depth_topic == topic and det_topic in self.pending:
                            self._resolve_pending(det_topic)
        except _SkipError as skip:
            self.report.add(skip.kind, topic, stamp, skip.message)

    def _emit(self, rec: Record, logtime: int | None = None) -> None:
        """Keep a record with its sort key: integer ns (so a stamp and a JSON time of the
        same instant tie), robot, kind, arrival. Untimed records sort where they were logged
        (after the records of that instant), those logged at 0 before everything."""
        robot = getattr(rec, "robot", None)
        if robot is not None and robot not in self.robot_order:
            self.robot_order.append(robot)
        if isinstance(rec, Meta | TruthObject):
            ns = logtime if (logtime and isinstance(rec, TruthObject)) else -(2**63)
        else:
            ns = seconds_to_ns(rec.t)  # type: ignore[union-attr]
        self.records.append((ns, robot, _KIND_RANK[type(rec)], len(self.records), rec))

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
        try:
            (rec,) = list(read_log(io.BytesIO(msg.data.encode("utf-8"))))
        except (LogError, ValueError) as err:
            self.report.add("bad_record", topic, logtime * 1e-9, str(err))
            return
        if isinstance(rec, Meta):
            if rec.schema is not None and self.schema is None:
                self.schema = rec.schema
                self._build_label_map()
            self.robot_order[:0] = [r for r in rec.robots if r not in self.robot_order]
        self._emit(rec, logtime)

    def _odometry(self, topic: str, stamp: float, msg: Any) -> None:
        robot, _ = self._robot_of(topic, odometry=True)
        if msg.child_frame_id:
            self.base_frames.setdefault(robot, msg.child_frame_id.lstrip("/"))
        pose = _planar(_pose_matrix(msg.pose.pose))
        full = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
        prev = self.odom_state.get(robot)
        self.odom_state[robot] = (pose, full)
        cov = self._increment_cov(topic, stamp, full, pose, prev)
        if self.bag.odometry_form == "delta":
            delta = pose if prev is None else between(prev[0], pose)
            self._emit(Odometry(stamp, robot, delta=delta, cov=cov))
        else:
            self._emit(Odometry(stamp, robot, pose=pose, cov=cov))

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
        if mode == "absolute":
            if prev is None:
                return cov
            # the increment's covariance: growth of the absolute one, in the previous frame
            c, s = math.cos(prev[0][2]), math.sin(prev[0][2])
            R = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
            before = prev[1][np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)]  # type: ignore[index]
            grown = R @ (cov - before) @ R.T
            w, V = np.linalg.eigh(0.5 * (grown + grown.T))
            return (V * np.clip(w, 0.0, None)) @ V.T
        moved = prev is not None and not np.allclose(prev[0], pose, rtol=0.0, atol=1e-12)
        if moved and not cov.any():
            self.report.add(
                "zero_covariance", topic, stamp,
                "all-zero pose covariance for a motion; the configured default is used",
            )  # fmt: skip
            return None
        return cov

    def _to_base(self, frame: str, robot: str) -> np.ndarray:
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
        raise _SkipError(
            "no_transform",
            f"no transform from frame {frame!r} to the base frame {base!r} "
            "(record tf_static, or set camera_to_base in the config)",
        )

    def _detections_3d(self, topic: str, stamp: float, msg: Any) -> None:
        robot, sensor = self._robot_of(topic)
        objects = []
        for i, det in enumerate(msg.detections):
            frame = msg.header.frame_id or det.header.frame_id
            T = self._to_base(frame, robot)
            hyps = _hypotheses(det.results)
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
                attrs, label, label_p = _parse_hypotheses(
                    [(c, s) for c, s, _ in hyps], self.bag.class_names
                )
            except _SkipError as skip:
                self.report.add(skip.kind, topic, stamp, f"detection {i}: {skip.message}")
                continue
            truth_id = getattr(det, "id", "") or getattr(det, "tracking_id", "") or None
            obj = self._geometry(point[:2], cov)
            obj = Detection(
                **obj, attributes=attrs, label=label, label_p=label_p, truth_id=truth_id
            )
            objects.append(self._semantics(obj, topic, stamp, i))
        self._emit(Detections(stamp, robot, tuple(objects), sensor))

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

    def _camera_info(self, topic: str, stamp: float, msg: Any) -> None:
        k = np.asarray(msg.k if hasattr(msg, "k") else msg.K, dtype=float)
        d = np.asarray(msg.d if hasattr(msg, "d") else msg.D, dtype=float)
        try:
            camera = PinholeCamera.from_camera_info(k, msg.width, msg.height, d)
        except ValueError as err:
            raise _SkipError("bad_camera_info", f"CameraInfo unusable: {err}") from None
        self.cameras[topic] = (camera, msg.header.frame_id)

    def _pair_cameras(self, roles: dict[str, list[str]]) -> None:
        """Detection2D topic -> depth, camera_info, instance, rgb topics (longest common
        prefix of the topic names)."""

        def nearest(topic: str, candidates: list[str]) -> str | None:
            return max(candidates, key=lambda c: _common_prefix(topic, c), default=None)

        self.depth_of: dict[str, str | None] = {}
        self.info_of: dict[str, str | None] = {}
        self.instance_of: dict[str, str | None] = {}
        self.rgb_of: dict[str, str | None] = {}
        for t in roles["detections"]:
            if self.topic_type[t] != DETECTION2D_ARRAY:
                continue
            depth = nearest(t, roles["depth"])
            self.depth_of[t] = depth
            self.info_of[t] = nearest(depth or t, roles["camera_info"])
            self.instance_of[t] = nearest(t, roles["instance"])
            self.rgb_of[t] = nearest(t, roles["rgb"])

    def _image_at(self, topic: str | None, stamp: float) -> tuple[np.ndarray, str] | None:
        if topic is None:
            return None
        best = None
        for s, img, frame in self.images.get(topic, ()):
            if abs(s - stamp) <= self.bag.sync_tolerance and (
                best is None or abs(s - stamp) < abs(best[0] - stamp)
            ):
                best = (s, img, frame)
        return None if best is None else (best[1], best[2])

    def _resolve_pending(self, topic: str, final: bool = False) -> None:
        """Project the Detection2D arrays of `topic` whose depth image has arrived (or, at
        the end of the bag or once later depth images exist, report them)."""
        depth_topic = self.depth_of.get(topic)
        newest = max((s for s, _, _ in self.images.get(depth_topic or "", ())), default=-math.inf)
        keep = []
        for stamp, msg in self.pending.get(topic, []):
            found = self._image_at(depth_topic, stamp)
            if found is None and not final and newest <= stamp + self.bag.sync_tolerance:
                keep.append((stamp, msg))  # its depth image may still come
                continue
            try:
                if found is None:
                    raise _SkipError(
                        "no_depth",
                        f"no depth image on {depth_topic or '(no depth topic)'} within "
                        f"{self.bag.sync_tolerance} s; frame dropped",
                    )
                self._detections_2d(topic, stamp, msg, *found)
            except _SkipError as skip:
                self.report.add(skip.kind, topic, stamp, skip.message)
        self.pending[topic] = keep

    def _detections_2d(
        self, topic: str, stamp: float, msg: Any, depth: np.ndarray, frame: str
    ) -> None:
        robot, sensor = self._robot_of(topic)
        info = self.info_of.get(topic)
        if info not in self.cameras:
            raise _SkipError(
                "no_camera_info", f"no valid CameraInfo on {info or '(none)'} yet; frame dropped"
            )
        camera, info_frame = self.cameras[info]  # type: ignore[index]
        if depth.shape != (camera.height, camera.width):
            raise _SkipError(
                "bad_image",
                f"depth image {depth.shape[1]}x{depth.shape[0]} differs from CameraInfo "
                f"{camera.width}x{camera.height}",
            )
        camera = camera.with_mount(self._to_base(frame or info_frame, robot))
        instance = self._image_at(self.instance_of.get(topic), stamp)
        rgb = self._image_at(self.rgb_of.get(topic), stamp)
        if self.perception.green_filter and rgb is None:
            raise _SkipError("no_rgb", "green filter on but no colour image within the tolerance")
        image_dets, extras = [], []
        for i, det in enumerate(msg.detections):
            hyps = _hypotheses(det.results)
            try:
                attrs, label, label_p = _parse_hypotheses(
                    [(c, s) for c, s, _ in hyps], self.bag.class_names
                )
            except _SkipError as skip:
                raise _SkipError(skip.kind, f"detection {i}: {skip.message}") from None
            mask = None if instance is None else (instance[0] == i + 1)
            image_dets.append(ImageDetection(_box_2d(det.bbox), label or "", label_p or 0.0, mask))
            extras.append((attrs, label, label_p, getattr(det, "id", "") or None))
        result = RgbdDetector(camera, self.perception).detect(
            stamp, robot, depth, image_dets, None if rgb is None else rgb[0], sensor
        )
        dropped = set()
        for issue in result.issues:
            dropped.add(issue.index)
            if issue.kind == "beyond_range":
                self.report.filtered["beyond_range"] += 1
            else:
                self.report.add(
                    issue.kind, topic, stamp, f"detection {issue.index}: {issue.message}"
                )
        objects = []
        kept = [i for i in range(len(image_dets)) if i not in dropped]
        for i, obj in zip(kept, result.detections.objects, strict=True):
            attrs, label, label_p, truth_id = extras[i]
            merged = {**obj.attributes, **attrs}
            obj = dataclasses.replace(
                obj, attributes=merged, label=label, label_p=label_p, truth_id=truth_id
            )
            objects.append(self._semantics(obj, topic, stamp, i))
        self._emit(Detections(stamp, robot, tuple(objects), sensor))


def open_bag_source(
    path: str | Path,
    config: AgrislamConfig | None = None,
    bag: BagSourceConfig | None = None,
) -> tuple[Iterator[Record], BagReport]:
    """Records of a ROS bag in time order, and the report that fills as they are read.

    `path`: a rosbag2 folder (sqlite3 or MCAP storage), a bare ``.mcap`` file, or a ROS 1
    ``.bag``. `config` gives the schema, label map and sensor defaults; `bag` the topics.
    The bag is read on the first ``next()``; the report is complete once the iterator is.
    """
    reader = _BagReader(Path(path), config or AgrislamConfig(), bag or BagSourceConfig())

    def records() -> Iterator[Record]:
        yield from reader.read()

    return records(), reader.report


# ----------------------------------------------------------------------------- writer


