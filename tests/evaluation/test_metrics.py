import dataclasses
import json
import math

import numpy as np
import pytest
from rich.console import Console

from agrislam.config import FieldSchema
from agrislam.evaluation.ground_truth import TruthObjects
from agrislam.evaluation.metrics import (
    association_scores,
    default_radius,
    evaluate,
    match_objects,
    print_metrics,
    rigid_fit,
    truth_at,
    truth_trajectories,
    write_metrics,
)
from agrislam.records import TruthObject, TruthPose
from agrislam.snapshot import MapSnapshot, ObjectMap, Trajectory

SCHEMA = FieldSchema.preset("colour_size")
COLOURS = SCHEMA.discrete["colour"].values
SIZES = SCHEMA.discrete["size"].values


def _truth(n=12):
    """Two rows 1 m apart, plants 0.4 m apart; attributes cycle through the values."""
    xy = np.array([[0.4 * (i % 6), float(i // 6)] for i in range(n)])
    return [
        TruthObject(f"p{i}", xy[i], {"colour": COLOURS[i % 7], "size": SIZES[i % 3]})
        for i in range(n)
    ]


def _track():
    t = np.arange(0.0, 10.0, 1.0)
    poses = np.column_stack([0.3 * t, 0.5 + 0.0 * t, 0.05 * t])
    return t, poses


def _snapshot(truth, xy=None, *, wrong_size=(), traj=None, dead=None, extra=None):
    xy = np.array([t.xy for t in truth]) if xy is None else np.asarray(xy, float)
    n = len(xy)
    colour = np.full((n, 7), 0.01)
    size = np.full((n, 3), 0.05)
    for k in range(n):
        src = truth[k % len(truth)].attributes
        colour[k, COLOURS.index(src["colour"])] = 0.94
        s = SIZES.index(src["size"])
        size[k, (s + 1) % 3 if k in wrong_size else s] = 0.9
    t, poses = _track()
    traj = poses if traj is None else traj
    dead = poses if dead is None else dead
    objects = ObjectMap(
        ids=np.arange(n),
        xy=xy,
        cov=np.tile(np.eye(2) * 1e-3, (n, 1, 1)),
        n_meas=np.full(n, 5),
        interest=np.zeros(n),
        row=np.zeros(n, int),
        discrete={"colour": colour, "size": size},
    )
    return MapSnapshot(
        schema=SCHEMA,
        objects=objects,
        trajectories={"r1": Trajectory("r1", t, traj)},
        dead_reckoning={"r1": Trajectory("r1", t, dead)},
        **(extra or {}),
    )


def _truth_poses():
    t, poses = _track()
    return [TruthPose(float(a), "r1", p) for a, p in zip(t, poses, strict=True)]


def test_perfect_estimate_scores_perfectly():
    truth = _truth()
    m = evaluate(_snapshot(truth), truth, _truth_poses())
    o = m["objects"]
    assert (o["mapped"], o["missed"], o["duplicates"], o["false_objects"]) == (12, 0, 0, 0)
    assert o["mapped_fraction"] == 1.0 and o["position_rms"] == 0.0
    assert o["match_radius"] == pytest.approx(0.2)  # half the 0.4 m plant distance
    assert m["attributes"]["colour"] == {"accuracy": 1.0, "n": 12}
    assert m["attributes"]["size"] == {"accuracy": 1.0, "n": 12}
    for kind in ("optimised", "dead_reckoning"):
        assert m["trajectory"][kind]["rms_position"] == 0.0
        assert m["trajectory"][kind]["rms_heading"] == 0.0
        assert m["trajectory"][kind]["n"] == 10
    assert m["alignment"] == {"applied": False}


def test_truth_as_arrays_scores_as_the_records_do():
    """The pipeline hands evaluate a TruthObjects table and each robot's true trajectory:
    the same metrics as the records they came from."""
    truth = _truth()
    later = TruthObject("p3", truth[3].xy + 0.05, {"colour": "red", "size": "big"})
    snap = _snapshot(truth, np.array([o.xy for o in truth]) + 0.02, wrong_size=(1, 5))
    records = evaluate(snap, [*truth, later], _truth_poses(), align=True)
    tables = evaluate(
        snap,
        TruthObjects.of([*truth, later]),
        truth_trajectories(_truth_poses()),
        align=True,
    )
    assert tables == records and records["attributes"]["size"]["accuracy"] < 1


def test_shifted_estimate_scores_the_shift_and_nothing_after_alignment():
    truth = _truth()
    shift = np.array([0.09, -0.12])  # 0.15 m, inside the matching radius
    _, poses = _track()
    moved = poses.copy()
    moved[:, :2] += shift
    snap = _snapshot(truth, np.array([o.xy for o in truth]) + shift, traj=moved, dead=moved)
    m = evaluate(snap, truth, _truth_poses())
    assert m["objects"]["mapped"] == 12
    assert m["objects"]["position_rms"] == pytest.approx(0.15)
    assert m["trajectory"]["optimised"]["rms_position"] == pytest.approx(0.15)
    assert m["trajectory"]["optimised"]["rms_heading"] == pytest.approx(0.0, abs=1e-12)
    m = evaluate(snap, truth, _truth_poses(), align=True)
    assert m["objects"]["position_rms"] == pytest.approx(0.0, abs=1e-9)
    assert m["trajectory"]["optimised"]["rms_position"] == pytest.approx(0.0, abs=1e-9)
    al = m["alignment"]
    assert al["applied"] and al["source"] == "trajectory" and al["n_pairs"] == 10
    assert al["translation"] == pytest.approx([-0.09, 0.12])
    assert al["rotation_deg"] == pytest.approx(0.0, abs=1e-9)


def test_other_frame_is_found_by_alignment():
    """Truth in a motion-capture frame: the map is rotated 30 deg and 3 m away."""
    truth = _truth()
    angle, shift = math.radians(30), np.array([3.0, -1.0])
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    _, poses = _track()
    moved = np.column_stack([poses[:, :2] @ rot.T + shift, poses[:, 2] + angle])
    snap = _snapshot(truth, np.array([o.xy for o in truth]) @ rot.T + shift, traj=moved, dead=moved)
    assert evaluate(snap, truth, _truth_poses())["objects"]["mapped"] == 0
    m = evaluate(snap, truth, _truth_poses(), align=True)
    assert m["objects"]["mapped"] == 12 and m["objects"]["position_rms"] < 1e-9
    assert m["alignment"]["rotation_deg"] == pytest.approx(-30.0)
    assert m["trajectory"]["dead_reckoning"]["rms_heading"] == pytest.approx(0.0, abs=1e-9)


def test_alignment_from_objects_when_there_is_no_trajectory():
    truth = _truth()
    angle, shift = math.radians(2.0), np.array([0.12, 0.05])
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    snap = _snapshot(truth, np.array([o.xy for o in truth]) @ rot.T + shift)
    m = evaluate(snap, truth, [], align=True)
    assert m["alignment"]["source"] == "objects"
    assert m["objects"]["position_rms"] == pytest.approx(0.0, abs=1e-9)
    assert m["trajectory"]["optimised"]["n"] == 0  # no truth poses: nothing to compare


def test_a_duplicated_object_counts_once_as_duplicate_and_a_stray_as_false():
    truth = _truth()
    xy = np.array([o.xy for o in truth])
    est = np.vstack([xy, xy[3] + [0.05, 0.0], [[10.0, 10.0]]])
    m = evaluate(_snapshot(truth, est), truth)
    o = m["objects"]
    assert (o["mapped"], o["duplicates"], o["false_objects"], o["n_estimated"]) == (12, 1, 1, 14)
    assert o["duplicate_fraction"] == pytest.approx(1 / 12)
    assert o["position_rms"] == 0.0  # the exact estimate is the match, not the duplicate


def test_missed_plants_and_wrong_sizes():
    truth = _truth()
    xy = np.array([o.xy for o in truth])
    m = evaluate(_snapshot(truth[:10], xy[:10], wrong_size=(0, 4)), truth)
    assert (m["objects"]["mapped"], m["objects"]["missed"]) == (10, 2)
    assert m["attributes"]["size"]["accuracy"] == pytest.approx(0.8)
    assert m["attributes"]["colour"]["accuracy"] == 1.0


def test_matching_takes_the_most_pairs_not_the_greedy_nearest():
    truth = np.array([[0.0, 0.0], [0.35, 0.0]])
    est = np.array([[0.17, 0.0], [-0.19, 0.0]])  # greedy: e0 -> t0, then e1 has nothing
    e, t = match_objects(est, truth, 0.2)
    assert sorted(zip(e.tolist(), t.tolist(), strict=True)) == [(0, 1), (1, 0)]
    # and among equally many pairs, the shortest total distance
    e, t = match_objects(np.array([[0.0, 0.05], [0.0, -0.15]]), np.array([[0.0, 0.0]]), 0.2)
    assert (e.tolist(), t.tolist()) == ([0], [0])
    assert match_objects(np.zeros((0, 2)), truth, 0.2)[0].size == 0


def test_purity_and_completeness_by_hand():
    assoc = [("a", 1)] * 3 + [("a", 2)] + [("b", 2)] * 2 + [(None, 3)]
    s = association_scores(assoc)
    # objects: 1 holds a x3 (3), 2 holds a x1 + b x2 (2): purity 5/6
    # truths: a went 3 to object 1 and 1 to object 2 (3), b 2 to object 2 (2): completeness 5/6
    assert s["purity"] == pytest.approx(5 / 6) and s["completeness"] == pytest.approx(5 / 6)
    assert (s["n_detections"], s["n_clutter"], s["truths"]) == (7, 1, 2)
    assert (s["truths_split"], s["objects_mixed"]) == (1, 1)
    assert s["truths_one_object_fraction"] == 0.5
    perfect = association_scores([("a", 1), ("a", 1), ("b", 2)])
    assert perfect["purity"] == perfect["completeness"] == 1.0
    merged = association_scores([("a", 1), ("b", 1)])  # two plants as one object
    assert merged["purity"] == 0.5 and merged["completeness"] == 1.0
    split = association_scores([("a", 1), ("a", 2)])  # one plant as two objects
    assert split["purity"] == 1.0 and split["completeness"] == 0.5
    shifted = association_scores([(t, 4 * o - 7) for t, o in assoc])  # any ids, negative too
    assert shifted == s
    truth = _truth()
    m = evaluate(_snapshot(truth), truth, associations=assoc)
    assert m["association"]["purity"] == pytest.approx(5 / 6)


def test_trajectory_is_compared_at_the_estimates_times():
    t_truth = np.array([0.0, 2.0, 4.0])
    truth = np.array([[0.0, 0.0, 3.0], [2.0, 0.0, -3.0], [4.0, 2.0, -2.9]])
    # heading interpolated across +-pi: halfway between 3.0 and -3.0 is pi, not 0
    np.testing.assert_allclose(truth_at(t_truth, truth, np.array([1.0]))[0], [1.0, 0.0, -np.pi])
    est = Trajectory(
        "r1",
        np.array([1.0, 3.0, 5.0]),
        np.array([[1.0, 0.3, np.pi], [3.0, 1.0, -2.95], [9.0, 9.0, 0.0]]),
    )
    snap = MapSnapshot(
        schema=None,
        objects=_snapshot(_truth()).objects,
        trajectories={"r1": est},
        dead_reckoning={},
    )
    poses = [TruthPose(float(a), "r1", p) for a, p in zip(t_truth, truth, strict=True)]
    m = evaluate(snap, [], poses)["trajectory"]
    # t = 5 is outside the truth; errors 0.3 m and 0 at t = 1, 0 m and 0 rad at t = 3
    assert m["optimised"]["n"] == 2
    assert m["optimised"]["rms_position"] == pytest.approx(math.sqrt(0.3**2 / 2))
    assert m["optimised"]["rms_heading"] == pytest.approx(0.0, abs=1e-12)
    assert m["dead_reckoning"]["n"] == 0 and m["dead_reckoning"]["rms_position"] is None


def test_continuous_attribute_rms_and_bias():
    schema = FieldSchema.preset("colour_length")
    truth = [
        TruthObject("a", np.zeros(2), {"colour": "red", "length": 0.3}),
        TruthObject("b", np.array([1.0, 0]), {"colour": "red", "length": 0.2}),
    ]
    objects = ObjectMap(
        ids=np.arange(2),
        xy=np.array([[0.0, 0], [1.0, 0]]),
        cov=np.zeros((2, 2, 2)),
        n_meas=np.ones(2, int),
        interest=np.zeros(2),
        row=np.zeros(2, int),
        discrete={"colour": np.tile(np.eye(7)[5], (2, 1))},
        continuous={"length": (np.array([0.4, 0.1]), np.array([0.01, 0.01]))},
    )
    snap = MapSnapshot(schema=schema, objects=objects, trajectories={}, dead_reckoning={})
    m = evaluate(snap, truth, radius=0.2)
    assert m["attributes"]["length"]["rms"] == pytest.approx(0.1)
    assert m["attributes"]["length"]["bias"] == pytest.approx(0.0)
    assert m["attributes"]["colour"]["accuracy"] == 1.0


def test_later_truth_replaces_earlier_and_default_radius():
    truth = _truth()
    later = TruthObject("p0", truth[0].xy, {"colour": truth[0].attributes["colour"], "size": "big"})
    m = evaluate(_snapshot(truth), [*truth, later])
    assert m["objects"]["n_truth"] == 12
    assert m["attributes"]["size"]["accuracy"] == pytest.approx(11 / 12)  # p0 grew to big
    grid = np.array([[0.4 * i, 0.0] for i in range(50)])
    assert default_radius(grid) == pytest.approx(0.2)
    assert default_radius(grid, min_plant_distance=0.3) == pytest.approx(0.15)


def test_rigid_fit_recovers_a_transform():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 2))
    a, t = 0.7, np.array([1.0, -2.0])
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    angle, shift = rigid_fit(src, src @ rot.T + t)
    assert angle == pytest.approx(a) and shift == pytest.approx(t)


def test_metrics_json_and_table(tmp_path):
    truth = _truth()
    snap = _snapshot(truth, extra={"step_times": {"associate": np.array([0.001, 0.002, 0.010])}})
    m = evaluate(
        snap,
        [*truth[:11], TruthObject("far", np.array([50.0, 50.0]))],
        _truth_poses(),
        associations=[("p0", 0)],
    )
    assert m["timings"]["associate"]["p50_s"] == pytest.approx(0.002)
    assert m["timings"]["associate"]["max_s"] == pytest.approx(0.010)
    m["objects"]["nan_example"] = float("nan")
    path = write_metrics(m, tmp_path / "metrics.json")
    back = json.loads(path.read_text())
    assert back["objects"]["mapped"] == 11 and back["objects"]["nan_example"] is None
    assert back["trajectory"]["optimised"]["per_robot"]["r1"]["n"] == 10
    console = Console(record=True, width=100)
    print_metrics(m, console)
    text = console.export_text()
    assert "plants mapped" in text and "11 / 12" in text and "dead reckoning" in text


def test_the_table_leaves_out_what_the_log_has_no_truth_for():
    # Victoria Park: which tree each detection saw, no tree positions, no true track
    snap = _snapshot(_truth())
    m = evaluate(snap, [], [], associations=[("tree1", 0), ("tree1", 0), ("tree2", 1)])
    console = Console(record=True, width=100)
    print_metrics(m, console)
    text = console.export_text()
    assert "association purity" in text and "100.0 %" in text
    assert "false objects" not in text and "dead reckoning" not in text


def test_a_steps_time_is_the_sum_of_its_stages():
    times = {"associate": np.array([0.001, 0.002]), "geometry": np.array([0.010, 0.030])}
    snap = _snapshot(_truth(), extra={"step_times": times})
    np.testing.assert_allclose(snap.step_seconds(), [0.011, 0.032])
    assert len(_snapshot(_truth()).step_seconds()) == 0


def test_objects_within_fixed_radii_are_counted_one_to_one():
    truth = [dataclasses.replace(t, xy=np.array([2.0 * i, 0.0])) for i, t in enumerate(_truth(3))]
    # 0.1 m, 0.2 m and 0.4 m off, and a second object 0.05 m off the first landmark
    est = np.array([[0.1, 0.0], [2.0, 0.2], [4.4, 0.0], [0.0, 0.05]])
    within = evaluate(_snapshot(truth, est), truth)["objects"]["within"]
    assert [(w["radius"], w["matched"]) for w in within] == [(0.3, 2), (0.15, 1)]
    assert within[0]["position_rms"] == pytest.approx(math.sqrt((0.05**2 + 0.2**2) / 2))
    assert within[1]["position_rms"] == pytest.approx(0.05)


def test_the_trajectorys_halves_are_scored_apart():
    t, poses = _track()
    drifted = poses.copy()
    drifted[t > 4.5, 1] += 0.2  # the second half of 0-9 s, 0.2 m off
    m = evaluate(_snapshot(_truth(), traj=drifted), _truth(), _truth_poses())["trajectory"]
    assert m["optimised"]["rms_position_first_half"] == pytest.approx(0.0)
    assert m["optimised"]["rms_position_second_half"] == pytest.approx(0.2)
    assert m["dead_reckoning"]["rms_position_second_half"] == pytest.approx(0.0)
