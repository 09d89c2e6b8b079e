"""The map's spatial index (mapping/spatial_index.py): never misses an object within the radius,
builds again only the tiles that changed, looks only at the tiles around what it is asked."""

import warnings

import numpy as np

from agrislam.mapping.spatial_index import TILE, SpatialIndex


def test_spatial_index_finds_tree_and_fresh_objects_within_radius():
    index = SpatialIndex(margin=0.0)
    index.rebuild(np.array([0, 1, 2]), np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]]))
    index.move(np.array([3]), np.array([[0.5, 0.5]]))
    assert index.query(np.array([[0.0, 0.0]]), 1.01).tolist() == [0, 1, 3]
    assert index.query(np.array([[10.0, 0.2]]), 0.5).tolist() == [2]
    index.forget(np.array([0]))
    assert index.query(np.array([[0.0, 0.0]]), 0.1).tolist() == []


def test_spatial_index_builds_from_the_positions_it_was_told_and_sweeps_in_turn():
    index = SpatialIndex(margin=0.0, sweep_steps=3)
    index.move(np.array([0, 1]), np.array([[0.0, 0.0], [5.0, 0.0]]))
    index.settle(np.array([1]), np.array([[9.0, 0.0]]))  # moved, read in a sweep
    index.rebuild()  # no positions given: the ones known, nothing from the back end
    assert index.n_fresh == 0
    assert index.query(np.array([[9.0, 0.0]]), 0.1).tolist() == [1]
    assert index.query(np.array([[5.0, 0.0]]), 0.1).tolist() == []
    index.forget(np.array([1]))
    index.rebuild()
    assert index.query(np.array([[9.0, 0.0]]), 0.1).tolist() == []
    rounds = [np.arange(7), np.arange(10, 13)]
    turns = [index.due(lambda: rounds.pop(0)).tolist() for _ in range(4)]
    assert turns[:3] == [[0, 1, 2], [3, 4, 5], [6]]  # every object once in 3 calls
    assert turns[3] == [10] and rounds == []  # a new round asks again what drifts


def brute_force(xy: np.ndarray, centres: np.ndarray, radius: float) -> set[int]:
    d2 = ((xy[:, None, :] - centres[None, :, :]) ** 2).sum(-1).min(axis=1)
    return set(np.flatnonzero(d2 <= radius**2).tolist())


def test_spatial_index_never_misses_an_object_as_the_map_moves_and_is_rebuilt():
    """Objects added, moved a little (settled) or much (moved), forgotten, across many
    tiles, with builds in between: every query holds every object within the radius and
    nothing beyond radius + margin."""
    rng = np.random.default_rng(4)
    margin, n = 0.3, 3000
    index = SpatialIndex(margin=margin)
    truth = rng.uniform(-3 * TILE, 5 * TILE, size=(n, 2))
    index.rebuild(np.arange(n), truth)
    alive = np.ones(n, dtype=bool)
    for step in range(60):
        some = rng.choice(np.flatnonzero(alive), 40, replace=False)
        truth[some] += rng.normal(0.0, 0.05, size=(40, 2))  # the map bends a little
        index.settle(some, truth[some])
        jumped = rng.choice(np.flatnonzero(alive), 3, replace=False)
        truth[jumped] += rng.uniform(-TILE, TILE, size=(3, 2))  # a merge, a loop closure
        index.move(jumped, truth[jumped])
        gone = rng.choice(np.flatnonzero(alive), 2, replace=False)
        index.forget(gone)
        alive[gone] = False
        if step % 7 == 0:
            index.rebuild()
        centres = rng.uniform(-3 * TILE, 5 * TILE, size=(1, 2)) + rng.normal(0, 1.0, (5, 2))
        radius = rng.uniform(0.2, 4.0)
        got = set(index.query(centres, radius).tolist())
        live = np.flatnonzero(alive)
        within = {int(live[i]) for i in brute_force(truth[live], centres, radius)}
        assert within <= got, f"step {step}: missed {within - got}"
        reach = {int(live[i]) for i in brute_force(truth[live], centres, radius + margin)}
        assert got <= reach, f"step {step}: {got - reach} beyond the margin"


