"""The NIS of accepted associations (association/gnn.py, `accepted_nis`): chi2 with 2 dof
for innovations drawn from the covariance it is taken with, NaN where nothing was accepted."""

import numpy as np
import pytest

from agrislam.association.gnn import accepted_nis
from agrislam.geometry.placed import PlacedDetections


def covariances(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    """(n, 2, 2) random positive definite covariances of about `scale` m^2."""
    a = rng.normal(0.0, np.sqrt(scale), (n, 2, 2))
    return a @ a.transpose(0, 2, 1) + 0.1 * scale * np.eye(2)


def test_innovations_drawn_from_the_absolute_bound_give_chi2_with_two_dof():
    rng = np.random.default_rng(3)
    n = 4000
    det_cov, pose_cov, obj_cov = (covariances(rng, n, s) for s in (0.01, 0.004, 0.002))
    s = det_cov + pose_cov + obj_cov  # K_n + R_m + the pose marginal
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(s), rng.normal(size=(n, 2)))
    det_xy = rng.uniform(-5.0, 5.0, (n, 2))
    placed = PlacedDetections(det_xy, det_cov, [{}] * n, pose_cov=pose_cov)
    nis = accepted_nis(placed, np.arange(n), det_xy + e, obj_cov)
    assert nis.mean() == pytest.approx(2.0, abs=0.1)
    assert (nis > -2.0 * np.log(0.01)).mean() == pytest.approx(0.01, abs=0.005)


def test_the_detections_own_innovation_covariance_is_used_where_given():
    det_xy = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    placed = PlacedDetections(det_xy, np.tile(np.eye(2), (3, 1, 1)), [{}] * 3)
    object_xy = np.array([[2.0, 0.3], [0.3, 0.4]])
    own = np.tile(np.eye(2) * 100.0, (3, 2, 1, 1))
    own[0, 1] = np.diag([0.09, 0.16])  # detection 0 on object 1: e = (0.3, 0.4)
    own[2, 0] = np.diag([1.0, 0.01])  # detection 2 on object 0: e = (0, 0.3)
    chosen = np.array([1, -1, 0])  # detection 1 starts a new object
    nis = accepted_nis(placed, chosen, object_xy, np.zeros((2, 2, 2)), own)
    np.testing.assert_allclose(nis[[0, 2]], [2.0, 9.0])
    assert np.isnan(nis[1])
