"""What changed since the saved map: saved plants seen again keep their id; saved plants not
seen where the camera clearly looked are gone (weeded, died, eaten), with a belief of being
gone; plants the survey started are new.

Where the camera looked is learned from the survey's own detections (geometry/view_area.py).
A saved plant inside that area at k frames and detected in n of them is gone with the
binomial posterior

    P(gone) = p0 e^n (1 - e)^(k - n) / (p0 e^n (1 - e)^(k - n) + (1 - p0) p_d^n (1 - p_d)^(k - n)),

p_d the share of in-view frames in which the plants clearly there (n >= 2) were detected, e
the rate of stray detections on a plant that is not there (config): a removed plant that
caught one detection of a neighbour or of clutter is still gone."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agrislam.config import SeasonConfig
from agrislam.geometry.view_area import ViewArea, log_odds_absent

__all__ = ["Changes", "ViewArea", "find_changes"]


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
    return log_odds_absent(seen, views, p_d, cfg.stray_rate, cfg.gone_prior)


def find_changes(
    saved_ids: np.ndarray,
    saved_xy: np.ndarray,
    frames_seen: np.ndarray,
    new: tuple[np.ndarray, np.ndarray, np.ndarray],
    poses: np.ndarray,
    seen_from: tuple[np.ndarray, np.ndarray],
    area: ViewArea,
    cfg: SeasonConfig,
) -> Changes:
    """Classify the saved plants (ids, map positions at the end of the survey), each seen
    in `frames_seen` frames of this survey, and the survey's new objects (ids, positions,
    frames seen), given the frame poses and what each saw (`seen_from`: rows of the poses,
    object ids). A new object is a new plant only when the same posterior says it is there
    (else it is `unconfirmed`: a stray detection's object)."""
    views = area.views(poses, saved_xy)
    hits = area.hits(poses, _rows_of(saved_ids, seen_from), saved_xy)
    p_d = _p_detect(hits, views, frames_seen >= 2)
    views = np.maximum(views, frames_seen)
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


def _p_detect(hits: np.ndarray, views: np.ndarray, there: np.ndarray) -> float:
    """The detection rate in view of the plants `there`: their in-area detections over
    their in-area frames, both counted in the same (shrunk) area frame by frame."""
    return float(np.clip(hits[there].sum() / max(views[there].sum(), 1), 0.05, 0.99))


def _rows_of(
    ids: np.ndarray, seen_from: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The sightings (pose rows, object ids) of the objects `ids`, as (pose rows, rows of
    `ids`); the others' left out."""
    pose_row, object_id = seen_from
    if not len(ids):
        return pose_row[:0], pose_row[:0]
    order = np.argsort(ids)
    row = order[np.minimum(np.searchsorted(ids, object_id, sorter=order), len(ids) - 1)]
    mine = ids[row] == object_id
    return pose_row[mine], row[mine]
