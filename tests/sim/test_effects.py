"""A real sensor's effects in both simulators: each is off by default and draws nothing then,
and each, turned on, has the sign and size it is configured with: the depth-like range by
bearing, range-dependent noise, heavy-tailed and offset bearings, misread labels, blind
spells, the odometry's clock offset and turn scale; and the arena's realistic profile."""

import numpy as np
import pytest
from scipy import stats

from agrislam.geometry.se2 import wrap_angle
from agrislam.records import Detections, Odometry
from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.arena_config import ArenaConfig, ArenaOdometry, RangeBearingCamera
from agrislam.sim.config import OdometryNoise, SimConfig
from agrislam.sim.detector import Detector
from agrislam.sim.effects import (
    CameraBias,
    bearing_noise,
    blind_spells,
    blinded,
    misread_labels,
    range_sigma,
)
from agrislam.sim.effects_config import CameraEffects, OdometryEffects
from agrislam.sim.field import make_field
from agrislam.sim.landmarks import clustered_landmarks
from agrislam.sim.odometry import drifting_odometry, increments, noisy_odometry
from agrislam.sim.range_bearing import observe
from agrislam.sim.simulator import Simulator
from quiet_arena import QUIET_ODOMETRY

LANDMARKS = clustered_landmarks(ArenaConfig().arena, np.random.default_rng(3)).xy


def _random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-7, 7, n), rng.uniform(-3.6, 3.6, n), rng.uniform(-np.pi, np.pi, n)]
    )


def _seen(bias: CameraBias | None = None, **camera):
    cam = RangeBearingCamera.model_validate({"outlier_rate": 0.0, **camera})
    rng, fx = np.random.default_rng(6), np.random.default_rng(7)
    return observe(_random_poses(20_000, 5), LANDMARKS, cam, rng, bias, fx)


