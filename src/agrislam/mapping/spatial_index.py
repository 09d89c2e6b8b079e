"""The map's spatial index, the gate's first cut (DESIGN step 4): which objects lie near a
point, in time that does not grow with the field. Square tiles each hold a KD-tree over the
positions their objects had when it was built; only the tiles that changed are rebuilt."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from agrislam.growing import Doubling

TILE = 8.0  # m, the side of a tile: a few hundred plants, a few in one camera view
EDGE = 2**31 - 1  # tiles from the origin (17 million km): `_packed` tiles stay distinct


class SpatialIndex:
    """Object positions by id, found by distance: tiled KD-trees built from the last
    known positions now and then; objects added or moved since are searched directly.
    Every query is widened by `margin`, the distance an object's estimate may have moved
    since its tile was built. Building reads nothing from the back end, so its cost is
    the trees' alone."""

    def __init__(self, margin: float = 0.3, sweep_steps: int = 500) -> None:
        self.margin = margin
        self.sweep_steps = sweep_steps
        self._sweep_at = 0
        self._round = np.empty(0, dtype=np.int64)  # what the sweep reads in turn
        self._xy = np.full((0, 2), np.nan)  # row = object id; NaN: not indexed
        self._built_xy = np.full((0, 2), np.nan)  # where its tile's tree holds it
        self._doubling = Doubling({"_xy": np.nan, "_built_xy": np.nan})
        self._tiles: dict[tuple[int, int], tuple[cKDTree, np.ndarray]] = {}  # tree, ids
        self._dirty: set[tuple[int, int]] = set()  # tiles to build again
        self._fresh: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------------ building
    def rebuild(self, ids: np.ndarray | None = None, xy: np.ndarray | None = None) -> None:
        """Build again the tiles that changed (given `ids` and `xy`: every tile, from those
        alone, forgetting every other object)."""
        if ids is not None and xy is not None:
            self._xy[:] = self._built_xy[:] = np.nan
            self._dirty.update(self._tiles)
            self.settle(ids, xy)
        if self._dirty:
            self._build(self._dirty)
        self._dirty.clear()
        self._fresh.clear()

    def _build(self, tiles: set[tuple[int, int]]) -> None:
        indexed = np.flatnonzero(np.isfinite(self._xy).all(axis=1))  # NaN: not indexed
        keys = _tile_of(self._xy[indexed])
        mine = np.isin(_packed(keys), _packed(np.array(sorted(tiles)).reshape(-1, 2)))
        members = indexed[mine]
        order = np.lexsort((keys[mine, 1], keys[mine, 0]))
        members, keys = members[order], keys[mine][order]
        starts = np.flatnonzero(np.r_[True, np.any(np.diff(keys, axis=0) != 0, axis=1)])
        for tile in tiles:
            self._tiles.pop(tile, None)
        for ids in np.split(members, starts[1:]) if len(members) else []:
            tile = tuple(_tile_of(self._xy[ids[:1]])[0].tolist())
            self._tiles[tile] = (cKDTree(self._xy[ids]), ids)
            self._built_xy[ids] = self._xy[ids]

    @property
    def n_fresh(self) -> int:
        return len(self._fresh)

    def move(self, ids: np.ndarray, xy: np.ndarray) -> None:
        """Objects just added, or whose estimate was just refreshed: searched directly."""
        self.settle(ids, xy)
        for i, p in zip(np.asarray(ids).tolist(), xy, strict=True):
            self._fresh[i] = p

    def settle(self, ids: np.ndarray, xy: np.ndarray) -> None:
        """New positions of objects: the next build uses them; one that moved more than half
        the margin since its tile was built gets its tile (and the one it is in now) built."""
        ids = np.asarray(ids, dtype=int)
        if len(ids):
            self._doubling.reserve_attributes(self, int(ids.max()) + 1, len(self._xy))
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        self._xy[ids] = xy
        built = self._built_xy[ids]
        moved = ~(np.sum((xy - built) ** 2, axis=1) <= (0.5 * self.margin) ** 2)  # NaN: new
        if moved.any():
            self._dirty |= _tiles_under(np.concatenate([xy[moved], built[moved]]))

    def due(self, drifting: Callable[[], np.ndarray]) -> np.ndarray:
        """The share of the objects whose positions are to be read again this step (and
        `settle`d), in turn: each round takes the objects `drifting()` gives then, and
        reads every one once in `sweep_steps` calls. Objects not seen move only with the
        map's keyframes; reading all at once would stall a step."""
        if self._sweep_at >= len(self._round):
            self._round, self._sweep_at = drifting(), 0
        start = self._sweep_at
        self._sweep_at += -(-len(self._round) // self.sweep_steps)
        return self._round[start : self._sweep_at]

    def forget(self, ids: np.ndarray) -> None:
        ids = np.atleast_1d(ids)
        ids = ids[ids < len(self._xy)]
        for i in ids.tolist():
            self._fresh.pop(i, None)
        self._dirty |= _tiles_under(self._built_xy[ids])
        self._xy[ids] = self._built_xy[ids] = np.nan

    # ------------------------------------------------------------------ queries
    def position(self, ids: np.ndarray) -> np.ndarray:
        """(k, 2) the last known positions of indexed objects."""
        return self._xy[np.asarray(ids, dtype=int)].reshape(-1, 2)

    def query(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """Ids of all objects within `radius` of any of `centres` (sorted, unique): never
        misses one within `radius`, may include one up to `margin` farther (its estimate
        may have moved that much since it was last read)."""
        found: list[np.ndarray] = []
        centres = centres[np.isfinite(centres).all(axis=1)]
        if self._tiles and len(centres):
            reach = radius + self.margin
            for key in self._tiles_near(centres, reach).tolist():
                if (tile := self._tiles.get(tuple(key))) is not None:
                    found.append(_within(tile, centres, reach))
        if self._fresh and len(centres):
            fresh_ids = np.fromiter(self._fresh.keys(), dtype=int, count=len(self._fresh))
            fresh_xy = np.stack(list(self._fresh.values()))
            d2 = ((fresh_xy[:, None, :] - centres[None, :, :]) ** 2).sum(-1).min(axis=1)
            found.append(fresh_ids[d2 <= radius**2])
        if not found:
            return np.empty(0, dtype=int)
        ids = np.unique(np.concatenate(found))
        # as last known (NaN: forgotten), not as a tile not yet built again holds them
        d2 = ((self._xy[ids, None, :] - centres[None, :, :]) ** 2).sum(-1).min(axis=1)
        return ids[d2 <= (radius + self.margin) ** 2]

    def _tiles_near(self, centres: np.ndarray, reach: float) -> np.ndarray:
        """(k, 2) the tiles within `reach` of any of `centres` that may hold objects: those
        around each centre, or, where these outnumber the built tiles, the built tiles near
        one. Never the tiles between far-apart centres: a frame with one detection far off
        costs what a frame of near ones costs."""
        lo, hi = _tile_of(centres - reach), _tile_of(centres + reach)
        span = hi - lo + 1  # tiles per axis around each centre
        if int(np.prod(span, axis=1).sum()) > len(self._tiles):
            built = np.array(list(self._tiles), dtype=np.int64).reshape(-1, 2)
            near = (built[:, None, :] >= lo[None]) & (built[:, None, :] <= hi[None])
            return built[near.all(axis=2).any(axis=1)]
        ox, oy = np.meshgrid(*(np.arange(n) for n in span.max(axis=0)), indexing="ij")
        around = lo[:, None, :] + np.column_stack([ox.ravel(), oy.ravel()])[None]
        around = around[(around <= hi[:, None, :]).all(axis=2)]
        _, first = np.unique(_packed(around), return_index=True)
        return around[first]


def _within(tile: tuple[cKDTree, np.ndarray], centres: np.ndarray, reach: float) -> np.ndarray:
    tree, ids = tile
    hits = tree.query_ball_point(centres, reach)
    return ids[np.concatenate([np.asarray(h, dtype=int) for h in hits])]


def _tile_of(xy: np.ndarray) -> np.ndarray:
    """(k, 2) integer tile coordinates of finite points xy (k, 2); a diverged estimate
    beyond EDGE tiles is in an edge tile."""
    return np.clip(np.floor(xy / TILE), -EDGE, EDGE).astype(np.int64)


def _tiles_under(xy: np.ndarray) -> set[tuple[int, int]]:
    """The tiles points xy (k, 2) lie in (rows not finite: none)."""
    tiles = _tile_of(xy[np.isfinite(xy).all(axis=1)])
    _, first = np.unique(_packed(tiles), return_index=True)
    return set(map(tuple, tiles[first].tolist()))


def _packed(tiles: np.ndarray) -> np.ndarray:
    """One int64 per tile (k, 2), to compare tiles as numbers."""
    return tiles[:, 0] * (1 << 32) + tiles[:, 1]
