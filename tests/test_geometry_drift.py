"""The dead-reckoning drift since an object was last seen (geometry/drift.py)."""

import numpy as np
import pytest

from agrislam.geometry import se2
from agrislam.geometry.drift import OdometryDrift, adjoint

Q = np.diag([0.02**2, 0.01**2, 0.01**2])  # per step: x, y, heading
STEP = np.array([0.5, 0.0, 0.04])  # a gentle left curve


def test_adjoint_moves_a_perturbation_across_the_pose():
    pose, eta = np.array([3.0, -2.0, 0.7]), np.array([1e-3, -2e-3, 3e-4])
    # P Exp(eta) P^-1 = Exp(Ad eta); to first order on a point, both move it alike
    point = np.array([1.5, 4.0])
    local = se2.compose(pose, se2.compose(eta, se2.between(pose, np.r_[point, 0.0])))[:2]
    ad_eta = adjoint(pose) @ eta
    left = se2.compose(ad_eta, np.r_[point, 0.0])[:2]
    assert left == pytest.approx(local, abs=1e-6)


def test_the_drift_since_an_object_was_seen_matches_monte_carlo():
    rng = np.random.default_rng(4)
    start, steps_before, steps_after = np.array([2.0, 1.0, 0.3]), 30, 40
    drift = OdometryDrift()
    drift.start("r", start)
    pose = start.copy()
    for _ in range(steps_before):
        pose = se2.compose(pose, STEP)
        drift.advance("r", pose, Q)
    drift.seen("r", np.array([7]))
    seen_at = pose.copy()
    for _ in range(steps_after):
        pose = se2.compose(pose, STEP)
        drift.advance("r", pose, Q)
    detection = np.array([[6.0, 2.0]])  # in the robot's frame now
    cov, known = drift.since_seen("r", np.array([7]), detection, map_heading=0.0)
    assert known.tolist() == [True]

    # sample the chain from where the object was seen to now; the map frame is the
    # dead-reckoning frame turned by -heading now (map_heading = 0)
    samples = []
    noise = rng.multivariate_normal(np.zeros(3), Q, size=(3000, steps_after))
    for chain in noise:
        p = seen_at.copy()
        for eta in chain:
            p = se2.compose(p, se2.compose(STEP, eta))
        samples.append(se2.compose(p, np.r_[detection[0], 0.0])[:2])
    nominal = seen_at.copy()
    for _ in range(steps_after):
        nominal = se2.compose(nominal, STEP)
    turn = se2.rotation(-nominal[2])
    expected = turn @ np.cov(np.array(samples).T) @ turn.T
    assert cov[0, 0] == pytest.approx(expected, rel=0.12, abs=2e-3)


def test_objects_of_another_robot_or_forgotten_have_no_chain():
    drift = OdometryDrift()
    drift.start("a", np.zeros(3))
    drift.start("b", np.zeros(3))
    drift.seen("a", np.array([1, 2]))
    drift.seen("b", np.array([3]))
    drift.forget(np.array([2]))
    drift.advance("a", STEP, Q)  # one step from the origin
    cov, known = drift.since_seen("a", np.array([1, 2, 3]), np.array([[1.0, 0.0]]), 0.0)
    assert known.tolist() == [True, False, False]
    assert cov.shape == (1, 3, 2, 2)
    assert np.linalg.eigvalsh(cov[0, 0]).min() > 0 and np.all(cov[0, 1:] == 0)


def test_a_merged_object_was_last_seen_when_either_was():
    drift = OdometryDrift()
    drift.start("r", np.zeros(3))
    pose = np.zeros(3)
    drift.seen("r", np.array([1]))  # seen at the start
    for _ in range(20):
        pose = se2.compose(pose, STEP)
        drift.advance("r", pose, Q)
    drift.seen("r", np.array([2]))  # its duplicate, seen just now
    drift.merge(keep=1, drop=2)
    cov, known = drift.since_seen("r", np.array([1, 2]), np.array([[3.0, 0.0]]), pose[2])
    assert known.tolist() == [True, False]
    assert np.allclose(cov[0, 0], 0.0)  # as recent as the duplicate
