"""A survey as a ROS 2 bag (rosbags; no ROS installation needed): the records of any source
written as the messages `sources.rosbag` reads back, as a bare MCAP file or a rosbag2
folder (MCAP or sqlite3 storage)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np

from agrislam.geometry.se2 import compose, quaternion_from_yaw
from agrislam.io.ros.conventions import (
    META_TOPIC,
    POSE_COV_INDEX,
    TRUTH_TOPIC,
    UNKNOWN_COVARIANCE,
    measurement_class_id,
)
from agrislam.io.ros.messages import (
    DETECTION3D_ARRAY,
    ODOMETRY,
    STRING,
    TF_MESSAGE,
    MessageFactory,
    open_ros2_writer,
    seconds_to_ns,
)
from agrislam.io.ros.navsat import NAVSAT_FIX, navsat_message
from agrislam.io.sinks.log_lines import record_to_json
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


class _SurveyBagWriter:
    def __init__(self, writer: Any, factory: MessageFactory) -> None:
        self.writer, self.make = writer, factory
        self.connections: dict[str, Any] = {}
        self.odom_pose: dict[str, np.ndarray] = {}
        self.antenna: dict[str, np.ndarray | None] = {}  # robot -> antenna in tf_static
        self.last_ns = 0
        self.count = 0

    def _write(self, topic: str, msgtype: str, msg: Any, ns: int) -> None:
        conn = self.connections.get(topic)
        if conn is None:
            conn = self.writer.add_connection(topic, msgtype, typestore=self.make.store)
            self.connections[topic] = conn
        self.writer.write(conn, ns, self.make.serialize(msg, msgtype))
        self.count += 1

    def write(self, rec: Record) -> None:
        if isinstance(rec, Odometry):
            self._odometry(rec)
        elif isinstance(rec, Detections):
            self._detections(rec)
        elif isinstance(rec, GnssFix):
            self._gnss(rec)
        elif isinstance(rec, Meta | TruthPose | TruthObject):
            topic = META_TOPIC if isinstance(rec, Meta) else TRUTH_TOPIC
            if isinstance(rec, TruthPose):
                self.last_ns = max(self.last_ns, seconds_to_ns(rec.t))
            text = json.dumps(record_to_json(rec), separators=(",", ":"), allow_nan=False)
            self._write(topic, STRING, self.make.T[STRING](data=text), self.last_ns)
        else:
            raise TypeError(f"not a record: {rec!r}")

    def _odometry(self, rec: Odometry) -> None:
        if rec.pose is not None:
            pose = np.asarray(rec.pose, dtype=float)
        else:  # integrate the increments into the odometry-frame pose nav_msgs carries
            previous = self.odom_pose.get(rec.robot, np.zeros(3))
            pose = compose(previous, np.asarray(rec.delta, dtype=float))
        self.odom_pose[rec.robot] = pose
        cov6 = np.zeros((6, 6))
        if rec.cov is None:
            cov6[0, 0] = UNKNOWN_COVARIANCE
        else:
            cov6[np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)] = rec.cov
        msg = self.make.odometry(
            rec.t,
            f"{rec.robot}/odom",
            f"{rec.robot}/base_link",
            (pose[0], pose[1], 0.0),
            quaternion_from_yaw(pose[2]),
            cov6,
        )
        ns = seconds_to_ns(rec.t)
        self.last_ns = max(self.last_ns, ns)
        self._write(f"/{rec.robot}/odom", ODOMETRY, msg, ns)

    def _gnss(self, rec: GnssFix) -> None:
        """A fix on /<robot>/gnss/fix in frame <robot>/gnss_link, whose place on the robot
        goes to /tf_static when it is first given or changes."""
        ns = seconds_to_ns(rec.t)
        self.last_ns = max(self.last_ns, ns)
        frame = f"{rec.robot}/gnss_link"
        known = self.antenna.get(rec.robot, None)
        if rec.antenna is not None and (known is None or not np.array_equal(known, rec.antenna)):
            self.antenna[rec.robot] = np.asarray(rec.antenna, dtype=float)
            T = np.eye(4)
            T[:3, 3] = rec.antenna
            tf = self.make.tf_message([(rec.t, f"{rec.robot}/base_link", frame, T)])
            self._write("/tf_static", TF_MESSAGE, tf, ns)
        msg = navsat_message(self.make.T, self.make.header(rec.t, frame), rec)
        self._write(f"/{rec.robot}/gnss/fix", NAVSAT_FIX, msg, ns)

    def _detections(self, rec: Detections) -> None:
        frame = f"{rec.robot}/base_link"
        dets = []
        for d in rec.objects:
            xy, cov = _xy_cov(d)
            hyps: list[tuple[str | int, float]] = []
            if d.label is not None:
                hyps.append((d.label, math.nan if d.label_p is None else float(d.label_p)))
            hyps += [measurement_class_id(n, m) for n, m in d.attributes.items()]
            center = (xy[0], xy[1], 0.0)
            dets.append(self.make.detection3d(rec.t, frame, center, hyps, cov, d.truth_id or ""))
        msg = self.make.detection_array(rec.t, frame, dets)
        topic = (
            f"/{rec.robot}/{rec.sensor}/detections" if rec.sensor else f"/{rec.robot}/detections"
        )
        ns = seconds_to_ns(rec.t)
        self.last_ns = max(self.last_ns, ns)
        self._write(topic, DETECTION3D_ARRAY, msg, ns)


def _xy_cov(d: Detection) -> tuple[np.ndarray, np.ndarray | None]:
    """Position and covariance of a detection in either geometry (range/bearing sigmas
    become the ray-aligned covariance R diag(sr^2, (r sb)^2) R^T)."""
    if d.xy is not None:
        return np.asarray(d.xy, dtype=float), None if d.cov is None else np.asarray(
            d.cov, dtype=float
        )
    xy = d.position()
    if d.sigma_range is None or d.sigma_bearing is None:
        return xy, None
    c, s = math.cos(d.bearing), math.sin(d.bearing)  # type: ignore[arg-type]
    R = np.array([[c, -s], [s, c]])
    return xy, R @ np.diag([d.sigma_range**2, (d.range * d.sigma_bearing) ** 2]) @ R.T  # type: ignore[operator]


def write_survey_bag(
    records: Iterable[Record], path: str | Path, storage: Literal["mcap", "sqlite3"] = "mcap"
) -> int:
    """Write a survey as a ROS 2 bag; returns the number of messages.

    `path` ending in ``.mcap``: a bare MCAP file; otherwise a rosbag2 folder with the given
    storage. Odometry -> ``/<robot>/odom`` (nav_msgs/Odometry, frames ``<robot>/odom`` and
    ``<robot>/base_link``; deltas are integrated into poses; the increment covariance in
    the pose covariance, -1 in its first entry when unknown). Detections ->
    ``/<robot>/[<sensor>/]detections`` (vision_msgs 4.x Detection3DArray in the base frame:
    one hypothesis per attribute, ``attr=value`` with p as score, or
    ``attr=value;var=v``; a combined label as its own hypothesis (NaN score when it has
    none); the covariance in the hypothesis pose; truth_id as ``id``; range/bearing
    detections as position + ray covariance). Meta, TruthPose and TruthObject ->
    ``/agrislam/meta`` and ``/agrislam/truth`` as survey-log JSON lines (std_msgs/String).
    GNSS fixes -> ``/<robot>/gnss/fix`` (sensor_msgs/NavSatFix, io/ros/navsat.py), the antenna
    as ``/tf_static`` from ``<robot>/base_link`` to ``<robot>/gnss_link``.
    """
    with open_ros2_writer(path, storage) as writer:
        out = _SurveyBagWriter(writer, MessageFactory("humble"))
        for rec in records:
            out.write(rec)
        return out.count


class _Collected:
    """A bag writer's interface that keeps the messages instead of writing them."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, str, int, bytes]] = []

    def add_connection(self, topic: str, msgtype: str, **_: Any) -> tuple[str, str]:
        return topic, msgtype

    def write(self, conn: tuple[str, str], ns: int, data: bytes) -> None:
        self.messages.append((*conn, ns, bytes(data)))


def survey_messages(records: Iterable[Record]) -> Iterator[tuple[str, str, int, bytes]]:
    """The messages `write_survey_bag` writes, one record at a time, as (topic, type, log
    time in ns, CDR): a survey published live as it would be recorded."""
    kept = _Collected()
    out = _SurveyBagWriter(kept, MessageFactory("humble"))
    for rec in records:
        out.write(rec)
        yield from kept.messages
        kept.messages.clear()