def test_a_build_touches_only_the_tiles_that_changed():
    index = SpatialIndex(margin=0.3)
    xy = np.array([[1.0, 1.0], [1.5, 1.0], [TILE * 3 + 1.0, 1.0]])
    index.rebuild(np.arange(3), xy)
    far_tree = index._tiles[(3, 0)][0]
    index.settle(np.array([0]), np.array([[1.1, 1.0]]))  # less than half the margin
    index.move(np.array([3]), np.array([[2.0, 2.0]]))  # a new object near the first two
    index.rebuild()
    assert index._tiles[(3, 0)][0] is far_tree  # the far tile was not built again
    assert sorted(index._tiles[(0, 0)][1].tolist()) == [0, 1, 3]
    index.settle(np.array([2]), np.array([[1.0, 5.0]]))  # read again far off: both tiles
    index.rebuild()
    assert (3, 0) not in index._tiles
    assert index.query(np.array([[1.0, 5.0]]), 0.1).tolist() == [2]


class _CountedTiles(dict):
    """The index's tiles, counting the look-ups of a query."""

    lookups = 0

    def get(self, key, default=None):
        self.lookups += 1
        return super().get(key, default)


def test_a_far_centre_costs_what_a_near_one_costs():
    """A frame with one detection far off (within the input limits) looks at the tiles
    around each detection, never at every tile of the box between them (it was 16 s for a
    detection at 1,000 km, hours at 9,000 km)."""
    rng = np.random.default_rng(0)
    index = SpatialIndex(margin=0.3)
    index.rebuild(np.arange(300), rng.uniform(0.0, 3 * TILE, size=(300, 2)))
    index._tiles = tiles = _CountedTiles(index._tiles)
    near = np.array([[5.0, 5.0], [6.5, 4.0], [7.0, 9.0]])
    expected = index.query(near, 1.0).tolist()
    alone, tiles.lookups = tiles.lookups, 0
    for far in ([1e4, 3e3], [9e6, -9e6]):
        assert index.query(np.vstack([near, [far]]), 1.0).tolist() == expected
        assert tiles.lookups <= alone + 4, far  # the far centre's own tiles, at most 2 x 2
        tiles.lookups = 0


def test_a_wide_radius_reads_the_built_tiles_near_a_centre():
    """Where the tiles around the centres outnumber the built ones, the built tiles are
    read instead: the same objects, no more look-ups than built tiles."""
    rng = np.random.default_rng(1)
    xy = rng.uniform(-2 * TILE, 4 * TILE, size=(400, 2))
    index = SpatialIndex(margin=0.0)
    index.rebuild(np.arange(400), xy)
    index._tiles = tiles = _CountedTiles(index._tiles)
    centres = np.array([[0.0, 0.0], [20.0, 5.0]])
    got = index.query(centres, 2 * TILE)
    assert set(got.tolist()) == brute_force(xy, centres, 2 * TILE)
    assert 0 < tiles.lookups <= len(tiles)


def test_an_object_at_no_finite_place_is_in_no_tile():
    """A diverged solve's infinite position: not indexed, no tile of it, no warning; one
    beyond what a tile number holds is in an edge tile."""
    index = SpatialIndex(margin=0.3)
    xy = np.array([[0.5, 0.0], [1.0, np.inf], [np.nan, 2.0], [0.0, 0.5], [1e300, -1e300]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        index.rebuild(np.arange(5), xy)
        index.settle(np.array([0]), np.array([[-np.inf, 0.0]]))
        index.rebuild()
        assert index.query(np.array([[0.5, 0.0]]), 1.0).tolist() == [3]
        assert index.query(np.array([[1e300, -1e300]]), 1.0).tolist() == [4]