def _robust_sigma(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


# ------------------------------------------------------------------------ off by default


def test_without_effects_the_camera_draws_what_the_plain_model_drew():
    cam = RangeBearingCamera()
    poses = _random_poses(3000, 1)
    seen = observe(poses, LANDMARKS, cam, np.random.default_rng(2))
    rng = np.random.default_rng(2)
    n = len(seen)
    noisy = seen.true_range + rng.normal(0.0, cam.sigma_range, n)
    outlier = rng.random(n) < cam.outlier_rate
    wild = rng.uniform(cam.min_range, cam.max_range, n)
    np.testing.assert_array_equal(seen.range, np.maximum(np.where(outlier, wild, noisy), 0.01))
    bearing = wrap_angle(seen.true_bearing + rng.normal(0.0, cam.sigma_bearing, n))
    np.testing.assert_array_equal(seen.bearing, bearing)
    np.testing.assert_array_equal(seen.label, seen.landmark)
    assert CameraBias.draw(CameraEffects(), rng) == CameraBias()


def test_the_defaults_leave_every_effect_off():
    assert ArenaConfig().camera.effects == CameraEffects()
    assert ArenaConfig().odometry.effects == OdometryEffects()
    assert SimConfig().detector.effects == CameraEffects()
    assert SimConfig().odometry.effects == OdometryEffects()
    rng = np.random.default_rng(0)
    assert len(blind_spells(0.0, 1e4, CameraEffects(), rng)) == 0
    state = rng.bit_generator.state
    misread_labels(np.arange(50), 60, CameraEffects(), rng)
    assert rng.bit_generator.state == state  # nothing drawn


# --------------------------------------------------------------------------------- range


def test_the_range_reads_depth_along_the_axis_shorter_off_axis_longer_by_the_scale():
    bias = CameraBias(range_scale=1.04)
    seen = _seen(bias, sigma_range=1e-4, fov_deg=70.0, effects={"off_axis_depth": 1.0})
    err, r, b = seen.range - seen.true_range, seen.true_range, np.abs(seen.true_bearing)
    on_axis, off_axis = b < 0.1, b > 0.5
    # r_meas = s r cos b: +4 % on the axis, 1.04 cos(0.55) - 1 = -11 % at its edge
    np.testing.assert_allclose(np.median(err[on_axis] / r[on_axis]), 0.04 * np.cos(0.05), atol=3e-3)
    assert np.median(err[off_axis] / r[off_axis]) == pytest.approx(
        1.04 * np.cos(0.55) - 1, abs=0.01
    )
    np.testing.assert_allclose(seen.range, 1.04 * r * np.cos(seen.true_bearing), atol=1e-3)
    half = _seen(bias, sigma_range=1e-4, fov_deg=70.0, effects={"off_axis_depth": 0.5})
    expected = 1.04 * r - 0.5 * 1.04 * r * (1 - np.cos(seen.true_bearing))
    np.testing.assert_allclose(half.range, expected, atol=1e-3)


def test_the_range_scale_is_drawn_per_robot_with_the_configured_spread():
    fx = CameraEffects(range_scale=1.03, range_scale_spread=0.01, bearing_offset_spread=0.02)
    draws = [CameraBias.draw(fx, np.random.default_rng(k)) for k in range(2000)]
    scale = np.array([d.range_scale for d in draws])
    offset = np.array([d.bearing_offset for d in draws])
    assert scale.mean() == pytest.approx(1.03, abs=1e-3) and scale.std() == pytest.approx(
        0.01, rel=0.1
    )
    assert offset.mean() == pytest.approx(0.0, abs=2e-3) and offset.std() == pytest.approx(
        0.02, rel=0.1
    )


def test_range_noise_grows_with_range():
    seen = _seen(sigma_range=0.01, effects={"sigma_range_per_m": 0.02})
    err, r = seen.range - seen.true_range, seen.true_range
    for lo, hi in ((1.0, 2.0), (4.0, 5.0)):
        inside = (r >= lo) & (r < hi)
        expected = float(
            np.mean(range_sigma(r[inside], 0.01, CameraEffects(sigma_range_per_m=0.02)))
        )
        assert err[inside].std() == pytest.approx(expected, rel=0.06)
    assert err[r > 4].std() > 2.5 * err[r < 2].std()


# ------------------------------------------------------------------------------- bearing


def test_student_t_bearings_keep_the_robust_sigma_and_fatten_the_tails():
    fx = CameraEffects(bearing_dof=2.5)
    e = bearing_noise(200_000, 0.01, fx, np.random.default_rng(1))
    sigma = _robust_sigma(e)
    assert sigma == pytest.approx(0.01, rel=0.02)
    scale = 1.4826 * stats.t.ppf(0.75, 2.5)
    assert np.mean(np.abs(e) > 3 * sigma) == pytest.approx(2 * stats.t.sf(3 * scale, 2.5), rel=0.05)
    assert np.mean(np.abs(e) > 3 * sigma) > 10 * 0.0027  # a Gaussian's share
    gauss = bearing_noise(200_000, 0.01, CameraEffects(), np.random.default_rng(1))
    assert np.mean(np.abs(gauss) > 0.03) == pytest.approx(0.0027, abs=0.0005)


def test_a_robot_bearing_offset_shifts_every_bearing():
    seen = _seen(CameraBias(bearing_offset=-0.04), sigma_bearing=0.01)
    err = wrap_angle(seen.bearing - seen.true_bearing)
    assert np.median(err) == pytest.approx(-0.04, abs=1e-3)


# ------------------------------------------------------------------ misreads, blind spells


def test_misread_detections_are_labelled_as_another_landmark():
    seen = _seen(effects={"misread_rate": 0.05})
    wrong = seen.label != seen.landmark
    assert wrong.mean() == pytest.approx(0.05, abs=0.004)
    assert set(seen.label[wrong & (seen.landmark == 3)].tolist()) <= set(range(17)) - {3}
    sim = ArenaSimulator(
        ArenaConfig.model_validate(
            {
                "driving": {"duration_s": 120.0, "n_robots": 2},
                "camera": {"effects": {"misread_rate": 0.1}},
            }
        )
    )
    ids = sim.landmarks.ids
    dets = [o for r in sim.records() if isinstance(r, Detections) for o in r.objects]
    robot = sim.robots[0]
    labelled = [ids[i] for i in robot.seen.label]
    assert sum(a != ids[b] for a, b in zip(labelled, robot.seen.landmark, strict=True)) > 0
    assert {o.truth_id for o in dets} <= set(ids)


def test_blind_spells_come_at_the_configured_rate_and_hide_every_landmark():
    fx = CameraEffects(blind_per_minute=0.5, blind_duration_s=(20.0, 30.0))
    spells = blind_spells(0.0, 6000.0, fx, np.random.default_rng(3))
    assert len(spells) == pytest.approx(50, abs=20)
    assert ((spells[:, 1] - spells[:, 0] >= 20.0) & (spells[:, 1] - spells[:, 0] <= 30.0)).all()
    assert blinded(np.array([spells[0, 0] + 1.0, spells[0, 0] - 1e-3]), spells[:1]).tolist() == [
        True,
        False,
    ]
    cfg = ArenaConfig.model_validate(
        {"driving": {"duration_s": 600.0, "n_robots": 2}, "camera": {"effects": fx.model_dump()}}
    )
    sim = ArenaSimulator(cfg)
    for robot in sim.robots:
        assert len(robot.blind) > 0
        assert not blinded(robot.t_frames[robot.seen.frame], robot.blind).any()
        frames = np.unique(robot.t_frames[robot.seen.frame])
        assert np.diff(frames).max() >= 20.0  # a spell is a gap at least as long


def test_p_detect_reads_that_share_of_the_landmarks_in_view():
    sim = ArenaSimulator
    full = sim(ArenaConfig.model_validate({"driving": {"duration_s": 300.0, "n_robots": 1}}))
    some = sim(
        ArenaConfig.model_validate(
            {"driving": {"duration_s": 300.0, "n_robots": 1}, "camera": {"p_detect": 0.3}}
        )
    )
    assert len(some.robots[0].seen) / len(full.robots[0].seen) == pytest.approx(0.3, abs=0.04)


def test_reported_sigmas_and_no_odometry_covariance_as_a_converted_real_log():
    cfg = ArenaConfig.model_validate(
        {
            "driving": {"duration_s": 60.0, "n_robots": 1},
            "camera": {"reported_sigmas": (0.15, 0.02)},
            "odometry": {"report_covariance": False},
        }
    )
    recs = list(ArenaSimulator(cfg).records())
    dets = [o for r in recs if isinstance(r, Detections) for o in r.objects]
    assert {(o.sigma_range, o.sigma_bearing) for o in dets} == {(0.15, 0.02)}
    assert all(r.cov is None for r in recs if isinstance(r, Odometry))


# ------------------------------------------------------------------------------ odometry


def _quiet_arena(offset: float) -> ArenaSimulator:
    odometry = {**QUIET_ODOMETRY, "effects": {"clock_offset_s": offset}}
    cfg = {"driving": {"duration_s": 300.0, "n_robots": 1}, "odometry": odometry}
    return ArenaSimulator(ArenaConfig.model_validate(cfg))


def test_the_clock_offset_turns_the_odometry_ahead_of_the_camera_during_a_turn():
    """Odometry stamped 0.3 s ahead: at a frame's time its heading is the truth's 0.3 s later,
    so a landmark's bearing predicted from it is off by the turn rate x 0.3 s."""
    offset = 0.3
    robot = _quiet_arena(offset).robots[0]
    t = robot.t_frames[(robot.t_frames > 1.0) & (robot.t_frames < 290.0)]
    heading = np.interp(t, robot.t_odom, np.unwrap(robot.odometry.dead_reckoned[:, 2]))
    truth_now = np.unwrap(robot.drive.sample(t)[:, 2])
    rate = (robot.drive.sample(t + 0.01)[:, 2] - robot.drive.sample(t - 0.01)[:, 2]) / 0.02
    steady = np.abs(rate - (robot.drive.sample(t + offset)[:, 2] - truth_now) / offset) < 1e-3
    turning = steady & (np.abs(rate) > 0.1)
    assert turning.sum() > 20
    lead = wrap_angle(heading - truth_now)
    # a landmark's predicted bearing is its direction minus this heading: off by -rate x 0.3
    np.testing.assert_allclose(lead[turning], rate[turning] * offset, atol=0.01)
    straight = np.abs(rate) < 1e-6
    np.testing.assert_allclose(lead[straight & steady], 0.0, atol=1e-3)
    plain = _quiet_arena(0.0).robots[0]
    np.testing.assert_allclose(
        wrap_angle(plain.odometry.dead_reckoned[:, 2] - plain.poses[:, 2]), 0.0, atol=1e-6
    )


def _circle(n: int, rate: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) / rate
    theta = 0.1 * t
    xy = 2.0 * np.column_stack([np.sin(theta), 1 - np.cos(theta)])
    return np.column_stack([xy, theta]), t


def test_each_robot_turns_by_a_scale_of_its_own_in_both_odometries():
    poses, t = _circle(5000, 50.0)
    true_turn = increments(poses)[:, 2].sum()
    arena, field = [], []
    for seed in range(200):
        quiet = ArenaOdometry(
            heading_bias_per_m=0.0, scale_bias=0.0, effects={"turn_scale_spread": 0.05}
        )
        track = drifting_odometry(poses, t, quiet, np.random.default_rng(seed))
        arena.append(track.delta[:, 2].sum() / true_turn)
        noise = OdometryNoise(
            heading_bias=0.0, heading_bias_walk=0.0, effects={"turn_scale_spread": 0.05}
        )
        track = noisy_odometry(poses, t, noise, np.random.default_rng(seed))
        field.append(track.delta[:, 2].sum() / true_turn)
    for scales in (np.array(arena), np.array(field)):
        assert scales.mean() == pytest.approx(1.0, abs=0.01)
        assert scales.std() == pytest.approx(0.05, rel=0.15)


# ------------------------------------------------------------------------ field detector


def _one_plant_detector(**effects):
    cfg = SimConfig.model_validate(
        {
            "field": {"n_plants": 40, "n_rows": 1, "row_jitter": 0.0},
            "detector": {
                "geometry": "range_bearing",
                "clutter_rate": 0.0,
                "double_detection_p": 0.0,
                "depth_bias_fraction": 0.0,
                "sigma_depth_0": 1e-4,
                "sigma_depth_per_m2": 0.0,
                "sigma_lateral_0": 0.0,
                "sigma_bearing": 0.0,
                "camera_xy": (0.0, 0.0),
                "effects": effects,
            },
        }
    )
    field = make_field(cfg, np.random.default_rng(0))
    return field, Detector(field, cfg.detector)


def test_the_field_detector_reads_depth_and_misreads_plants():
    field, det = _one_plant_detector(off_axis_depth=1.0, misread_rate=0.2)
    rng = np.random.default_rng(1)
    bias = CameraBias(range_scale=1.05, bearing_offset=0.02)
    where = dict(zip(field.ids.tolist(), field.xy, strict=True))
    err, wrong, n = [], 0, 0
    for x in np.linspace(-3.0, 10.0, 160):
        for heading in (-0.5, 0.0, 0.5):
            pose = np.array([x, -1.0, heading])
            for d in det.frame(pose, rng, bias):
                n += 1
                xy = where[d.truth_id] - pose[:2]
                r = np.hypot(*xy)
                b = wrap_angle(np.arctan2(xy[1], xy[0]) - heading)
                if abs(wrap_angle(d.bearing - 0.02 - b)) > 1e-3:
                    wrong += 1
                    continue
                err.append(d.range - 1.05 * r * np.cos(b))
    assert n > 500
    assert wrong / n == pytest.approx(0.2, abs=0.04)
    np.testing.assert_allclose(err, 0.0, atol=2e-3)


def test_the_field_simulator_goes_blind_and_stamps_its_odometry_ahead():
    cfg = SimConfig.model_validate(
        {
            "field": {"n_plants": 80, "n_rows": 2},
            "detector": {"effects": {"blind_per_minute": 2.0, "blind_duration_s": (10.0, 10.0)}},
            "odometry": {"effects": {"clock_offset_s": 0.5}},
        }
    )
    sim = Simulator(cfg)
    recs = list(sim.records())
    frames = [r for r in recs if isinstance(r, Detections)]
    empty = np.mean([not f.objects for f in frames])
    assert empty > 0.1  # blind for tens of seconds of a few-minute survey
    sv = sim.survey(0, 0)
    ahead = sim.paths[0].sample(sv.t_odom + 0.5, cfg.path.speed)
    np.testing.assert_allclose(
        increments(ahead)[:, 2], sv.odometry.delta[:, 2], atol=0.05
    )  # the noisy increments follow the poses half a second ahead


# -------------------------------------------------------------------- realistic profile


def test_the_realistic_profile_turns_the_effects_on_and_takes_changes():
    cfg = ArenaConfig.realistic({"seed": 4, "driving": {"duration_s": 60.0}})
    assert cfg.seed == 4 and cfg.driving.duration_s == 60.0
    assert cfg.driving.n_robots == 5 and cfg.camera.effects == CameraEffects.mrclam()
    assert cfg.odometry.effects == OdometryEffects.mrclam()
    assert not cfg.odometry.report_covariance and cfg.camera.reported_sigmas is not None
    assert sum(cfg.arena.clusters) == 15 and cfg.arena.single_landmarks == 0
    assert ArenaConfig() != cfg
