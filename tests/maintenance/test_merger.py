"""The merge of sec. 2.6.3 (maintenance.Merger): objects nearer than d_inter become one,
unless, with no field prior to say how near two can be, they were detected together; a
third object living between two on their detections is merged all the same."""

import itertools

import numpy as np

from agrislam.config import SemanticsConfig
from agrislam.maintenance.merger import CROWD_MIN_FRAMES, TOGETHER_SHARE, Merger
from agrislam.mapping.objects import ObjectTable
from agrislam.mapping.spatial_index import SpatialIndex
from agrislam.semantics.beliefs import BeliefTable

XY = np.array([[0.0, 0.0], [0.1, 0.0]])  # two objects a range sigma apart
D_INTER = 0.2


def detected(frames: list[np.ndarray], xy: np.ndarray, spare_together: bool = True):
    """Objects at `xy` detected in `frames` (each the indices of the objects it saw): the
    merges the merger finds then, the merger and the ids."""
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    ids = objects.add(len(xy), 0.0)
    index = SpatialIndex()
    index.move(ids, xy)
    merger = Merger()
    merger.spare_together = spare_together
    for k, frame in enumerate(frames):
        frame = ids[frame]
        objects.seen(frame, 0, np.zeros((3, 3, 3)), xy[frame], np.zeros((len(frame), 2, 2)))
        objects.beliefs.update(frame, [{}] * len(frame), float(k))
        merger.saw(frame, xy[frame], 2 * D_INTER)
    return merger.pairs(ids, index, lambda i: xy[i], objects, D_INTER), merger, ids


def near_pair(frames: int, together: int, spare_together: bool = True):
    """Two objects detected in `frames` frames: both in the first `together`, then the
    first and the second by turns (the first once more if they are odd)."""
    both = [np.arange(2)] * together
    by_turns = [np.array([(k - together) % 2]) for k in range(together, frames)]
    return detected(both + by_turns, XY, spare_together)


def test_two_objects_detected_together_in_most_frames_stay_two():
    pairs, merger, ids = near_pair(frames=20, together=20)
    assert pairs == []
    assert merger.together(int(ids[0]), ids[1:]).tolist() == [20]


def test_one_object_split_in_two_is_merged_into_the_better_observed():
    # an outlier's frame put a detection on each once: below the share, still one object
    pairs, _, ids = near_pair(frames=22, together=1)
    assert TOGETHER_SHARE * 11 >= 1  # each was detected in 11 frames
    assert pairs == [(int(ids[0]), int(ids[1]))]


def test_with_a_field_prior_nearer_than_d_inter_is_one_plant_even_if_seen_together():
    pairs, merger, ids = near_pair(frames=20, together=20, spare_together=False)
    assert pairs == [(int(ids[0]), int(ids[1]))]
    assert merger.together(int(ids[0]), ids[1:]).tolist() == [0]  # not counted at all


# two landmarks 0.18 m apart and a third object between them (nearer to the first)
CROWD_XY = np.array([[0.0, 0.0], [0.18, 0.0], [0.08, 0.0]])


def test_an_object_between_two_fed_by_their_detections_is_merged_into_its_nearest():
    # each frame sees both landmarks; the ambiguous detection of either goes to the third
    # object by turns: each pair meets often, the three never
    frames = [np.array([0, 1])] * 20 + [np.array([0, 2]), np.array([2, 1])] * 10
    pairs, merger, ids = detected(frames, CROWD_XY)
    assert merger.together(int(ids[2]), ids[:2]).tolist() == [10, 10]
    assert CROWD_MIN_FRAMES <= 20  # seen often enough to judge
    assert pairs == [(int(ids[0]), int(ids[2]))]


def test_three_landmarks_detected_all_at_once_stay_three():
    frames = [np.array([0, 1, 2])] * 20 + [np.array([0, 2]), np.array([2, 1])] * 10
    pairs, _, _ = detected(frames, CROWD_XY)
    assert pairs == []


def test_a_crowd_too_little_seen_to_judge_stays():
    # the third object met each neighbour twice: too few frames to tell a ghost
    frames = [np.array([0, 1])] * 20 + [np.array([0, 2]), np.array([2, 1])] * 2
    pairs, _, _ = detected(frames, CROWD_XY)
    assert pairs == []


# three landmarks 0.16 m apart, each with two objects: its own and a twin beside it
TRIO = np.array([[0.0, 0.0], [0.16, 0.0], [0.08, 0.14]])
TWINS_XY = np.vstack([TRIO, TRIO + np.array([0.03, 0.03])])


def test_three_landmarks_fed_to_six_objects_lose_the_least_seen():
    # each frame detects the three landmarks, and their detections go to three of the six
    # objects, any three: every two objects meet often (no pair is spared by the pairwise
    # test), but no frame detects more than three of the six
    cycle = [np.array(c) for c in itertools.combinations(range(6), 3)]
    frames = cycle * 2 + [c for c in cycle if 5 not in c]  # the last twin is the least seen
    pairs, merger, ids = detected(frames, TWINS_XY)
    twin = int(ids[5])
    assert CROWD_MIN_FRAMES <= 20  # the twin's frames: 10 of the 20 threes, twice
    assert (merger.together(twin, ids[:5]) > TOGETHER_SHARE * 20).all()
    assert (int(ids[2]), twin) in pairs  # into its nearest


def test_a_merged_objects_frames_with_its_neighbours_count_as_its_keepers():
    frames = [np.array([0, 1])] * 3 + [np.array([2, 1])] * 4
    _, merger, ids = detected(frames, CROWD_XY)
    keep, drop, other = (int(i) for i in ids[[0, 2, 1]])
    merger.merged(keep, drop)
    assert merger.together(keep, np.array([other])).tolist() == [7]
    assert merger.together(other, np.array([keep, drop])).tolist() == [7, 0]
