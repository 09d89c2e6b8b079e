"""What changed since the saved map (issue 15): saved plants seen again keep their id;
saved plants not seen where the camera clearly looked are gone (weeded, died, eaten), with
a belief of being gone; plants the survey started are new.

Where the camera looked is learned from the survey itself: the robot-frame area its
detections filled (range and bearing quantiles), shrunk by a margin. A saved plant inside
it at k frames and detected in n of them is gone with the binomial posterior

    P(gone) = p0 e^n (1 - e)^(k - n) / (p0 e^n (1 - e)^(k - n) + (1 - p0) p_d^n (1 - p_d)^(k - n)),

p_d the share of in-view frames in which the plants clearly there (n >= 2) were detected,
e the rate of stray detections associated to a plant that is not there (config): a
removed plant that caught one detection of a neighbour or of clutter is still gone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from agrislam.config import SeasonConfig


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
        return cls((r_lo + margin, r_hi - margin), (b_lo + turn, b_hi - turn))

    def views(self, poses: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(k,) frames (poses (m, 3)) in which each map point (k, 2) was inside the area."""
        counts = np.zeros(len(xy), dtype=np.int64)
        if not len(poses) or not len(xy):
            return counts
        near = cKDTree(poses[:, :2]).query_ball_point(xy, self.range[1])
        for k, frames in enumerate(near):
            if frames:
                local = _in_robot_frames(poses[frames], xy[k])
                r = np.hypot(local[:, 0], local[:, 1])
                b = np.arctan2(local[:, 1], local[:, 0])
                inside = (r >= self.range[0]) & (r <= self.range[1])
                inside &= (b >= self.bearing[0]) & (b <= self.bearing[1])
                counts[k] = int(inside.sum())
        return counts


@dataclass(frozen=True, slots=True)
class Changes:
    """Saved plants seen again, gone (with P(gone)), unseen (not looked at), and new ones."""

    kept: np.ndarray
    gone: np.ndarray
    p_gone: np.ndarray  # (len(gone),)
    unseen: np.ndarray
    new: np.ndarray
    p_detect: float
    unconfirmed: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))

    def as_dict(self) -> dict[str, object]:
        return {
            "kept": len(self.kept),
            "gone": len(self.gone),
            "new": len(self.new),
            "not_looked_at": len(self.unseen),
            "unconfirmed": len(self.unconfirmed),
            "p_detect": self.p_detect,
        }


def _log_odds_gone(
    seen: np.ndarray, views: np.ndarray, p_d: float, cfg: SeasonConfig
) -> np.ndarray:
    """log P(not there) - log P(there) after `seen` detections in `views` frames in view
    (the binomial posterior of the module docstring)."""
    p0, e = cfg.gone_prior, cfg.stray_rate
    miss = views - seen
    log_gone = np.log(p0) + seen * np.log(e) + miss * np.log1p(-e)
    log_there = np.log1p(-p0) + seen * np.log(p_d) + miss * np.log1p(-p_d)
    return log_gone - log_there


def find_changes(
    saved_ids: np.ndarray,
    saved_xy: np.ndarray,
    frames_seen: np.ndarray,
    new: tuple[np.ndarray, np.ndarray, np.ndarray],
    poses: np.ndarray,
    area: ViewArea,
    cfg: SeasonConfig,
) -> Changes:
    """Classify the saved plants (ids, map positions at the end of the survey), each seen
    in `frames_seen` frames of this survey, and the survey's new objects (ids, positions,
    frames seen), given the frame poses. A new object is a new plant only when the same
    posterior says it is there (else it is `unconfirmed`: a stray detection's object)."""
    views = np.maximum(area.views(poses, saved_xy), frames_seen)
    there = frames_seen >= 2
    p_d = float(np.clip(frames_seen[there].sum() / max(views[there].sum(), 1), 0.05, 0.99))
    p_gone = 1.0 / (1.0 + np.exp(-_log_odds_gone(frames_seen, views, p_d, cfg)))
    gone = p_gone >= cfg.gone_threshold
    seen = (frames_seen > 0) & ~gone
    new_ids, new_xy, new_seen = new
    new_views = np.maximum(area.views(poses, new_xy), new_seen)
    p_new = 1.0 / (1.0 + np.exp(_log_odds_gone(new_seen, new_views, p_d, cfg)))
    confirmed = p_new >= cfg.gone_threshold
    return Changes(
        kept=saved_ids[seen],
        gone=saved_ids[gone],
        p_gone=p_gone[gone],
        unseen=saved_ids[~seen & ~gone],
        new=np.asarray(new_ids, dtype=np.int64)[confirmed],
        p_detect=p_d,
        unconfirmed=np.asarray(new_ids, dtype=np.int64)[~confirmed],
    )


def _in_robot_frames(poses: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(m, 2) the map point xy in the frame of each robot pose (m, 3)."""
    d = xy - poses[:, :2]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
