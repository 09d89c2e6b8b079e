"""The sensor model (frontend/sensor_model.py): a record's uncertainty, its own or the
configured default, never below the least variance the solver takes."""

from __future__ import annotations

from collections import Counter

import numpy as np

from agrislam.config import SensorDefaults
from agrislam.frontend.sensor_model import RAISED, SOLVER_VARIANCE, SensorModel
from agrislam.records import Detection


def test_an_odometry_covariance_below_the_solvers_least_is_raised_and_counted():
    model = SensorModel(SensorDefaults(), Counter())
    fair = np.diag([1e-4, 1e-4, 4e-6])
    np.testing.assert_array_equal(model.odometry_covariance(fair), fair)
    assert not model.issues  # no count of nothing
    sure = np.diag([1e-16, 1e-4, 1e-16])
    np.testing.assert_allclose(
        model.odometry_covariance(sure), np.diag([SOLVER_VARIANCE, 1e-4, SOLVER_VARIANCE])
    )
    assert model.issues == {RAISED: 1}


def test_a_detection_is_raised_to_its_least_variance_in_the_form_it_came_in():
    """An xy detection's covariance is raised in its own directions; a range and bearing's
    sigmas each; a detection above its least is the same object."""
    model = SensorModel(SensorDefaults(), Counter())
    fair = Detection(xy=np.array([1.0, 0.5]), cov=np.diag([0.01, 0.0025]))
    sure = Detection(xy=np.array([1.0, 0.5]), cov=np.array([[1e-16, 0.0], [0.0, 1e-4]]))
    ranged = Detection(range=2.0, bearing=0.1, sigma_range=1e-8, sigma_bearing=0.02)
    detections = [fair, sure, ranged]
    covs = np.stack([model.detection_covariance(d) for d in detections])
    out, raised = model.with_least_variance(detections, covs, np.array([0.0, 0.0, 1e-4]))
    assert raised.tolist() == [False, True, True] and out[0] is fair
    np.testing.assert_allclose(out[1].cov, np.diag([SOLVER_VARIANCE, 1e-4]))
    assert (out[2].sigma_range, out[2].sigma_bearing) == (0.01, 0.02)  # 0.02 * 2 m > 0.01
    assert model.issues == {RAISED: 1}  # the range's was raised to a floor of the data's
