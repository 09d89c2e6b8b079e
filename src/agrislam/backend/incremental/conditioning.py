"""A window's graph made solvable on its own (incremental/fold.py folds it away):
conditioned on one keyframe, cut to the part connected to it, and with every node GTSAM
finds indeterminate held by a weak prior, so that degenerate geometry (an object seen along
one ray only, a robot that shares a single landmark yet) costs that node's certainty and
never the run."""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable
from typing import TypeVar

import gtsam
import numpy as np
import scipy.sparse as sp
from scipy.linalg import solve_triangular
from threadpoolctl import ThreadpoolController

from agrislam.backend.graph import POSE, key_kind
from agrislam.backend.values import insert_value, value_array
from agrislam.geometry.se2 import rotation

T = TypeVar("T")
_BLAS = ThreadpoolController()

# conditioning on a keyframe: its prior (m, rad); others only kept from floating away
FIXED_SIGMA = 1e-4
FREE_SIGMA = 10.0
# a covariance entry past this (m^2) is no measurement's: the node is indeterminate
INDETERMINATE = 1e6


def shared_copy(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """A new graph holding the same factors (no factor is changed in place; a Python
    CustomFactor, the GNSS factor, cannot be cloned)."""
    out = gtsam.NonlinearFactorGraph()
    out.push_back(graph)
    return out


def conditioned(
    graph: gtsam.NonlinearFactorGraph, point: gtsam.Values, fixed: int | None, free: list[int]
) -> gtsam.NonlinearFactorGraph:
    """The graph with node `fixed` held at its value (a tight prior) and the other
    `free` nodes given only a weak prior, so that it can be solved on its own."""
    out = shared_copy(graph)
    for key in free:
        sigma = FIXED_SIGMA if key == fixed else FREE_SIGMA
        if key_kind(key) == POSE:
            noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma)
            out.push_back(gtsam.PriorFactorPose2(key, point.atPose2(key), noise))
        else:
            noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma)
            out.push_back(gtsam.PriorFactorPoint2(key, point.atPoint2(key), noise))
    return out


def weakly_held(values: dict[int, np.ndarray]) -> gtsam.NonlinearFactorGraph:
    """A weak prior (FREE_SIGMA) holding each node where it is."""
    point = gtsam.Values()
    for key, value in values.items():
        insert_value(point, key, value)
    return conditioned(gtsam.NonlinearFactorGraph(), point, None, list(values))


def marginal_covariances(
    graph: gtsam.NonlinearFactorGraph, point: gtsam.Values, keys: list[int]
) -> list[np.ndarray]:
    """Marginal covariances of the 2-D nodes `keys` (objects, none tied to another) of a
    solvable `graph` at `point`, by the Schur complement onto the other nodes: with H
    the information matrix, objects l and the rest p, S = H_pp - H_pl H_ll^-1 H_lp and
    cov(l_i) = H_ii^-1 + H_ii^-1 H_ip S^-1 H_pi H_ii^-1 (a `gtsam.Marginals` query per
    object costs a Bayes-tree shortcut each: most of a keyframe fold). Where objects are
    tied or the system is singular, GTSAM's own marginals decide (and name the node)."""
    order = sorted(graph.keyVector())  # the matrix's columns: nodes in key order
    dims = np.array([3 if key_kind(key) == POSE else 2 for key in order])
    start = dict(zip(order, np.cumsum(dims) - dims, strict=True))
    if outside := [gtsam.DefaultKeyFormatter(key) for key in keys if key not in start]:
        # a merge of objects far apart can leave one outside its keyframe's part
        raise RuntimeError(f"objects {', '.join(outside)} are not in the graph given")
    information = information_matrix(graph, point, int(dims.sum()))
    objects = np.concatenate([start[key] + np.arange(2) for key in keys])
    rest = np.setdiff1d(np.arange(int(dims.sum())), objects)
    rows = information[objects]  # the objects' rows of H, sliced once
    h_ll = rows[:, objects].toarray()
    blocks = h_ll.reshape(len(keys), 2, len(keys), 2)
    own = blocks[np.arange(len(keys)), :, np.arange(len(keys)), :]  # (k, 2, 2)
    tied = np.abs(h_ll).sum() - np.abs(own).sum() > 1e-9 * np.abs(own).sum()
    # a few hundred rows of dense algebra: one BLAS thread (more spin on a busy machine)
    with np.errstate(all="ignore"), _BLAS.limit(limits=1, user_api="blas"):
        covs = None if tied else _schur_covariances(information, rows, rest, own)
    if covs is not None and _measured(covs):
        return list(covs)
    marginals = gtsam.Marginals(graph, point)
    return [marginals.marginalCovariance(key) for key in keys]


def information_matrix(
    graph: gtsam.NonlinearFactorGraph, point: gtsam.Values, size: int
) -> sp.csr_matrix:
    """J^T J (size, size) of the graph linearised at `point`, columns in key order."""
    jacobian = graph.linearize(point).sparseJacobian_()  # 1-based [row, column, value]
    row, col, value = jacobian[0] - 1, jacobian[1] - 1, jacobian[2]
    inside = col < size  # not the right-hand side, the last column
    shape = (int(row.max()) + 1, size)
    a = sp.csr_matrix((value[inside], (row[inside], col[inside])), shape=shape)
    return (a.T @ a).tocsr()


def _measured(covs: np.ndarray) -> bool:
    """Whether 2x2 matrices are finite, bounded (not indeterminate) and positive definite."""
    if not (np.isfinite(covs).all() and (np.abs(covs) < INDETERMINATE).all()):
        return False
    return bool((np.linalg.eigvalsh(covs) > 0).all())


