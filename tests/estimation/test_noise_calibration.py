"""Noise that calibrates itself (estimation/noise_calibration.py, issue 11): the variance factors
from pairs of sightings, robust to wrong pairs, bounded, and applied to odometry parts."""

from __future__ import annotations

from itertools import takewhile

import numpy as np
import pytest

from agrislam.config import AgrislamConfig, CalibrationConfig
from agrislam.estimation.noise_calibration import (
    ANCHOR_SPAN,
    FISHER_ITERATIONS,
    MIN_SPREAD_PAIRS,
    PAIRS_A_CALL,
    Anchors,
    NoiseCalibration,
    NoiseScale,
    nearest_other,
    pair_components,
)
from agrislam.geometry import se2
from agrislam.geometry.drift import odometry_parts
from agrislam.io.sources.jsonl import read_log
from agrislam.run.pipeline import run_survey
from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.config import ArenaConfig
from agrislam.world import WorldModel
from paths import SHARED_DATA

Q = np.array([[4e-4, 1e-5, 2e-5], [1e-5, 1e-4, 0.0], [2e-5, 0.0, 9e-6]])


def test_odometry_parts_sum_to_the_covariance_and_scale_as_its_sigmas():
    parts = odometry_parts(Q)
    np.testing.assert_allclose(parts.sum(axis=0), Q)
    scale = NoiseScale(np.array([1.0, 4.0, 9.0]))  # sigmas x2 translation, x3 heading
    s = np.diag([2.0, 2.0, 3.0])
    np.testing.assert_allclose(scale.odometry(parts), s @ Q @ s)
    # parts compose like the covariance they sum to (linear in the covariance)
    d = np.array([0.5, 0.1, 0.2])
    _, composed = se2.compose_increments(d, parts, d, parts)
    _, whole = se2.compose_increments(d, Q, d, Q)
    np.testing.assert_allclose(composed.sum(axis=0), whole, atol=1e-15)


