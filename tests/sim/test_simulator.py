from collections import Counter

import numpy as np
import pytest

from agrislam.io.sinks.jsonl import write_log
from agrislam.io.sources.jsonl import read_log
from agrislam.io.sources.sync import synchronise
from agrislam.records import Detections, Meta, Odometry, TruthObject, TruthPose
from agrislam.sim.config import SimConfig
from agrislam.sim.odometry import integrate
from agrislam.sim.simulator import Simulator

SMALL = {"field": {"n_plants": 60, "n_rows": 4}}


def _sim(**over):
    return Simulator(SimConfig.model_validate({**SMALL, **over}))


def test_default_run_is_the_papers_400_plant_survey():
    sim = Simulator()
    recs = list(sim.records())
    meta = recs[0]
    assert isinstance(meta, Meta) and set(meta.schema.attributes) == {"colour", "size"}
    assert meta.anchor.lat == 51.4488 and meta.anchor.lon == 5.4905
    assert meta.field.row_spacing == 1.0 and meta.field.min_plant_distance == 0.4
    assert meta.field.row_angle_deg is None  # the mapper estimates it (sec. 2.6.2)
    np.testing.assert_allclose(meta.robots["r1"].pose, [-1.0, 0.5, 0.0])
    truth = [r for r in recs if isinstance(r, TruthObject)]
    assert len(truth) == 400 and all(isinstance(r, TruthObject) for r in recs[1:401])
    dets = [d for r in recs if isinstance(r, Detections) for d in r.objects]
    per_plant = Counter(d.truth_id for d in dets if d.truth_id is not None)
    # each plant is seen several times (the brief: several frames per pass, two passes)
    assert len(per_plant) == 400 and np.median(list(per_plant.values())) >= 10
    frames = [r for r in recs if isinstance(r, Detections)]
    assert np.diff([f.t for f in frames]) == pytest.approx(0.5)  # 2 Hz


def test_every_frame_has_odometry_of_its_robot_at_its_time_and_time_never_goes_back():
    recs = list(_sim(path={"n_robots": 2}).records())
    last_odom: dict[str, float] = {}
    last_t: dict[str, float] = {}
    robots = set()
    for r in recs:
        if isinstance(r, (Odometry, Detections, TruthPose)):
            assert r.t >= last_t.get(r.robot, -np.inf)
            last_t[r.robot] = r.t
            robots.add(r.robot)
        if isinstance(r, Odometry):
            last_odom[r.robot] = r.t
        if isinstance(r, Detections):
            assert last_odom[r.robot] == r.t
    assert robots == {"r1", "r2"}


def test_odometry_records_dead_reckon_to_the_simulated_track():
    sim = _sim()
    recs = list(sim.records())
    start = recs[0].robots["r1"].pose
    odo = [r for r in recs if isinstance(r, Odometry)]
    np.testing.assert_array_equal(odo[0].delta, 0.0)  # the start marker
    np.testing.assert_allclose(odo[0].cov, np.diag([1e-8, 1e-8, 1e-8]))  # standing still
    assert np.linalg.eigvalsh(odo[0].cov).min() > 0  # a graph back end can use it
    dr = integrate(start, np.array([o.delta for o in odo[1:]]))
    np.testing.assert_allclose(dr, sim.survey(0, 0).odometry.dead_reckoned, atol=1e-12)
    truth = np.array([r.pose for r in recs if isinstance(r, TruthPose)])
    np.testing.assert_allclose(truth, sim.survey(0, 0).poses_odom)
    assert np.linalg.norm(dr[-1, :2] - truth[-1, :2]) > 0.01  # noisy


def test_pose_odometry_is_the_same_motion():
    a = [r for r in _sim().records() if isinstance(r, Odometry)]
    b = [r for r in _sim(odometry={"kind": "pose"}).records() if isinstance(r, Odometry)]
    np.testing.assert_array_equal(b[0].pose, 0.0)
    np.testing.assert_allclose(
        b[-1].pose, integrate(np.zeros(3), np.array([o.delta for o in a[1:]]))[-1]
    )


def test_deterministic_per_seed(tmp_path):
    paths = [tmp_path / f"{k}.jsonl" for k in range(3)]
    for path, seed in zip(paths, (5, 5, 6), strict=True):
        write_log(Simulator(SimConfig.model_validate({**SMALL, "seed": seed})).records(), path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert paths[0].read_bytes() != paths[2].read_bytes()


def test_recorded_log_reads_back_strictly(tmp_path):
    path = tmp_path / "sim.jsonl"
    cfg = SimConfig.model_validate(
        {**SMALL, "schema": "crops_weeds", "field": {**SMALL["field"], "weed_fraction": 0.1}}
    )
    n = write_log(Simulator(cfg).records(), path)
    reader = read_log(path)
    back = list(reader)
    assert len(back) == n == reader.report.records and not reader.report.skipped
    direct = list(Simulator(cfg).records())
    assert [type(r) for r in back] == [type(r) for r in direct]
    d0 = next(r for r in direct if isinstance(r, Detections) and r.objects)
    b0 = next(r for r in back if isinstance(r, Detections) and r.objects)
    assert d0.objects[0].attributes == b0.objects[0].attributes
    weeds = [r for r in back if isinstance(r, TruthObject) and r.attributes["type"] == "weed"]
    assert len(weeds) == 6


def test_faster_odometry_is_synchronised_to_the_frames():
    recs = list(_sim(path={"odom_rate_hz": 5.0}).records())
    frames = [r.t for r in recs if isinstance(r, Detections)]
    odo = [r.t for r in recs if isinstance(r, Odometry)]
    assert len(odo) > 2 * len(frames)
    sync = synchronise(recs)
    out = list(sync)
    assert not sync.unplaced
    last = None
    for r in out:
        if isinstance(r, Odometry):
            last = r.t
        elif isinstance(r, Detections):
            assert r.t == last


def test_survey_days_grow_the_truth_and_start_new_robots():
    sim = _sim(growth={"survey_days": [0.0, 30.0]})
    recs = list(sim.records())
    assert set(recs[0].robots) == {"r1_d0", "r1_d1"}
    truth = [r for r in recs if isinstance(r, TruthObject)]
    assert len(truth) == 120
    np.testing.assert_array_equal(truth[0].xy, truth[60].xy)
    day2 = [r for r in recs if isinstance(r, Odometry) and r.robot == "r1_d1"]
    assert day2[0].t == 30 * 86400.0
    np.testing.assert_allclose(
        sim.field_on(1).length, 0.6 - (0.6 - sim.field.length) * np.exp(-sim.field.growth_rate * 30)
    )
    sizes = ["small", "medium", "big"]
    grew = [
        sizes.index(truth[k + 60].attributes["size"]) - sizes.index(truth[k].attributes["size"])
        for k in range(60)
    ]
    assert min(grew) >= 0 and max(grew) >= 1
    alone = list(sim.day_records(1))
    assert set(alone[0].robots) == {"r1"} and alone[-1].t >= 30 * 86400.0


def test_return_to_start_sees_the_first_plants_again():
    recs = list(_sim(path={"return_to_start": True}).records())
    frames = [r for r in recs if isinstance(r, Detections)]
    first = {d.truth_id for f in frames[:20] for d in f.objects if d.truth_id}
    last = {d.truth_id for f in frames[-20:] for d in f.objects if d.truth_id}
    assert len(first & last) >= 5
