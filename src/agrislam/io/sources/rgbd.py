"""Detection2DArray frames of a bag through the RGB-D front end: each frame waits for its
camera's depth image (within the sync tolerance), then is projected with the camera's
CameraInfo, instance and colour images of the same instant (cameras paired with detection
topics by the longest common prefix of their names)."""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from agrislam.io.perception.camera import PinholeCamera
from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.perception.detector import ImageDetection, RgbdDetector
from agrislam.io.ros.messages import DETECTION2D_ARRAY, image_array
from agrislam.io.sources.bag_config import BagSourceConfig
from agrislam.io.sources.bag_report import BagReport, SkipError
from agrislam.io.sources.hypotheses import hypotheses, parse_hypotheses
from agrislam.records import Detection

IMAGES_KEPT = 64  # per image topic: the latest images a frame can be paired with


class FrameHost(Protocol):
    """What projecting a frame needs from the bag reader."""

    report: BagReport

    def robot_of(self, topic: str) -> tuple[str, str | None]: ...

    def to_base(self, frame: str, robot: str) -> np.ndarray: ...


@dataclass(frozen=True, slots=True)
class ProjectedFrame:
    """The detections of one Detection2DArray in the robot base frame, each with its index
    in the array."""

    topic: str
    stamp: float
    robot: str
    sensor: str | None
    objects: list[tuple[int, Detection]]


def _common_prefix(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a, b, strict=False):
        if x != y:
            break
        n += 1
    return n


def box_2d(bbox: Any) -> np.ndarray:
    """(x0, y0, x1, y1) of a BoundingBox2D: 4.x ``center.position.x``, older ``center.x``."""
    c = getattr(bbox.center, "position", bbox.center)
    hx, hy = 0.5 * float(bbox.size_x), 0.5 * float(bbox.size_y)
    return np.array([c.x - hx, c.y - hy, c.x + hx, c.y + hy], dtype=float)