def _schur_covariances(
    information: sp.csr_matrix, rows: sp.csr_matrix, rest: np.ndarray, own: np.ndarray
) -> np.ndarray | None:
    """(k, 2, 2) the objects' marginal covariances (`marginal_covariances`; `rows`: the
    objects' rows of the information matrix), or None where an object's own block or
    the reduced system is singular."""
    count, size = len(own), len(rest)
    try:
        own_inv = np.linalg.inv(own)
        h_lp = rows[:, rest].toarray()  # (2k, p)
        w = (own_inv @ h_lp.reshape(count, 2, size)).reshape(-1, size)  # H_ii^-1 H_ip
        factor = np.linalg.cholesky(information[rest][:, rest].toarray() - h_lp.T @ w)
    except np.linalg.LinAlgError:
        return None
    half = solve_triangular(factor, w.T, lower=True).T.reshape(count, 2, size)  # (L^-1 W^T)^T
    return own_inv + half @ half.swapaxes(1, 2)


def indeterminate_key(err: RuntimeError) -> int | None:
    """The node GTSAM names in an IndeterminateLinearSystemException, if it names one."""
    found = re.search(r"near variable\s+(\d+)", str(err))
    return int(found.group(1)) if found else None


def isolating(
    build: Callable[[gtsam.NonlinearFactorGraph], T],
    graph: gtsam.NonlinearFactorGraph,
    point: gtsam.Values,
    issues: Counter[str],
    what: str,
) -> T:
    """build(graph), where GTSAM may find the system indeterminate: the node it names (an
    object seen along one ray only) gets the weak FREE_SIGMA prior and the build is tried
    again; named again, or where a whole part has no gauge (a robot that shares only one
    landmark yet), every node gets it. Degenerate geometry costs those nodes' certainty,
    not the run; raises only if even that fails."""
    isolated: set[int] = set()
    every_node = False
    while True:
        try:
            return build(graph)
        except RuntimeError as err:
            key = indeterminate_key(err)
            if key is None or not point.exists(key) or every_node:
                raise
            every_node = key in isolated
            isolated.add(key)
            graph = conditioned(
                graph, point, None, list(graph.keyVector()) if every_node else [key]
            )
            kind = "pose" if key_kind(key) == POSE else "object"
            issues[f"{kind} held by a weak prior: indeterminate in {what}"] += 1


def marginalised(
    graph: gtsam.NonlinearFactorGraph,
    point: gtsam.Values,
    window: set[int],
    issues: Counter[str],
) -> gtsam.NonlinearFactorGraph:
    """The window's factors with the window's nodes eliminated: dense factors on the
    keyframes and rows they touched, linearised at `point` (a node found indeterminate is
    held by a weak prior first, `isolating`)."""
    kept = gtsam.Values()
    for key in point.keys():  # noqa: SIM118
        if key not in window:
            insert_value(kept, key, value_array(point, key))

    def eliminated(graph: gtsam.NonlinearFactorGraph) -> gtsam.GaussianFactorGraph:
        return graph.linearize(point).eliminatePartialMultifrontal(sorted(window))[1]

    remaining = isolating(eliminated, graph, point, issues, "a keyframe fold")
    return gtsam.LinearContainerFactor.ConvertLinearGraph(remaining, kept)


def covariances_given(
    keyframe: int,
    keys: list[int],
    parts: Callable[[], dict[int, tuple[gtsam.NonlinearFactorGraph, set[int]]]],
    point: gtsam.Values,
    blanket: list[int],
    issues: Counter[str],
) -> list[np.ndarray]:
    """Covariances of objects `keys` given `keyframe` in its frame, from the part of the
    graph around connected to it (`parts()[keyframe]`, `components`); failing that,
    FREE_SIGMA wide (a keyframe fold, incremental/fold.py)."""
    local, nodes = parts()[keyframe]
    free = [k for k in blanket if k in nodes]

    def covariances(graph: gtsam.NonlinearFactorGraph) -> list[np.ndarray]:
        return marginal_covariances(graph, point, keys)

    graph = conditioned(local, point, keyframe, free)
    try:
        covs = isolating(covariances, graph, point, issues, "a keyframe fold")
    except RuntimeError:
        issues["object given a weak covariance at a keyframe fold"] += len(keys)
        return [np.eye(2) * FREE_SIGMA**2 for _ in keys]
    rot = rotation(value_array(point, keyframe)[2])
    return [rot.T @ cov @ rot for cov in covs]


def components(
    graph: gtsam.NonlinearFactorGraph,
) -> dict[int, tuple[gtsam.NonlinearFactorGraph, set[int]]]:
    """Each node of `graph` -> the factors connected to it (in their order) and their
    nodes: with several robots, the part of a window that another robot's keyframe does
    not reach has no gauge of its own when conditioned on this one."""
    parent: dict[int, int] = {}

    def root(key: int) -> int:
        while parent.setdefault(key, key) != key:
            parent[key] = key = parent[parent[key]]
        return key

    keys = [list(graph.at(n).keys()) for n in range(graph.size())]
    for factor_keys in filter(None, keys):
        first = root(factor_keys[0])  # a node only a prior holds is a part of its own
        for key in factor_keys[1:]:
            parent[root(key)] = first
    parts: dict[int, tuple[gtsam.NonlinearFactorGraph, set[int]]] = {}
    for key in parent:
        parts.setdefault(root(key), (gtsam.NonlinearFactorGraph(), set()))[1].add(key)
    for n, factor_keys in enumerate(keys):
        if factor_keys:
            parts[root(factor_keys[0])][0].push_back(graph.at(n))
    return {key: parts[root(key)] for key in parent}
