"""The merge of sec. 2.6.3 (maintenance.Merger): objects nearer than d_inter become one,
unless, with no field prior to say how near two can be, they were detected together."""

import numpy as np

from agrislam.config import SemanticsConfig
from agrislam.maintenance import TOGETHER_SHARE, Merger
from agrislam.objects import ObjectTable
from agrislam.semantics.beliefs import BeliefTable
from agrislam.spatial_index import SpatialIndex

XY = np.array([[0.0, 0.0], [0.1, 0.0]])  # two objects a range sigma apart
D_INTER = 0.2


def near_pair(frames: int, together: int, spare_together: bool = True):
    """Two objects detected in `frames` frames: both in the first `together`, then the
    first and the second by turns (the first once more if they are odd)."""
    objects = ObjectTable(BeliefTable(None, SemanticsConfig()))
    ids = objects.add(2, 0.0)
    index = SpatialIndex()
    index.move(ids, XY)
    merger = Merger()
    merger.spare_together = spare_together
    for k in range(frames):
        frame = ids if k < together else ids[(k - together) % 2 :][:1]
        objects.seen(frame, 0, np.zeros((3, 3, 3)), XY[frame], np.zeros((len(frame), 2, 2)))
        objects.beliefs.update(frame, [{}] * len(frame), float(k))
        merger.saw(frame, XY[frame], 2 * D_INTER)
    return merger.pairs(ids, index, lambda i: XY[i], objects, D_INTER), merger, ids


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
