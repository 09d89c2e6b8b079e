"""The arena scenario: records that obey the log spec, odometry drifting by the configured
amount, a camera that sees what is in range and view with the configured noise and outliers,
clustered landmarks, determinism, and the noisy landmark attribute."""

from collections import Counter

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from agrislam.geometry.se2 import wrap_angle
from agrislam.io.sinks.jsonl import write_log
from agrislam.io.sources.jsonl import read_log
from agrislam.io.sources.sync import synchronise
from agrislam.records import Detections, Meta, Odometry, TruthObject, TruthPose
from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.arena_config import (
    ArenaConfig,
    ArenaOdometry,
    LandmarkAttribute,
    RangeBearingCamera,
)
from agrislam.sim.landmarks import clustered_landmarks
from agrislam.sim.odometry import drifting_odometry, increments, integrate, random_walk_variance
from agrislam.sim.random_drive import segment_distance
from agrislam.sim.range_bearing import observe, read_ids

SMALL = {"driving": {"duration_s": 60.0, "n_robots": 2}}


def _cfg(seed: int = 1, **over) -> ArenaConfig:
    merged = {**SMALL, **over}
    merged["driving"] = {**SMALL["driving"], **over.get("driving", {})}
    return ArenaConfig.model_validate({"seed": seed, **merged})


def _records(seed: int = 1, **over) -> list:
    return list(ArenaSimulator(_cfg(seed, **over)).records())


def _of(kind, records):
    return [r for r in records if isinstance(r, kind)]


# ------------------------------------------------------------------ the log and its order


def test_records_round_trip_through_the_log_strictly(tmp_path):
    recs = _records(attribute={"enabled": True})
    path = tmp_path / "arena.jsonl"
    n = write_log(recs, path)
    reader = read_log(path)  # strict: a record against the spec would raise
    back = list(reader)
    assert n == len(recs) == len(back) == reader.report.records
    assert [type(r) for r in back] == [type(r) for r in recs]
    kinds = Counter(type(r).__name__ for r in back)
    assert kinds["Meta"] == 1 and kinds["TruthObject"] == 17
    assert kinds["Odometry"] == kinds["TruthPose"] == 2 * (60 * 50 + 1)  # 50 Hz, both ends
    d0 = next(r for r in recs if isinstance(r, Detections))
    b0 = next(r for r in back if isinstance(r, Detections))
    assert d0.objects[0].attributes == b0.objects[0].attributes
    assert b0.objects[0].range == pytest.approx(d0.objects[0].range)


def test_meta_has_start_poses_and_no_field_no_schema_unless_the_attribute_is_on():
    sim = ArenaSimulator(_cfg())
    meta = next(sim.records())
    assert isinstance(meta, Meta) and meta.schema is None and meta.field is None
    assert meta.anchor is None and set(meta.robots) == {"r1", "r2"}
    for robot in sim.robots:
        np.testing.assert_array_equal(meta.robots[robot.name].pose, robot.poses[0])
    first = next(ArenaSimulator(_cfg(driving={"start_poses": "first"})).records())
    assert set(first.robots) == {"r1"}
    with_attr = ArenaSimulator(_cfg(attribute={"enabled": True}))
    schema = next(with_attr.records()).schema
    assert list(schema.attributes) == ["landmark"]
    assert schema.attributes["landmark"].values == with_attr.landmarks.ids


def test_records_are_in_time_order_and_every_frame_is_placed():
    recs = _records()
    assert isinstance(recs[0], Meta) and all(isinstance(r, TruthObject) for r in recs[1:18])
    timed = [r for r in recs if isinstance(r, (Odometry, Detections, TruthPose))]
    t = np.array([r.t for r in timed])
    assert (np.diff(t) >= 0).all()  # all robots interleaved in one time order
    sync = synchronise(recs)
    list(sync)
    assert not sync.unplaced and sync.n_interpolated > 0  # frames fall between odometry
    frames = _of(Detections, recs)
    assert all(f.objects for f in frames)  # a frame that sees nothing is not written
    every = _of(Detections, _records(camera={"empty_frames": True}))
    r1 = np.array([f.t for f in every if f.robot == "r1"])
    np.testing.assert_allclose(np.diff(r1), 1 / 3)  # 3 Hz
    assert len(every) > len(frames) and not np.isin(r1, np.arange(3001) / 50).all()


