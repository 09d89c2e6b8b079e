"""Merging (sec. 2.6.3): objects closer than d_inter are one. Without a field prior, two
landmarks a range sigma apart are detected together in nearly every frame that sees them,
one object split in two hardly ever: only objects rarely detected in the same frame merge."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from agrislam.mapping.objects import NO_OBJECTS, ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex

# two near objects seen in one frame in more than this share of the frames that saw the
# less-seen one are two (a split object's parts are seen together only when an outlier or a
# neighbour's detection goes to one of them)
TOGETHER_SHARE = 0.1
# frames the least seen object of a crowd must have before its company is judged (a
# landmark's object in the arena has hundreds; a crowd's ghost lives on tens)
CROWD_MIN_FRAMES = 20


class Merger:
    """Finds the objects to merge (sec. 2.6.3): closer than d_inter, and not often detected
    in the same frame (ambiguous neighbours): two landmarks a range sigma apart
    are detected together in nearly every frame that sees them, one object split in two
    hardly ever. A field prior's plant spacing rules out two plants that near: with one, the
    test is off (`spare_together`).

    Between two landmarks a third object can live on their detections, each frame's
    ambiguous one going to it: it is detected with each of the two often, never with both
    (one object too many for the frames' detections). Three landmarks' detections can feed
    six objects the same way. Such a crowd's least seen object, detected with its
    neighbours often but never with all at once, is merged too, until the crowd is no
    larger than what its frames detect together."""

    def __init__(self, spare_together: bool = False) -> None:
        # per object, the sets of other objects detected near it in one frame -> frames
        self._company: dict[int, dict[frozenset[int], int]] = {}
        self.spare_together = spare_together

    def saw(self, object_ids: np.ndarray, xy: np.ndarray, radius: float) -> None:
        """A frame's detections: their objects and map positions; each object counts one
        frame with the set of objects whose detections lie within `radius` of its own."""
        if len(object_ids) < 2 or not self.spare_together:
            return
        near = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2) < radius
        np.fill_diagonal(near, False)
        for i in np.flatnonzero(near.any(axis=1)).tolist():
            company = self._company.setdefault(int(object_ids[i]), {})
            others = frozenset(object_ids[near[i]].tolist())
            company[others] = company.get(others, 0) + 1

    def merged(self, keep: int, drop: int) -> None:
        """`drop` joined `keep`: its frames count as `keep`'s (as its frames do in the
        object table), and its neighbours' frames with it as frames with `keep`."""
        moved = self._company.pop(drop, {})
        for obj in {keep}.union(*moved):
            company = self._company.get(obj)
            if company is None:
                continue
            renamed: dict[frozenset[int], int] = {}
            for others, n in [*company.items(), *(moved.items() if obj == keep else ())]:
                others = others | {keep} if drop in others else others
                others = others - {drop, obj}
                if others:
                    renamed[others] = renamed.get(others, 0) + n
            self._company[obj] = renamed

    def together(self, obj: int, others: np.ndarray) -> np.ndarray:
        """(k,) the frames `obj` was detected in together with each of `others`."""
        company = self._company.get(int(obj), {})
        return np.array(
            [sum(n for s, n in company.items() if b in s) for b in np.asarray(others).tolist()],
            dtype=np.int64,
        )

    def surplus(self, crowd: np.ndarray, n_frames: np.ndarray) -> int | None:
        """The object one too many in `crowd` (three or more near objects), if any: the
        least seen, when in most of its frames it was detected with others of the crowd, but
        with all of them in at most TOGETHER_SHARE of those: the crowd has more objects than
        its frames detect at once (a pair and a ghost between them; or three landmarks
        whose detections went to six objects, which the frames never detect more than three
        of). Judged once it has CROWD_MIN_FRAMES frames."""
        if len(crowd) < 3:
            return None
        obj = int(crowd[np.argmin(n_frames[crowd])])
        n = int(n_frames[obj])
        if n < CROWD_MIN_FRAMES:
            return None
        everyone = frozenset(crowd[crowd != obj].tolist())
        company = self._company.get(obj, {})
        with_some = sum(k for s, k in company.items() if s & everyone)
        all_together = sum(k for s, k in company.items() if everyone <= s)
        crowded = with_some >= 0.5 * n
        return obj if crowded and all_together <= TOGETHER_SHARE * with_some else None

    def pairs(
        self,
        touched: np.ndarray,
        index: SpatialIndex,
        positions: Callable[[np.ndarray], np.ndarray],  # ids -> (k, 2) current estimates
        objects: ObjectTable,
        d_inter: float,
        apart: np.ndarray = NO_OBJECTS,
    ) -> list[tuple[int, int]]:
        """Pairs (keep, drop) of distinct objects to merge, each object in at most one
        pair, none of those kept `apart`; the better-observed object (then the older) is
        kept."""
        pairs: list[tuple[int, int]] = []
        used: set[int] = set(apart.tolist())
        n_meas, n_frames = objects.n_meas, objects.n_frames
        for obj, xy in zip(touched.tolist(), positions(touched), strict=True):
            if obj in used:
                continue
            near = index.query(xy[None, :], d_inter)
            near = near[(near != obj) & ~np.isin(near, list(used))]
            if self.spare_together:
                crowd = np.append(near, obj)
                if (ghost := self.surplus(crowd, n_frames)) is not None:
                    obj, near = ghost, crowd[crowd != ghost]
                    xy = positions(np.array([ghost]))[0]
                else:
                    fewer_frames = np.minimum(n_frames[obj], n_frames[near])
                    near = near[self.together(obj, near) <= TOGETHER_SHARE * fewer_frames]
            if len(near) == 0:
                continue
            d = np.linalg.norm(positions(near) - xy, axis=1)
            if d.min() >= d_inter:
                continue
            other = int(near[int(np.argmin(d))])
            keep, drop = sorted((obj, other), key=lambda i: (-n_meas[i], i))
            pairs.append((keep, drop))
            used.update((keep, drop))
        return pairs