def synthetic_pairs(rng, n, sigma_factors, wrong=0.0):
    """n pairs whose d is drawn from the model with the given true sigma factors, the
    first `wrong` share replaced by far-off wrong pairs (another object 2-8 m away)."""
    xy = rng.uniform(-5, 5, (n, 2))
    cov = np.tile(np.diag([0.01, 0.0025]), (n, 1, 1))
    drift = np.zeros((3, 3, 3))
    seen_drift = np.zeros((n, 3, 3, 3))
    steps = rng.integers(1, 40, n)[:, None, None]
    seen_drift[:, 0] = -steps * np.diag([1e-4, 1e-4, 0.0])  # the chain came `steps` far
    seen_drift[:, 1] = -steps * np.diag([0.0, 0.0, 4e-6])
    d0, comps = pair_components(xy, cov, drift, xy, cov, seen_drift)
    v = np.asarray(sigma_factors) ** 2
    total = np.einsum("c,ncij->nij", v, comps)
    d = np.stack([rng.multivariate_normal(np.zeros(2), c) for c in total])
    k = int(wrong * n)
    angle = rng.uniform(0, 2 * np.pi, k)
    d[:k] = rng.uniform(2, 8, k)[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    assert np.allclose(d0, 0.0)
    return d, comps


def calibration(**settings) -> NoiseCalibration:
    return NoiseCalibration(CalibrationConfig(min_pairs=200, update_every=10**9, **settings))


@pytest.mark.parametrize("wrong", [0.0, 0.1])
def test_the_estimate_finds_the_true_factors_despite_wrong_pairs(wrong):
    rng = np.random.default_rng(3)
    cal = calibration(sigma_bounds=(0.05, 30.0))
    cal.add_pairs(*synthetic_pairs(rng, 3000, [0.7, 3.0, 3.0], wrong))
    v = NoiseScale.configured().variance
    for _ in range(4):  # each estimate moves a sigma by at most 2x
        v = cal.estimate(v)
    np.testing.assert_allclose(np.sqrt(v), [0.7, 3.0, 3.0], rtol=0.1)
    assert cal.pairs_used == pytest.approx(3000 * (1 - wrong), rel=0.03)


def test_by_default_noise_found_smaller_than_configured_is_not_used():
    rng = np.random.default_rng(5)
    cal = calibration()
    cal.add_pairs(*synthetic_pairs(rng, 2000, [0.5, 2.0, 2.0]))
    v = cal.estimate(cal.estimate(NoiseScale.configured().variance))
    np.testing.assert_allclose(np.sqrt(v)[0], 1.0)  # a floor: the detection stays as logged
    assert np.sqrt(v)[1] > 1.5


def test_one_estimate_moves_a_sigma_by_at_most_a_factor_of_two():
    rng = np.random.default_rng(6)
    cal = calibration()
    cal.add_pairs(*synthetic_pairs(rng, 2000, [1.0, 10.0, 10.0]))
    v = cal.estimate(NoiseScale.configured().variance)
    np.testing.assert_allclose(np.sqrt(v)[1:], 2.0)


def test_the_estimate_is_renewed_every_so_many_pairs_and_reported():
    rng = np.random.default_rng(7)
    cal = NoiseCalibration(CalibrationConfig(min_pairs=200, update_every=250))
    d, comps = synthetic_pairs(rng, 1000, [1.0, 2.0, 2.0])
    for start in range(0, 1000, 50):
        cal.add_pairs(d[start : start + 50], comps[start : start + 50])
    report = cal.report()
    # due at 250 and done 7 calls later (600), due again at once and done at 1000
    assert report["updates"] == 2 and report["pairs_seen"] == 1000
    assert report["sigma_factors"]["heading"] == report["sigma_factors"]["translation"] > 1.5


def test_an_estimate_takes_an_iteration_a_call_and_ends_where_one_made_at_once_does():
    rng = np.random.default_rng(11)
    d, comps = synthetic_pairs(rng, 300, [1.0, 3.0, 3.0])
    config = CalibrationConfig(min_pairs=200, update_every=250)
    at_once = NoiseCalibration(config.model_copy(update={"update_every": 10**6}))
    at_once.add_pairs(d[:250], comps[:250])
    expected = at_once.estimate(NoiseScale.configured().variance)
    paced = NoiseCalibration(config)
    paced.add_pairs(d[:250], comps[:250])  # due: the first of FISHER_ITERATIONS
    path = [paced.scale.variance[2]]
    for k in range(1, FISHER_ITERATIONS):
        assert paced.updates == 0  # under way: each iteration's factors apply at once
        paced.add_pairs(d[250 + k : 251 + k], comps[250 + k : 251 + k])
        path.append(paced.scale.variance[2])
    np.testing.assert_array_equal(paced.scale.variance, expected)
    assert paced.updates == 1 and paced.pairs_used == at_once.pairs_used
    assert 1.0 < path[0] < path[-1]  # the scale moves up to the estimate step by step


def test_an_iteration_over_more_pairs_than_a_call_sums_is_paced_and_ends_the_same():
    rng = np.random.default_rng(5)
    n = 2 * PAIRS_A_CALL + 500
    d, comps = synthetic_pairs(rng, n, [1.0, 2.0, 2.0])
    config = CalibrationConfig(min_pairs=200, update_every=n, max_pairs=n)
    at_once = NoiseCalibration(config)
    at_once._d[:], at_once._components[:], at_once.pairs_seen = d, comps, n
    whole = at_once._start(np.ones(3))
    assert whole.advance(n) and whole.done == 1  # one iteration in one part
    paced = NoiseCalibration(config)
    paced.add_pairs(d, comps)  # due: the first of three parts of the first iteration
    assert paced.scale.variance.tolist() == [1.0, 1.0, 1.0]
    paced.add_pairs(d[:1], comps[:1])
    assert paced.scale.variance.tolist() == [1.0, 1.0, 1.0]
    paced.add_pairs(d[1:2], comps[1:2])  # the third part ends the iteration
    np.testing.assert_allclose(paced.scale.variance, at_once._factors(whole), rtol=1e-12)


def test_only_the_latest_max_pairs_pairs_are_kept():
    rng = np.random.default_rng(3)
    cal = NoiseCalibration(CalibrationConfig(min_pairs=10, update_every=10_000, max_pairs=100))
    d, comps = synthetic_pairs(rng, 250, [1.0, 1.0, 1.0])
    cal.add_pairs(d[:70], comps[:70])
    cal.add_pairs(d[70:250], comps[70:250])  # more than the ring holds at once
    assert cal.pairs_kept == 100 and cal.pairs_seen == 250
    kept = {tuple(row) for row in cal._d}
    assert kept == {tuple(row) for row in d[150:]}


def test_a_disabled_calibration_keeps_the_configured_noise():
    cal = NoiseCalibration(CalibrationConfig(enabled=False, min_pairs=10))
    d, comps = synthetic_pairs(np.random.default_rng(8), 500, [1.0, 5.0, 5.0])
    cal.add_pairs(d, comps)
    np.testing.assert_array_equal(cal.scale.variance, 1.0)


def test_the_arena_finds_its_under_reported_odometry_noise():
    """The arena's odometry reports a heading sigma 4x too small (sim/config.py): after
    90 s the run's own re-sightings have scaled the odometry up, and say so."""
    arena = ArenaConfig.model_validate({"seed": 2, "driving": {"duration_s": 90.0}})
    world = WorldModel(AgrislamConfig())
    result = run_survey(list(ArenaSimulator(arena).records()), world)
    noise = result.noise
    assert noise is not None and noise["updates"] >= 1
    assert 2.0 <= noise["sigma_factors"]["heading"] <= 8.0


def test_nearest_other_is_the_distance_to_the_nearest_object_but_that_one():
    dist = np.array([[1.0, 3.0, 2.0], [5.0, 4.0, 6.0]])
    np.testing.assert_array_equal(nearest_other(dist), [[2.0, 1.0, 1.0], [4.0, 5.0, 4.0]])
    assert np.isinf(nearest_other(np.array([[1.0]]))).all()  # nothing else around


def test_an_anchor_pairs_once_the_drift_since_it_outweighs_the_detection_noise():
    """Anchors: the first sighting anchors; later ones pair against it (not against the
    last one) until the chain's drift since it outweighs the detection terms, then that
    sighting becomes the anchor; another robot's sighting does not pair with it."""
    anchors, scale = Anchors(slots=8), NoiseScale.configured()
    ids, cov = np.array([3, 12]), np.tile(0.01 * np.eye(2), (2, 1, 1))

    def sighting(x: float, heading_var: float, robot: int = 0):
        drift = odometry_parts(np.diag([0.0, 0.0, heading_var]))
        xy = np.array([[x, 1.0], [x, 2.0]])
        return anchors.pair(ids, robot, (xy, cov, drift), scale)

    _, _, ripe = sighting(5.0, 0.0)
    assert not ripe.any()  # anchored now
    d, _, ripe = sighting(5.1, 1e-5)  # drift ~1e-5 * |p|^2 << 0.02: not ripe
    assert not ripe.any() and np.allclose(d[:, 0], 0.1)
    d, comps, ripe = sighting(5.3, 1e-2)
    assert ripe.all() and np.allclose(d[:, 0], 0.3)  # against the first sighting
    assert np.all(np.trace(comps[:, 2], axis1=1, axis2=2) > 0.02)
    _, _, ripe = sighting(5.4, 1e-2, robot=1)
    assert not ripe.any()  # robot 1 had no anchor: it takes the slots
    d, _, ripe = sighting(5.45, 1e-2, robot=1)
    assert not ripe.any() and np.allclose(d[:, 0], 0.05)


def test_an_anchor_the_robot_drifted_far_from_is_renewed_without_a_pair():
    """A sighting after a long absence (the drift since over ANCHOR_SPAN x the detection
    terms: mostly a real robot's bias, not a random walk) makes no pair; it anchors, and
    the next sighting pairs against it."""
    anchors, scale = Anchors(slots=8), NoiseScale.configured()
    ids, cov = np.array([3, 12]), np.tile(0.01 * np.eye(2), (2, 1, 1))

    def sighting(x: float, heading_var: float):
        drift = odometry_parts(np.diag([0.0, 0.0, heading_var]))
        xy = np.array([[x, 1.0], [x, 2.0]])
        return anchors.pair(ids, 0, (xy, cov, drift), scale)

    sighting(5.0, 0.0)
    _, comps, ripe = sighting(6.0, 0.1)  # drift ~2.6 against detection terms of 0.04
    drift = np.trace(comps[:, 1:].sum(axis=1), axis1=1, axis2=2)
    assert np.all(drift > ANCHOR_SPAN * 0.04) and not ripe.any()
    d, _, ripe = sighting(6.2, 0.105)  # drift ~0.2 since the sighting at 6.0
    assert ripe.all() and np.allclose(d[:, 0], 0.2)


def _sighted_again(cal: NoiseCalibration, rng: np.random.Generator, sigma: float, n: int) -> None:
    """n objects 5 m apart seen again by robot 0 a frame later (no drift), each sighting
    scattered by `sigma`, each claiming a sigma of a micrometre."""
    truth = np.column_stack([np.arange(n) * 5.0, np.zeros(n)])
    cov, drift = np.tile(1e-12 * np.eye(2), (n, 1, 1)), np.zeros((3, 3, 3))
    then, now = (truth + rng.normal(0.0, sigma, (n, 2)) for _ in range(2))
    dist = np.full((n, n), 5.0)
    np.fill_diagonal(dist, 0.01)
    last = (np.ones(n, dtype=bool), then, cov, np.zeros((n, 3, 3, 3)))
    cal.observe((now, cov, drift), 0, np.arange(n), last, np.eye(n, dtype=bool), dist)


def test_a_detection_far_surer_than_its_re_sightings_is_raised_to_their_spread():
    """The spread of re-sightings a frame apart is a floor from the first pairs on (the
    configured detection noise before them): a covariance claiming a sigma ten times
    below it is raised to it, whatever the variance factor; a fair one is left alone."""
    cal = NoiseCalibration(CalibrationConfig(), detection_sigma=0.03)
    covs = np.stack([1e-12 * np.eye(2), np.diag([0.01, 0.0025])])
    np.testing.assert_allclose(cal.detection_floor(covs), [0.03**2, 0.0])
    _sighted_again(cal, np.random.default_rng(0), 0.05, MIN_SPREAD_PAIRS * 4)
    floor = cal.detection_floor(covs)
    assert floor[1] == 0.0 and floor[0] == pytest.approx(0.05**2, rel=0.3)


def test_victoria_park_finds_its_heading_noise_without_a_config():
    """The log's heading sigma is ~9x too small (examples/victoria_park.yaml sets 7x by
    hand): in its first 2000 s the default config estimates a factor in the hand tuning's
    range from its own re-sightings (4.2 from consecutive sightings alone, 9.6 with
    anchors of any span: the car's drift over a long absence is mostly bias)."""
    log = SHARED_DATA / "victoria_park" / "victoria_park.jsonl"
    if not log.exists():
        pytest.skip("Victoria Park data not present")
    records = takewhile(lambda r: getattr(r, "t", 0.0) <= 2000.0, read_log(log))
    noise = run_survey(records, WorldModel(AgrislamConfig())).noise
    assert noise is not None and noise["anchor_pairs"] >= 5
    assert 5.0 <= noise["sigma_factors"]["heading"] <= 10.0