# --------------------------------------------------------------------------- odometry


def test_odometry_records_dead_reckon_to_the_simulated_track():
    sim = ArenaSimulator(_cfg())
    recs = list(sim.records())
    robot = sim.robots[1]
    odo = [r for r in recs if isinstance(r, Odometry) and r.robot == robot.name]
    np.testing.assert_array_equal(odo[0].delta, 0.0)  # the start marker
    assert np.linalg.eigvalsh(odo[0].cov).min() > 0  # a graph back end can use it
    dr = integrate(robot.poses[0], np.array([o.delta for o in odo[1:]]))
    np.testing.assert_allclose(dr, robot.odometry.dead_reckoned, atol=1e-12)
    truth = np.array([r.pose for r in recs if isinstance(r, TruthPose) and r.robot == robot.name])
    np.testing.assert_allclose(truth, robot.poses)
    assert np.linalg.norm(dr[-1, :2] - truth[-1, :2]) > 0.01  # noisy


def test_dead_reckoning_drifts_about_a_metre_in_five_minutes():
    """The drift statistic the defaults are calibrated on: RMS over robots and seeds of the
    dead-reckoned position error after 5 minutes."""

    def drift(**odometry) -> float:
        errors = []
        for seed in range(1, 9):
            cfg = ArenaConfig.model_validate(
                {"seed": seed, "driving": {"duration_s": 300.0}, "odometry": odometry}
            )
            for robot in ArenaSimulator(cfg).robots:
                errors.append(robot.odometry.dead_reckoned[-1, :2] - robot.poses[-1, :2])
        return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1))))

    assert 0.75 <= drift() <= 1.3
    assert drift(heading_bias_per_m=0.0, scale_bias=0.0) < 0.8  # the biases add their part
    assert drift(heading_bias_per_m=0.012) > 1.8  # and it follows the configured bias


