"""The dead-reckoning drift since an object was last seen (geometry/drift.py) and the
odometry chain that accumulates it (geometry/odometry.py)."""

import numpy as np
import pytest

from agrislam.estimation.noise_calibration import NoiseScale
from agrislam.geometry import se2
from agrislam.geometry.drift import adjoint, since_seen
from agrislam.geometry.odometry import OdometryChain

Q = np.diag([0.02**2, 0.01**2, 0.01**2])  # per step: x, y, heading
STEP = np.array([0.5, 0.0, 0.04])  # a gentle left curve
CONFIGURED = NoiseScale.configured()  # the chain keeps its covariance in parts


def test_adjoint_moves_a_perturbation_across_the_pose():
    pose, eta = np.array([3.0, -2.0, 0.7]), np.array([1e-3, -2e-3, 3e-4])
    # P Exp(eta) P^-1 = Exp(Ad eta); to first order on a point, both move it alike
    point = np.array([1.5, 4.0])
    local = se2.compose(pose, se2.compose(eta, se2.between(pose, np.r_[point, 0.0])))[:2]
    ad_eta = adjoint(pose) @ eta
    left = se2.compose(ad_eta, np.r_[point, 0.0])[:2]
    assert left == pytest.approx(local, abs=1e-6)


def chain_after(chain: OdometryChain, steps: int) -> OdometryChain:
    """`steps` motions of STEP, each its own pose node (its drift taken at once)."""
    for _ in range(steps):
        chain.move(0.0, STEP, Q)
        chain.take_pending()
    return chain


def test_the_drift_since_an_object_was_seen_matches_monte_carlo():
    rng = np.random.default_rng(4)
    start, steps_before, steps_after = np.array([2.0, 1.0, 0.3]), 30, 40
    chain = OdometryChain()
    chain.start(start, 0.0)
    chain_after(chain, steps_before)
    seen_at, seen_drift = chain.pose.copy(), chain.drift.copy()
    chain_after(chain, steps_after)
    detection = np.array([[6.0, 2.0]])  # in the robot's frame now
    now, then = CONFIGURED.odometry(chain.drift), CONFIGURED.odometry(seen_drift)
    cov = since_seen(chain.pose, now, then[None], np.array([True]), detection, 0.0)

    # sample the chain from where the object was seen to now; the map frame is the
    # dead-reckoning frame turned by -heading now (map_heading = 0)
    samples = []
    noise = rng.multivariate_normal(np.zeros(3), Q, size=(3000, steps_after))
    for eta_chain in noise:
        p = seen_at.copy()
        for eta in eta_chain:
            p = se2.compose(p, se2.compose(STEP, eta))
        samples.append(se2.compose(p, np.r_[detection[0], 0.0])[:2])
    nominal = seen_at.copy()
    for _ in range(steps_after):
        nominal = se2.compose(nominal, STEP)
    turn = se2.rotation(-nominal[2])
    expected = turn @ np.cov(np.array(samples).T) @ turn.T
    assert cov[0, 0] == pytest.approx(expected, rel=0.12, abs=2e-3)


def test_objects_without_a_chain_to_the_robot_add_no_drift():
    chain = chain_after(OdometryChain(), 1)
    seen = np.stack([np.zeros((3, 3)), np.eye(3)])
    now = CONFIGURED.odometry(chain.drift)
    cov = since_seen(chain.pose, now, seen, np.array([True, False]), np.ones((1, 2)), 0.0)
    assert cov.shape == (1, 2, 2, 2)
    assert np.linalg.eigvalsh(cov[0, 0]).min() > 0 and np.all(cov[0, 1] == 0)


def test_the_chain_composes_increments_between_pose_nodes():
    chain = OdometryChain()
    chain.start(np.zeros(3), 0.0)
    chain.move(1.0, STEP, Q)
    chain.move(2.0, STEP, Q)
    delta, parts = chain.take_pending()
    expected, expected_cov = se2.compose_increments(STEP, Q, STEP, Q)
    np.testing.assert_allclose(delta, expected)
    np.testing.assert_allclose(CONFIGURED.odometry(parts), expected_cov)  # parts sum to it
    assert chain.take_pending() is None  # nothing moved since
    times, poses = chain.track()
    assert times.tolist() == [0.0, 1.0, 2.0]
    np.testing.assert_allclose(poses[-1], se2.compose(STEP, STEP))


def test_a_pose_record_starts_the_odometry_frame():
    chain = OdometryChain()
    assert chain.increment(np.array([5.0, 1.0, 0.5]), None) is None
    delta = chain.increment(se2.compose(np.array([5.0, 1.0, 0.5]), STEP), None)
    np.testing.assert_allclose(delta, STEP)
