"""Noise models of the graph: detections (anisotropic along the viewing ray), odometry, row
constraints (across the row only), robust kernels and marginal priors."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from agrislam.config import SlamConfig

# a detection closer than this to the robot origin has no defined bearing
MIN_RANGE = 1e-6


def ray_rotation(xy: np.ndarray) -> np.ndarray:
    """(..., 2, 2) rotations whose first column is the unit viewing ray of each point."""
    xy = np.asarray(xy, dtype=float)
    bearing = np.arctan2(xy[..., 1], xy[..., 0])
    c, s = np.cos(bearing), np.sin(bearing)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def detection_covariance(
    xy_robot: np.ndarray, sigma_depth: float | np.ndarray, sigma_lateral: float | np.ndarray
) -> np.ndarray:
    """2x2 covariance of a detection at `xy_robot` (robot frame): sigma_depth along the ray,
    sigma_lateral across it, R diag(sd^2, sl^2) R^T (sec. 2.3, 2.6). Vectorised: (n, 2) in,
    (n, 2, 2) out."""
    rot = ray_rotation(xy_robot)
    sd2 = np.asarray(sigma_depth, dtype=float) ** 2
    sl2 = np.asarray(sigma_lateral, dtype=float) ** 2
    diag = np.zeros((*np.shape(rot)[:-2], 2, 2))
    diag[..., 0, 0] = sd2
    diag[..., 1, 1] = sl2
    return rot @ diag @ np.swapaxes(rot, -1, -2)


@dataclass(frozen=True)
class RelativePosition:
    """An object at `xy` in the robot frame (x forward, y left) with a 2x2 covariance."""

    xy: np.ndarray
    cov: np.ndarray


@dataclass(frozen=True)
class RangeBearing:
    """An object at `range` m and `bearing` rad (from the robot's x axis, left positive)."""

    range: float
    bearing: float
    sigma_range: float
    sigma_bearing: float


Measurement = RelativePosition | RangeBearing


def range_bearing_jacobian(xy: np.ndarray) -> np.ndarray:
    """d(bearing, range)/d(x, y) at a point of the robot frame."""
    x, y = float(xy[0]), float(xy[1])
    r2 = x * x + y * y
    r = np.sqrt(r2)
    return np.array([[-y / r2, x / r2], [x / r, y / r]])


def relative_to_range_bearing(xy: np.ndarray, cov: np.ndarray) -> tuple[float, float, np.ndarray]:
    """A relative position with a 2x2 covariance as (bearing, range) with the covariance
    carried over to first order, J cov J^T; exact for the mean (g2o's EDGE_SE2_XY, sec. 2.6)."""
    xy = np.asarray(xy, dtype=float)
    rng = float(np.hypot(xy[0], xy[1]))
    if not rng > MIN_RANGE:
        raise ValueError(f"detection at {xy.tolist()} is at the robot origin: no bearing")
    jac = range_bearing_jacobian(xy)
    return float(np.arctan2(xy[1], xy[0])), rng, jac @ cov @ jac.T


def range_bearing_to_relative(
    bearing: float, rng: float, cov_br: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `relative_to_range_bearing`: xy in the robot frame and its 2x2 covariance."""
    xy = rng * np.array([np.cos(bearing), np.sin(bearing)])
    jac_inv = np.linalg.inv(range_bearing_jacobian(xy))
    return xy, jac_inv @ cov_br @ jac_inv.T


def check_covariance(cov: np.ndarray, dim: int, what: str) -> np.ndarray:
    """A finite, symmetric, positive definite dim x dim matrix, or a ValueError naming `what`."""
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (dim, dim):
        raise ValueError(f"{what}: covariance must be {dim}x{dim}, got shape {cov.shape}")
    if not np.all(np.isfinite(cov)):
        raise ValueError(f"{what}: covariance has non-finite entries {cov.tolist()}")
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12):
        raise ValueError(f"{what}: covariance is not symmetric {cov.tolist()}")
    if np.linalg.eigvalsh(cov)[0] <= 0.0:
        raise ValueError(f"{what}: covariance is not positive definite {cov.tolist()}")
    return cov


def least_variance_bound(cov: np.ndarray) -> float:
    """A lower bound of a symmetric matrix's smallest eigenvalue (Gershgorin): the least
    diagonal entry less its row's other entries; exact for a diagonal one. Plain floats:
    every odometry record's covariance is checked."""
    rows = np.asarray(cov, dtype=float).tolist()
    return min(row[i] + abs(row[i]) - sum(map(abs, row)) for i, row in enumerate(rows))


def raised(cov: np.ndarray, variance: float | np.ndarray) -> np.ndarray:
    """Symmetric covariances (..., n, n) with every eigenvalue below `variance` (a number,
    or one per matrix) raised to it, the directions kept: the least uncertainty a
    measurement is taken with."""
    cov = np.asarray(cov, dtype=float)
    w, v = np.linalg.eigh(cov)
    w = np.maximum(w, np.asarray(variance, dtype=float)[..., None])
    return (v * w[..., None, :]) @ np.swapaxes(v, -1, -2)


def gaussian(cov: np.ndarray) -> gtsam.noiseModel.Base:
    """Gaussian noise model of a covariance; diagonal ones become the cheaper Diagonal model."""
    variances = cov.diagonal().copy()
    if np.count_nonzero(cov) == np.count_nonzero(variances):
        return gtsam.noiseModel.Diagonal.Variances(variances)
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def robust(slam: SlamConfig, model: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    """Wrap a detection's noise model in the configured robust kernel (sec. 2.6.3, outliers)."""
    if slam.robust_kernel == "none":
        return model
    kernel = {
        "huber": gtsam.noiseModel.mEstimator.Huber,
        "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
    }
    return gtsam.noiseModel.Robust.Create(kernel[slam.robust_kernel].Create(slam.robust_k), model)


def row_normal(angle: float) -> np.ndarray:
    """Unit normal n = (-sin a, cos a) of rows at angle a to the x axis (snapshot.RowLines)."""
    return np.array([-np.sin(angle), np.cos(angle)])


def row_direction(angle: float) -> np.ndarray:
    """Unit vector t = (cos a, sin a) along the rows."""
    return np.array([np.cos(angle), np.sin(angle)])


def one_direction(direction: np.ndarray, sigma: float) -> gtsam.noiseModel.Base:
    """A 2D noise model that only penalises the component along `direction` (unit vector):
    square-root information [d^T / sigma; 0] (rank one). A row constraint acts across the
    row only, nothing along it (sec. 2.6.2)."""
    sqrt_info = np.zeros((2, 2))
    sqrt_info[0] = np.asarray(direction, dtype=float) / sigma
    return gtsam.noiseModel.Gaussian.SqrtInformation(sqrt_info, False)