def _straight_line(n: int, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """A robot driving 0.2 m/s straight on while turning 0.1 rad/s, sampled at `rate`."""
    t = np.arange(n) / rate
    theta = 0.1 * t
    xy = 2.0 * np.column_stack([np.sin(theta), 1 - np.cos(theta)])  # radius 2 m
    return np.column_stack([xy, theta]), t


def test_noise_is_reported_by_the_configured_factors_and_the_biases_not_at_all():
    noise = ArenaOdometry(scale_bias=0.0, heading_bias_per_m=0.0)
    poses, t = _straight_line(40_000, 50.0)
    track = drifting_odometry(poses, t, noise, np.random.default_rng(4))
    err = track.delta - increments(poses)
    err[:, 2] = wrap_angle(err[:, 2])
    z = err / np.sqrt(np.diagonal(track.cov, axis1=1, axis2=2))
    np.testing.assert_allclose(z.std(axis=0), [1.0, 1.0, 4.0], rtol=0.03)  # heading 1/0.25
    biased = ArenaOdometry(scale_bias=0.05, heading_bias_per_m=0.01)
    again = drifting_odometry(poses, t, biased, np.random.default_rng(4))
    np.testing.assert_allclose(again.cov, track.cov)  # the biases are not reported
    ratio = np.sum(again.delta[:, 0]) / np.sum(increments(poses)[:, 0])
    assert abs(ratio - 1.0) > 1e-3  # a scale error of its own


def test_the_noise_does_not_depend_on_the_odometry_rate():
    noise = ArenaOdometry()
    totals = []
    for rate in (10.0, 50.0, 200.0):
        poses, t = _straight_line(int(600 * rate) + 1, rate)
        totals.append(random_walk_variance(increments(poses), np.diff(t), noise).sum(axis=0))
    np.testing.assert_allclose(totals[1], totals[0], rtol=1e-3)
    np.testing.assert_allclose(totals[2], totals[0], rtol=1e-3)


# ------------------------------------------------------------------------ paths, arena


def test_robots_stay_in_the_arena_off_the_landmarks_and_turn_on_the_spot():
    sim = ArenaSimulator(_cfg(driving={"duration_s": 900.0}))
    d = sim.cfg.driving
    half = np.array(sim.cfg.arena.size) / 2
    for robot in sim.robots:
        xy = robot.poses[:, :2]
        assert (np.abs(xy) <= half - d.wall_margin + 1e-9).all()
        assert cdist(xy, sim.landmarks.xy).min() >= d.landmark_clearance - 0.05  # arcs cut in
        step = increments(robot.poses)
        speed = np.hypot(step[:, 0], step[:, 1]) * sim.cfg.odometry.rate_hz
        assert speed.max() <= d.speed[1] + 1e-6 and np.median(speed) >= d.speed[0]
        spinning = (speed < 1e-9) & (np.abs(step[:, 2]) > 1e-3)
        assert 0.01 < spinning.mean() < 0.3  # sometimes, not mostly


def test_segment_distance_by_hand():
    a, b = np.array([[0.0, 0.0]]), np.array([[2.0, 0.0]])
    pts = np.array([[1.0, 1.0], [-1.0, 0.0], [3.0, 1.0]])
    np.testing.assert_allclose(segment_distance(a, b, pts), [[1.0, 1.0, np.sqrt(2)]])


@pytest.mark.parametrize("spacing", [(0.15, 0.2), (0.3, 0.35)])
def test_clusters_at_the_configured_distances(spacing):
    for seed in range(6):
        cfg = ArenaConfig.model_validate({"arena": {"cluster_spacing": spacing}})
        lm = clustered_landmarks(cfg.arena, np.random.default_rng(seed))
        assert len(lm) == 17 and sorted(Counter(lm.group.tolist()).values()) == [1] * 10 + [2, 2, 3]
        d = cdist(lm.xy, lm.xy) + np.diag(np.full(len(lm), np.inf))
        same = lm.group[:, None] == lm.group[None, :]
        clustered = np.bincount(lm.group)[lm.group] > 1
        nearest = np.where(same, d, np.inf).min(axis=1)[clustered]
        assert spacing[0] - 1e-9 <= nearest.min() and nearest.max() <= spacing[1] + 1e-9
        assert d[~same].min() >= cfg.arena.separation
        assert (np.abs(lm.xy) <= np.array(cfg.arena.size) / 2 - cfg.arena.wall_margin).all()


# ---------------------------------------------------------------------------- camera


def _random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-7, 7, n), rng.uniform(-3.6, 3.6, n), rng.uniform(-np.pi, np.pi, n)]
    )