class RgbdFrames:
    """The Detection2DArray topics of a bag, their cameras and the frames waiting for depth."""

    def __init__(
        self,
        bag: BagSourceConfig,
        perception: PerceptionConfig,
        host: FrameHost,
        roles: dict[str, list[str]],
        topic_type: dict[str, str],
    ) -> None:
        self.bag, self.perception, self.host = bag, perception, host
        self.images: dict[str, deque[tuple[float, np.ndarray, str]]] = {}
        self.cameras: dict[str, tuple[PinholeCamera, str]] = {}
        self.pending: dict[str, list[tuple[float, Any]]] = {}
        self._pair(roles, topic_type)

    def _pair(self, roles: dict[str, list[str]], topic_type: dict[str, str]) -> None:
        """Detection2D topic -> depth, camera_info, instance, rgb topics (longest common
        prefix of the topic names)."""

        def nearest(topic: str, candidates: list[str]) -> str | None:
            return max(candidates, key=lambda c: _common_prefix(topic, c), default=None)

        self.depth_of: dict[str, str | None] = {}
        self.info_of: dict[str, str | None] = {}
        self.instance_of: dict[str, str | None] = {}
        self.rgb_of: dict[str, str | None] = {}
        for t in roles["detections"]:
            if topic_type[t] != DETECTION2D_ARRAY:
                continue
            depth = nearest(t, roles["depth"])
            self.depth_of[t] = depth
            self.info_of[t] = nearest(depth or t, roles["camera_info"])
            self.instance_of[t] = nearest(t, roles["instance"])
            self.rgb_of[t] = nearest(t, roles["rgb"])

    # ------------------------------------------------------------------ input

    def camera_info(self, topic: str, msg: Any) -> None:
        k = np.asarray(msg.k if hasattr(msg, "k") else msg.K, dtype=float)
        d = np.asarray(msg.d if hasattr(msg, "d") else msg.D, dtype=float)
        try:
            camera = PinholeCamera.from_camera_info(k, msg.width, msg.height, d)
        except ValueError as err:
            raise SkipError("bad_camera_info", f"CameraInfo unusable: {err}") from None
        self.cameras[topic] = (camera, msg.header.frame_id)

    def add_image(self, topic: str, stamp: float, msg: Any) -> None:
        """Keep a depth, instance or colour image for the frames of its instant."""
        buf = self.images.setdefault(topic, deque(maxlen=IMAGES_KEPT))
        try:
            array = image_array(msg)
        except ValueError as err:
            raise SkipError("bad_image", str(err)) from None
        buf.append((stamp, array, msg.header.frame_id))

    def add_frame(self, topic: str, stamp: float, msg: Any) -> Iterator[ProjectedFrame]:
        """Queue a Detection2DArray; the frames of `topic` whose depth has come."""
        self.pending.setdefault(topic, []).append((stamp, msg))
        return self._resolve(topic)

    def waiting_on(self, depth_topic: str) -> Iterator[ProjectedFrame]:
        """After a depth image: the frames it (or a later one) settles."""
        for det_topic, depth in self.depth_of.items():
            if depth == depth_topic and det_topic in self.pending:
                yield from self._resolve(det_topic)

    def finish(self) -> Iterator[ProjectedFrame]:
        """At the end of the bag: every frame still waiting, or why it cannot be placed."""
        for topic in list(self.pending):
            yield from self._resolve(topic, final=True)

    # ------------------------------------------------------------- pairing

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

    def _resolve(self, topic: str, final: bool = False) -> Iterator[ProjectedFrame]:
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
                    raise SkipError(
                        "no_depth",
                        f"no depth image on {depth_topic or '(no depth topic)'} within "
                        f"{self.bag.sync_tolerance} s; frame dropped",
                    )
                projected = self._project(topic, stamp, msg, *found)
            except SkipError as skip:
                self.host.report.add(skip.kind, topic, stamp, skip.message)
                continue
            yield projected
        self.pending[topic] = keep

    # ---------------------------------------------------------- projection

    def _project(
        self, topic: str, stamp: float, msg: Any, depth: np.ndarray, frame: str
    ) -> ProjectedFrame:
        report = self.host.report
        robot, sensor = self.host.robot_of(topic)
        info = self.info_of.get(topic)
        if info not in self.cameras:
            raise SkipError(
                "no_camera_info", f"no valid CameraInfo on {info or '(none)'} yet; frame dropped"
            )
        camera, info_frame = self.cameras[info]  # type: ignore[index]
        if depth.shape != (camera.height, camera.width):
            raise SkipError(
                "bad_image",
                f"depth image {depth.shape[1]}x{depth.shape[0]} differs from CameraInfo "
                f"{camera.width}x{camera.height}",
            )
        camera = camera.with_mount(self.host.to_base(frame or info_frame, robot))
        instance = self._image_at(self.instance_of.get(topic), stamp)
        rgb = self._image_at(self.rgb_of.get(topic), stamp)
        if self.perception.green_filter and rgb is None:
            raise SkipError("no_rgb", "green filter on but no colour image within the tolerance")
        image_dets, extras = [], []
        for i, det in enumerate(msg.detections):
            hyps = hypotheses(det.results)
            try:
                attrs, label, label_p = parse_hypotheses(
                    [(c, s) for c, s, _ in hyps], self.bag.class_names
                )
            except SkipError as skip:
                raise SkipError(skip.kind, f"detection {i}: {skip.message}") from None
            mask = None if instance is None else (instance[0] == i + 1)
            image_dets.append(ImageDetection(box_2d(det.bbox), label or "", label_p or 0.0, mask))
            extras.append((attrs, label, label_p, getattr(det, "id", "") or None))
        result = RgbdDetector(camera, self.perception).detect(
            stamp, robot, depth, image_dets, None if rgb is None else rgb[0], sensor
        )
        dropped = set()
        for issue in result.issues:
            dropped.add(issue.index)
            if issue.kind == "beyond_range":
                report.filtered["beyond_range"] += 1
            else:
                report.add(issue.kind, topic, stamp, f"detection {issue.index}: {issue.message}")
        objects = []
        kept = [i for i in range(len(image_dets)) if i not in dropped]
        for i, obj in zip(kept, result.detections.objects, strict=True):
            attrs, label, label_p, truth_id = extras[i]
            merged = {**obj.attributes, **attrs}
            obj = dataclasses.replace(
                obj, attributes=merged, label=label, label_p=label_p, truth_id=truth_id
            )
            objects.append((i, obj))
        return ProjectedFrame(topic, stamp, robot, sensor, objects)
