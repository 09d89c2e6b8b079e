"""A fold's dense marginal over many keyframes made sparse (backend/incremental/sparsify.py)."""

import itertools
from collections import Counter

import gtsam
import numpy as np
import pytest

from agrislam.backend.graph import POSE, key_kind, object_key, pose_key
from agrislam.backend.incremental import sparsify
from agrislam.backend.incremental.sparsify import DIM, junction_tree, sparsified, tree_parents
from agrislam.config import AgrislamConfig
from agrislam.run.pipeline import run_survey
from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.config import ArenaConfig
from agrislam.world import WorldModel

UNIT = gtsam.noiseModel.Unit.Create(DIM)


def alone(factor: gtsam.GaussianFactor) -> gtsam.GaussianFactorGraph:
    graph = gtsam.GaussianFactorGraph()
    graph.push_back(factor)
    return graph


def keyframes(n: int, robots: int = 3, first: int = 0) -> list[int]:
    """n keyframes taken in turn by `robots` robots (numbered from `first`)."""
    return [pose_key(first + k % robots, k // robots) for k in range(n)]


def dense_factor(keys: list[int], seed: int, gauge_free: bool = False) -> gtsam.GaussianFactorGraph:
    """One Gaussian factor tying every key to every other (a fold's marginal): random
    relative measurements between all pairs, and a prior on each unless `gauge_free`."""
    rng = np.random.default_rng(seed)
    graph = gtsam.GaussianFactorGraph()
    for a in range(len(keys)):
        if not gauge_free:
            graph.push_back(gtsam.JacobianFactor(keys[a], np.eye(DIM), rng.normal(size=DIM), UNIT))
        for b in range(a + 1, len(keys)):
            w = rng.uniform(0.2, 3.0) * np.diag(rng.uniform(0.5, 2.0, DIM))
            graph.push_back(
                gtsam.JacobianFactor(keys[a], -w, keys[b], w, rng.normal(size=DIM), UNIT)
            )
    return alone(gtsam.JacobianFactor(graph, gtsam.Ordering(keys)))


def moments(graph: gtsam.GaussianFactorGraph, keys: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Covariance and mean of the graph's Gaussian over `keys` (in that order)."""
    hessian = graph.augmentedHessian(gtsam.Ordering(keys))
    covariance = np.linalg.inv(hessian[:-1, :-1])
    return covariance, covariance @ hessian[:-1, -1]


def block(covariance: np.ndarray, at: list[int]) -> np.ndarray:
    rows = np.concatenate([np.arange(DIM * a, DIM * a + DIM) for a in at])
    return covariance[np.ix_(rows, rows)]


def test_a_chain_is_its_own_tree_and_comes_back_exact():
    keys = keyframes(6)
    chain = gtsam.GaussianFactorGraph()
    chain.push_back(gtsam.JacobianFactor(keys[0], np.eye(DIM), np.ones(DIM), UNIT))
    rng = np.random.default_rng(3)
    for a, b in itertools.pairwise(keys):
        w = np.diag(rng.uniform(1.0, 5.0, DIM))
        chain.push_back(gtsam.JacobianFactor(a, -w, b, w, rng.normal(size=DIM), UNIT))
    for exact in ([], keys[-2:]):
        tree = junction_tree(chain, keys, exact)
        want, got = (
            chain.augmentedHessian(gtsam.Ordering(keys)),
            tree.augmentedHessian(gtsam.Ordering(keys)),
        )
        np.testing.assert_allclose(got[:-1], want[:-1], atol=1e-6 * np.abs(want).max())


def covariance_of(graph: gtsam.GaussianFactorGraph, keys: list[int]) -> np.ndarray:
    """The graph's covariance over `keys`; where its frame is free, the pseudo-inverse
    (what the tree's ridge adds there is left out)."""
    information = graph.augmentedHessian(gtsam.Ordering(keys))[:-1, :-1]
    return np.linalg.pinv(information, rcond=1e-6, hermitian=True)


def relative(covariance: np.ndarray, a: int, b: int) -> np.ndarray:
    """Covariance of x_a - x_b (frame-free, as a fold's marginal on its own is)."""
    pick = np.zeros((DIM, len(covariance)))
    pick[:, DIM * a : DIM * a + DIM] = np.eye(DIM)
    pick[:, DIM * b : DIM * b + DIM] -= np.eye(DIM)
    return pick @ covariance @ pick.T


@pytest.mark.parametrize("gauge_free", [False, True])
def test_the_tree_keeps_the_newest_joint_and_every_edge_marginal(gauge_free):
    keys = keyframes(9)
    dense = dense_factor(keys, seed=1, gauge_free=gauge_free)
    newest = [6, 7, 8]
    tree = junction_tree(dense, keys, [keys[n] for n in newest])
    assert set(tree.at(0).keys()) == {keys[n] for n in newest}  # the newest ones' joint
    assert all(tree.at(n).size() == 2 for n in range(1, tree.size()))  # and one edge each
    assert tree.size() == 1 + len(keys) - len(newest)
    want, got = covariance_of(dense, keys), covariance_of(tree, keys)
    scale = np.abs(want).max()
    edges = [(6, 7), (6, 8), (7, 8)]
    for n in range(1, tree.size()):
        edges.append(tuple(keys.index(k) for k in tree.at(n).keys()))  # noqa: SIM118
    for a, b in edges:
        np.testing.assert_allclose(relative(got, a, b), relative(want, a, b), atol=1e-6 * scale)
    if not gauge_free:  # in the survey's frame: each keyframe's own marginal too
        np.testing.assert_allclose(np.diag(got), np.diag(want), rtol=1e-6)
        _, want_mean = moments(dense, keys)
        _, got_mean = moments(tree, keys)
        np.testing.assert_allclose(got_mean, want_mean, atol=1e-6 * np.abs(want_mean).max())


def test_the_tree_follows_the_most_information():
    """Three keyframes, 0-1 and 1-2 tied tightly, 0-2 loosely: the tree is 0-1-2."""
    keys = keyframes(3)
    graph = gtsam.GaussianFactorGraph()
    graph.push_back(gtsam.JacobianFactor(keys[0], np.eye(DIM), np.zeros(DIM), UNIT))
    for a, b, w in ((0, 1, 10.0), (1, 2, 10.0), (0, 2, 0.1)):
        graph.push_back(
            gtsam.JacobianFactor(
                keys[a], -w * np.eye(DIM), keys[b], w * np.eye(DIM), np.zeros(DIM), UNIT
            )
        )
    covariance, _ = moments(graph, keys)
    parent = tree_parents(covariance.reshape(3, DIM, 3, DIM).transpose(0, 2, 1, 3), [0])
    assert parent.tolist() == [-1, 0, 1]


def as_marginal(
    graph: gtsam.GaussianFactorGraph, point: gtsam.Values
) -> gtsam.NonlinearFactorGraph:
    """A fold's marginal: the linear graph at a point, as the fold hands it on."""
    for n, key in enumerate(graph.keyVector()):
        if not point.exists(key):
            if key_kind(key) == POSE:
                point.insert(key, gtsam.Pose2(float(n), 0.0, 0.1 * n))
            else:
                point.insert(key, gtsam.Point2(float(n), 1.0))
    return gtsam.LinearContainerFactor.ConvertLinearGraph(graph, point)


def test_only_a_wide_keyframe_marginal_is_made_sparse():
    wide = keyframes(sparsify.TREE_ABOVE + 4)
    narrow = keyframes(sparsify.TREE_ABOVE, first=3)
    with_object = keyframes(sparsify.TREE_ABOVE + 4, first=6)
    lone = keyframes(sparsify.TREE_ABOVE + 4, robots=1, first=9)  # at most 30 of its own
    point = gtsam.Values()
    marginal = as_marginal(dense_factor(wide, seed=2), point)
    marginal.push_back(as_marginal(dense_factor(narrow, seed=4), point))
    marginal.push_back(as_marginal(dense_factor(lone, seed=3), point))
    object_graph = dense_factor(with_object, seed=5)  # one key a landmark's (2-D)
    rng = np.random.default_rng(6)
    object_graph.push_back(
        gtsam.JacobianFactor(
            with_object[0],
            rng.normal(size=(2, DIM)),
            object_key(7),
            np.eye(2),
            np.zeros(2),
            gtsam.noiseModel.Unit.Create(2),
        )
    )
    marginal.push_back(as_marginal(alone(gtsam.JacobianFactor(object_graph)), point))
    issues: Counter[str] = Counter()
    out = sparsified(marginal, point, set(wide[-3:]), issues)
    sizes = sorted(out.at(n).size() for n in range(out.size()))
    # the narrow one, the lone robot's and the one with a landmark as they were; the wide
    # one the newest three's joint and one edge for each other keyframe
    assert sizes == [2] * (len(wide) - 3) + [3, len(narrow), len(lone), len(with_object) + 1]
    assert not issues
    want = marginal.linearize(point)
    got = out.linearize(point)
    want_cov, _ = moments(alone(want.at(0)), wide)
    tree = gtsam.GaussianFactorGraph()
    for n in range(got.size()):
        if set(got.at(n).keys()) <= set(wide):
            tree.push_back(got.at(n))
    got_cov, _ = moments(tree, wide)
    np.testing.assert_allclose(np.diag(got_cov), np.diag(want_cov), rtol=1e-5)


def test_an_ill_conditioned_marginal_stays_dense_and_is_counted(monkeypatch):
    def singular(*_):
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    monkeypatch.setattr(sparsify, "junction_tree", singular)
    wide = keyframes(sparsify.TREE_ABOVE + 1)
    point = gtsam.Values()
    marginal = as_marginal(dense_factor(wide, seed=8), point)
    issues: Counter[str] = Counter()
    out = sparsified(marginal, point, set(wide[-3:]), issues)
    assert out.size() == 1 and out.at(0).size() == len(wide)
    assert sum(issues.values()) == 1 and "dense" in next(iter(issues))


def test_robots_sharing_landmarks_keep_their_live_graph_narrow(monkeypatch):
    """Five robots in the arena tie their keyframes at each fold; once keyframes age out
    the fold's marginal takes in most kept keyframes. Made sparse, no live factor is wider
    than TREE_ABOVE."""
    trees = []
    monkeypatch.setattr(
        sparsify, "junction_tree", lambda *a: trees.append(a[1]) or junction_tree(*a)
    )
    widest = []
    arena = ArenaConfig.model_validate({"seed": 1, "driving": {"duration_s": 100.0}})
    config = AgrislamConfig.model_validate(
        {"advanced": {"slam": {"window": 30, "keyframes_kept": 50}}}
    )
    world = WorldModel(config)
    records = list(ArenaSimulator(arena).records())
    world.process(records[0])  # the meta: the survey's stages are built for it
    update = world.backend.update

    def watched() -> bool:
        folded = update()
        if folded:
            live = world.backend.isam_factors()
            widest.append(max(live.at(n).size() for n in range(live.size()) if live.exists(n)))
        return folded

    world.backend.update = watched
    result = run_survey(records[1:], world)
    assert result.error is None and len(widest) > 30
    assert trees and max(len(keys) for keys in trees) > sparsify.TREE_ABOVE
    assert max(widest) <= sparsify.TREE_ABOVE