def test_detections_are_the_landmarks_in_range_and_view_with_the_configured_noise():
    sim = ArenaSimulator(_cfg(driving={"duration_s": 180.0}))
    cam, recs = sim.cfg.camera, list(sim.records())
    half_fov = np.deg2rad(cam.fov_deg) / 2
    xy = dict(zip(sim.landmarks.ids, sim.landmarks.xy, strict=True))
    res_r, res_b, n_seen, n_in_view = [], [], 0, 0
    for robot in sim.robots:
        for frame in [f for f in _of(Detections, recs) if f.robot == robot.name]:
            pose = robot.drive.sample(np.array([frame.t]))[0]
            d = np.array([xy[o.truth_id] for o in frame.objects]) - pose[:2]
            r = np.hypot(d[:, 0], d[:, 1])
            b = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2])
            assert ((r >= cam.min_range) & (r <= cam.max_range)).all()
            assert (np.abs(b) <= half_fov).all()
            res_r += [o.range - ri for o, ri in zip(frame.objects, r, strict=True)]
            res_b += [wrap_angle(o.bearing - bi) for o, bi in zip(frame.objects, b, strict=True)]
            assert {o.sigma_range for o in frame.objects} == {0.13}  # outliers too
            assert {o.sigma_bearing for o in frame.objects} == {0.015}
            n_seen += len(frame.objects)
        # nothing in view is missed: count the pairs in range and view at every frame
        d = sim.landmarks.xy[None] - robot.poses_frames[:, None, :2]
        r = np.hypot(d[..., 0], d[..., 1])
        b = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - robot.poses_frames[:, 2:3])
        n_in_view += int(
            ((r >= cam.min_range) & (r <= cam.max_range) & (np.abs(b) <= half_fov)).sum()
        )
    assert n_seen == n_in_view > 500
    res_r, res_b = np.array(res_r), np.array(res_b)
    inlier = np.abs(res_r) < 5 * cam.sigma_range
    assert res_r[inlier].std() == pytest.approx(0.13, rel=0.1)
    assert res_b.std() == pytest.approx(0.015, rel=0.1)
    assert 0.003 < (~inlier).mean() < 0.04  # about 2 %, some land near the truth


@pytest.mark.parametrize("rate", [0.02, 0.1])
def test_outlier_rate_as_configured(rate):
    cam = RangeBearingCamera(sigma_range=1e-4, outlier_rate=rate)
    landmarks = clustered_landmarks(ArenaConfig().arena, np.random.default_rng(3)).xy
    seen = observe(_random_poses(30_000, 5), landmarks, cam, np.random.default_rng(6))
    wild = np.abs(seen.range - seen.true_range) > 0.01
    assert len(seen) > 20_000
    assert wild.mean() == pytest.approx(rate * (1 - 0.02 / 4.7), abs=0.004)
    assert seen.range[wild].min() >= cam.min_range and seen.range[wild].max() <= cam.max_range


# ------------------------------------------------------------------ seeds and attribute


def test_deterministic_per_seed_with_independent_streams(tmp_path):
    paths = [tmp_path / f"{k}.jsonl" for k in range(3)]
    for path, seed in zip(paths, (5, 5, 6), strict=True):
        write_log(_records(seed), path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert paths[0].read_bytes() != paths[2].read_bytes()
    base, other = _records(5), _records(5, camera={"outlier_rate": 0.3})
    for kind in (Odometry, TruthPose):  # the camera's stream leaves the drive alone
        for a, b in zip(_of(kind, base), _of(kind, other), strict=True):
            np.testing.assert_array_equal(
                a.delta if kind is Odometry else a.pose, b.delta if kind is Odometry else b.pose
            )
    ranges = [o.range for f in _of(Detections, base) for o in f.objects]
    assert ranges != [o.range for f in _of(Detections, other) for o in f.objects]


def test_the_attribute_reports_a_wrong_id_at_the_configured_rate():
    recs = _records(attribute={"enabled": True, "error_rate": 0.2, "p": 0.8})
    dets = [o for f in _of(Detections, recs) for o in f.objects]
    assert {o.attributes["landmark"].p for o in dets} == {0.8}
    wrong = np.mean([o.attributes["landmark"].value != o.truth_id for o in dets])
    assert wrong == pytest.approx(0.2, abs=0.06)  # a few hundred detections
    truth = _of(TruthObject, recs)
    assert all(t.attributes == {"landmark": t.id} for t in truth)
    # many reads: the rate to the percent, the wrong ids spread over all the others
    landmark = np.repeat(np.arange(17), 4000)
    read = read_ids(landmark, 17, LandmarkAttribute(error_rate=0.1), np.random.default_rng(2))
    assert (read != landmark).mean() == pytest.approx(0.1, abs=0.006)
    assert set(read[(landmark == 4) & (read != 4)].tolist()) == set(range(17)) - {4}
    off = _records(attribute={"enabled": False})
    assert all(not o.attributes for f in _of(Detections, off) for o in f.objects)
