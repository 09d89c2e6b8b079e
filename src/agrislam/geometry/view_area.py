"""Where the camera looked, and what a detection count there says about existence.

The camera's seen area is learned from a survey's own detections (in the robot frame:
range and bearing quantiles), so no camera model is needed. A map point inside it at k
frames and detected in n of them is there, against not there (nothing but stray
detections: clutter, a neighbour), with the binomial likelihoods

    P(n | there) = p_d^n (1 - p_d)^(k - n),    P(n | not there) = e^n (1 - e)^(k - n),

p_d the detection rate of a plant in view and e the rate of stray detections on a point.
Used for plants gone between surveys (season/changes.py) and for the clutter of one survey
(maintenance/).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True, slots=True)
class ViewArea:
    """The camera's seen area in the robot frame: range and bearing bounds."""

    range: tuple[float, float]
    bearing: tuple[float, float]

    @classmethod
    def learned(cls, robot_xy: np.ndarray, margin: float) -> ViewArea:
        r = np.hypot(robot_xy[:, 0], robot_xy[:, 1])
        b = np.arctan2(robot_xy[:, 1], robot_xy[:, 0])
        r_lo, r_hi = np.quantile(r, [0.02, 0.98])
        b_lo, b_hi = np.quantile(b, [0.02, 0.98])
        turn = margin / max(r_hi, 1e-6)
        # shrunk where the detection rate falls (the far edge, the sides); the near edge is
        # kept: it holds views of headland turns, the only ones of plants at a row's end
        return cls((r_lo, r_hi - margin), (b_lo + turn, b_hi - turn))

    def views(self, poses: np.ndarray, xy: np.ndarray, chunk: int = 1024) -> np.ndarray:
        """(k,) frames (poses (m, 3)) in which each map point (k, 2) was inside the area;
        `chunk` points at a time, so that a whole field's (point, near frame) pairs are never held
        at once."""
        counts = np.zeros(len(xy), dtype=np.int64)
        if not len(poses) or not len(xy):
            return counts
        tree = cKDTree(poses[:, :2])
        for start in range(0, len(xy), chunk):
            part = xy[start : start + chunk]
            near = tree.query_ball_point(part, self.range[1])
            per_point = np.fromiter(map(len, near), dtype=np.intp, count=len(near))
            frames = np.fromiter(chain.from_iterable(near), dtype=np.intp, count=per_point.sum())
            point = np.repeat(np.arange(len(part)), per_point)
            inside = self.contains(in_robot_frames(poses[frames], part[point]))
            counts[start : start + len(part)] = np.bincount(point[inside], minlength=len(part))
        return counts

    def hits(
        self, poses: np.ndarray, sightings: tuple[np.ndarray, np.ndarray], xy: np.ndarray
    ) -> np.ndarray:
        """(k,) frames (poses (m, 3)) in which each map point (k, 2) was inside the area and
        detected: the sightings (rows of the poses, rows of the points; each pair once)
        counted where `views` counts, so that hits <= views."""
        pose_row, point_row = sightings
        inside = self.contains(in_robot_frames(poses[pose_row], xy[point_row]))
        return np.bincount(point_row[inside], minlength=len(xy))

    def in_view(self, pose: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(k,) whether each map point (k, 2) is inside the area seen from one pose (3,)."""
        return self.contains(in_robot_frames(np.asarray(pose, dtype=float)[None, :], xy))

    def contains(self, local: np.ndarray) -> np.ndarray:
        """(k,) whether each robot-frame point (k, 2) is inside the area."""
        r = np.hypot(local[:, 0], local[:, 1])
        b = np.arctan2(local[:, 1], local[:, 0])
        inside = (r >= self.range[0]) & (r <= self.range[1])
        return inside & (b >= self.bearing[0]) & (b <= self.bearing[1])


def log_odds_absent(
    seen: np.ndarray, views: np.ndarray, p_d: float, e: float, p_absent: float
) -> np.ndarray:
    """log P(not there) - log P(there) after `seen` detections in `views` frames in view,
    with the prior P(not there) = `p_absent` (the binomial posterior of the docstring)."""
    miss = views - seen
    log_absent = np.log(p_absent) + seen * np.log(e) + miss * np.log1p(-e)
    log_there = np.log1p(-p_absent) + seen * np.log(p_d) + miss * np.log1p(-p_d)
    return log_absent - log_there


def in_robot_frames(poses: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(m, 2) the map point xy (2,) in the frame of each robot pose (m, 3); or (k, 2) the
    map points xy (k, 2) in the frame of one pose (1, 3); or (m, 2) each map point xy
    (m, 2) in the frame of its own pose (m, 3)."""
    d = xy - poses[:, :2]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
