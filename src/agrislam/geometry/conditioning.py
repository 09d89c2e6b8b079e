"""A window's graph made solvable on its own (geometry/incremental.py folds it away):
conditioned on one keyframe, cut to the part connected to it, and with every node GTSAM
finds indeterminate held by a weak prior, so that degenerate geometry (an object seen along
one ray only, a robot that shares a single landmark yet) costs that node's certainty and
never the run (issues 11 and 12)."""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable
from typing import TypeVar

import gtsam

from agrislam.geometry.graph import POSE, key_kind

T = TypeVar("T")

# conditioning on a keyframe: its prior (m, rad); others only kept from floating away
FIXED_SIGMA = 1e-4
FREE_SIGMA = 10.0


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


def component(
    graph: gtsam.NonlinearFactorGraph, seed: int
) -> tuple[gtsam.NonlinearFactorGraph, set[int]]:
    """The factors of `graph` connected to node `seed` (in their order) and their nodes:
    with several robots, the part of a window that another robot's keyframe does not
    reach has no gauge of its own when conditioned on this one."""
    parent: dict[int, int] = {}

    def root(key: int) -> int:
        while parent.setdefault(key, key) != key:
            parent[key] = key = parent[parent[key]]
        return key

    keys = [list(graph.at(n).keys()) for n in range(graph.size())]
    for factor_keys in keys:
        for key in factor_keys[1:]:
            parent[root(key)] = root(factor_keys[0])
    mine = root(seed)
    out = gtsam.NonlinearFactorGraph()
    for n, factor_keys in enumerate(keys):
        if factor_keys and root(factor_keys[0]) == mine:
            out.push_back(graph.at(n))
    return out, {key for key in parent if root(key) == mine}
