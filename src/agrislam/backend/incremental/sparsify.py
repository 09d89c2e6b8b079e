"""A fold's dense marginal over many keyframes made sparse (incremental/fold.py): the
newest keyframes' joint kept exact, the older ones hung from it by a Chow-Liu tree.

Robots that share landmarks tie their keyframes together at every fold; once keyframes age
out, each fold's marginal takes in the last one's, and the factor grows to most kept
keyframes: one dense clique that every iSAM2 update and every marginal read goes
through. The Chow-Liu tree is the
tree-shaped Gaussian nearest to a Gaussian (least Kullback-Leibler divergence; Chow and
Liu 1968, as Kretzschmar and Stachniss compress pose graphs, IJRR 2012): it keeps each
keyframe's marginal and the joint marginal of each tree edge's pair exactly, as one
conditional down each edge, so the older keyframes cost iSAM2 a tree, not a clique. The
newest keyframes, which the live window's poses and objects hang from, keep their joint.
"""

from __future__ import annotations

from collections import Counter

import gtsam
import numpy as np
from scipy.sparse import csr_array
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

from agrislam.backend.graph import POSE, key_kind, robot_index_of

# a marginal over more keyframes than this is replaced by its tree (fewer: kept exact)
TREE_ABOVE = 20
# the marginal of a window's factors alone is free in the survey's frame (their priors
# live on): a ridge this small relative to its information makes it invertible
GAUGE_RIDGE = 1e-9
DIM = 3  # a keyframe's tangent space (x, y, theta)
UNIT = gtsam.noiseModel.Unit.Create(DIM)


def sparsified(
    marginal: gtsam.NonlinearFactorGraph,
    point: gtsam.Values,
    newest: set[int],
    issues: Counter[str],
) -> gtsam.NonlinearFactorGraph:
    """`marginal` with each factor over more than TREE_ABOVE keyframes of several robots
    (and nothing else) replaced by the exact marginal of its `newest` keyframes and a
    Chow-Liu tree of the others hung from it, linearised at `point` as the factor was; one
    whose information is too ill-conditioned for that stays as it is (counted in
    `issues`)."""
    out = gtsam.NonlinearFactorGraph()
    for n in range(marginal.size()):
        factor = marginal.at(n)
        keys = list(factor.keys())
        if not _several_robots_wide(keys):
            out.push_back(factor)
            continue
        linear = gtsam.GaussianFactorGraph()
        linear.push_back(factor.linearize(point))
        kept = gtsam.Values()
        for key in keys:
            kept.insert(key, point.atPose2(key))
        try:
            tree = junction_tree(linear, keys, [k for k in keys if k in newest])
        except (np.linalg.LinAlgError, RuntimeError):
            issues["a fold's marginal kept dense: too ill-conditioned for its tree"] += 1
            out.push_back(factor)
            continue
        out.push_back(gtsam.LinearContainerFactor.ConvertLinearGraph(tree, kept))
    return out


def _several_robots_wide(keys: list[int]) -> bool:
    """Keyframes only, more than TREE_ABOVE, of more than one robot: a lone robot keeps
    at most `slam.keyframes_per_robot`, a clique iSAM2 carries; robots that
    share landmarks tie up to `slam.keyframes_kept` together."""
    if len(keys) <= TREE_ABOVE or any(key_kind(k) != POSE for k in keys):
        return False
    return len({robot_index_of(k) for k in keys}) > 1


def junction_tree(
    linear: gtsam.GaussianFactorGraph, keys: list[int], exact: list[int]
) -> gtsam.GaussianFactorGraph:
    """The Gaussian of `linear` over `keys` as the exact marginal of `exact` (if none,
    of the first key) and, down a Chow-Liu tree from it, each other key's conditional on
    its parent."""
    exact = exact or keys[:1]
    hessian = linear.augmentedHessian(gtsam.Ordering(keys))
    information, gradient = hessian[:-1, :-1], hessian[:-1, -1]
    n = len(keys)
    ridge = GAUGE_RIDGE * np.trace(information) / len(information)
    covariance = np.linalg.inv(information + ridge * np.eye(len(information)))
    mean = (covariance @ gradient).reshape(n, DIM)
    blocks = covariance.reshape(n, DIM, n, DIM).transpose(0, 2, 1, 3)  # (n, n, DIM, DIM)
    joined = [keys.index(k) for k in exact]
    parent = tree_parents(blocks, joined)
    # the exact keys' own marginal: the others eliminated (the ridge holds one that the
    # factor leaves free)
    old = [k for k in keys if k not in exact]
    ridged = gtsam.GaussianFactorGraph()
    ridged.push_back(linear)
    for key in old:
        ridged.push_back(
            gtsam.JacobianFactor(key, np.sqrt(ridge) * np.eye(DIM), np.zeros(DIM), UNIT)
        )
    out = ridged.eliminatePartialMultifrontal(gtsam.Ordering(old), gtsam.EliminateQR)[1]
    for child in np.flatnonzero(parent >= 0):
        up = parent[child]
        # x_c | x_p from the pair's information P (inverse of its joint covariance):
        # R (x_c - mu_c) + R^-T P_cp (x_p - mu_p), R^T R = P_cc
        pair = np.linalg.inv(
            np.block(
                [[blocks[child, child], blocks[child, up]], [blocks[up, child], blocks[up, up]]]
            )
        )
        whiten = np.linalg.cholesky(0.5 * (pair[:DIM, :DIM] + pair[:DIM, :DIM].T)).T
        coupling = np.linalg.solve(whiten.T, pair[:DIM, DIM:])
        rhs = whiten @ mean[child] + coupling @ mean[up]
        out.push_back(gtsam.JacobianFactor(keys[child], whiten, keys[up], coupling, rhs, UNIT))
    return out


def tree_parents(blocks: np.ndarray, joined: list[int]) -> np.ndarray:
    """Each node's parent (-1: in `joined`, the root) in the spanning tree of the most
    mutual information between blocks of the joint covariance `blocks` (n, n, DIM, DIM),
    the nodes `joined` taken as one."""
    n = len(blocks)
    i, j = np.triu_indices(n, 1)
    pairs = np.block([[blocks[i, i], blocks[i, j]], [blocks[j, i], blocks[j, j]]])
    own = np.linalg.slogdet(blocks[np.arange(n), np.arange(n)])[1]
    information = 0.5 * (own[i] + own[j] - np.linalg.slogdet(pairs)[1])  # I(x_i; x_j)
    # the most information is the least cost; every cost kept positive (0 = no edge)
    cost = information.max() - information + 1.0
    cost[np.isin(i, joined) & np.isin(j, joined)] = 0.5  # below every other: joined first
    tree = minimum_spanning_tree(csr_array((cost, (i, j)), shape=(n, n)))
    _, parent = breadth_first_order(tree, joined[0], directed=False)
    parent[joined] = -1
    return parent
