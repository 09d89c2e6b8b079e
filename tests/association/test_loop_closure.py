"""A returning robot closes the loop (association/loop_closure.py): its newest objects,
moved far past
the association's gate by its drift, merge into the old objects of the same place when one
rigid motion puts enough of them there, and no other place fits about as well."""

from collections import Counter

import numpy as np
import pytest

from agrislam.association.loop_closure import CLOSED, MIN_FRAMES, RECENT_S, LoopCloser
from agrislam.config import SemanticsConfig
from agrislam.estimation.point_spacing import PointSpacing
from agrislam.geometry import se2
from agrislam.mapping.births import Births
from agrislam.mapping.objects import ObjectTable
from agrislam.semantics.beliefs import BeliefTable

ROBOT = 0
DRIFT = np.array([12.0, -7.0, 0.5])  # (dx, dy, dtheta) the returning robot is off by
DETECTION_VARIANCE = 0.6**2  # per axis, as Victoria Park's 0.4 m^2 trace


class Positions:
    """The back end as the loop closer sees it: the objects' estimates."""

    def __init__(self, xy: np.ndarray) -> None:
        self.xy = xy

    def object_positions(self, ids: np.ndarray) -> np.ndarray:
        return self.xy[ids]


def scattered(n: int, seed: int) -> np.ndarray:
    """`n` trees scattered over 60 m x 60 m, none within 3 m of another."""
    rng, trees = np.random.default_rng(seed), []
    while len(trees) < n:
        xy = rng.uniform(0.0, 60.0, 2)
        if all(np.hypot(*(xy - t)) > 3.0 for t in trees):
            trees.append(xy)
    return np.array(trees)


def drifted(xy: np.ndarray, drift: np.ndarray = DRIFT) -> np.ndarray:
    """Points as a robot off by `drift` (about the points' middle) maps them."""
    centre = xy.mean(axis=0)
    return (xy - centre) @ se2.rotation(drift[2]).T + centre + drift[:2]


def closer_over(
    old_xy: np.ndarray, new_xy: np.ndarray, old_seen_until: float = 100.0
) -> tuple[LoopCloser, list[tuple[int, int]]]:
    """Objects `old_xy` started at t = 0 and last seen at `old_seen_until`, then `new_xy`
    started at t = 400 by the robot; the loop closer's pairs at t = 450."""
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    births = Births(RECENT_S)
    objects.add(len(old_xy), old_seen_until)  # a belief's time is its last update
    births.record(0.0, len(objects))
    objects.add(len(new_xy), 450.0)
    births.record(400.0, len(objects))
    ids = np.arange(len(objects))
    for _ in range(MIN_FRAMES):
        cov = np.repeat(DETECTION_VARIANCE * np.eye(2)[None], len(ids), axis=0)
        objects.seen(ids, ROBOT, np.zeros((3, 3, 3)), np.zeros((len(ids), 2)), cov)
    closer = LoopCloser(births, Counter(), 9.21, PointSpacing(0.2))  # reach 2 d_inter = 0.4
    xy = np.r_[old_xy, new_xy]
    return closer, closer.pairs(ROBOT, 450.0, objects, Positions(xy), 1.0)


def test_a_returning_robots_new_objects_merge_into_the_old_ones_of_that_place():
    trees = scattered(40, seed=3)
    rng = np.random.default_rng(4)
    back = trees[:8] + rng.normal(0.0, 0.1, (8, 2))  # seen again, through the drift
    elsewhere = scattered(5, seed=5) + 100.0  # and five trees it never saw before
    closer, pairs = closer_over(trees, np.r_[drifted(back), elsewhere])
    assert sorted(pairs) == [(i, 40 + i) for i in range(8)]
    assert closer.issues[CLOSED] == 1


def test_old_objects_seen_while_the_new_ones_were_are_other_objects():
    trees = scattered(40, seed=3)
    _, pairs = closer_over(trees, drifted(trees[:8]), old_seen_until=420.0)
    assert pairs == []


def test_a_place_that_repeats_itself_closes_nothing():
    # a grid of trees 4 m apart: the constellation fits many places equally well
    grid = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), axis=-1).reshape(-1, 2) * 4.0
    drift = np.array([12.0, -7.0, 0.0])
    _, pairs = closer_over(grid, drifted(grid[[11, 12, 13, 21, 22, 23, 31, 32]], drift))
    assert pairs == []


@pytest.mark.parametrize("matched", [MIN_FRAMES, 4])
def test_too_few_objects_in_common_close_nothing(matched):
    trees = scattered(40, seed=3)
    _, pairs = closer_over(trees, np.r_[drifted(trees[:matched]), scattered(3, 6) + 100.0])
    assert pairs == []


def test_a_constellation_already_in_place_is_left_to_association():
    trees = scattered(40, seed=3)
    _, pairs = closer_over(trees, drifted(trees[:8], np.array([0.2, 0.1, 0.0])))
    assert pairs == []


def test_births_say_which_objects_are_older_than_a_time():
    births = Births(keep_s=100.0)
    births.record(0.0, 5)
    births.record(10.0, 5)  # nothing started: nothing recorded
    births.record(20.0, 9)
    assert births.below(-1.0) == 0 and births.below(19.0) == 5 and births.below(20.0) == 9
    assert births.started(4) == 0.0 and births.started(7) == 20.0
    births.record(150.0, 12)  # what was more than keep_s before goes, but the last before
    assert births.below(50.0) == 9 and births.below(200.0) == 12 and births.below(19.0) == 0
    assert births.started(10) == 150.0
    with pytest.raises(ValueError, match="not started"):
        births.started(12)
