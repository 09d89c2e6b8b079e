"""Object position from the depth pixels inside a detection's mask (sec. 2.3, App. A): a
robust average of the back-projected points (invalid depths ignored, depths far from the
median dropped as background), with a covariance larger along the viewing ray than across."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrislam.io.perception.camera import PinholeCamera
from agrislam.io.perception.config import PerceptionConfig

MAD_TO_SIGMA = 1.4826  # MAD of a normal distribution times this is its sigma


class DepthRejectedError(ValueError):
    """A detection that yields no position; `kind` says why (for counting)."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True, slots=True)
class DepthEstimate:
    point_cam: np.ndarray  # (3,) optical frame
    point_base: np.ndarray  # (3,) base frame
    cov: np.ndarray  # (2, 2) base-frame xy covariance
    range: float  # m, camera to point
    n_pixels: int  # depth pixels averaged

    @property
    def xy(self) -> np.ndarray:
        return self.point_base[:2]


def depth_in_metres(depth: np.ndarray, scale: float) -> np.ndarray:
    """A depth image as float metres: integer images (16UC1, mm) times `scale`."""
    if np.issubdtype(depth.dtype, np.integer):
        return depth.astype(np.float64) * scale
    return depth.astype(np.float64, copy=False)


def green_pixels(rgb: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels whose excess green 2g - r - b on chromaticity (r+g+b = 1) exceeds `threshold`."""
    c = rgb[..., :3].astype(np.float64)
    total = c.sum(axis=-1)
    total[total == 0.0] = np.inf  # black is not green
    r, g, b = (c[..., i] / total for i in range(3))
    return (2.0 * g - r - b) > threshold


def box_region(box: np.ndarray, shape: tuple[int, int], core: float = 1.0) -> np.ndarray:
    """Boolean image of the central `core` fraction (per side) of box (x0, y0, x1, y1):
    the pixels whose centres (integer coordinates) lie inside it."""
    x0, y0, x1, y1 = (float(v) for v in box)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    hw, hh = 0.5 * core * (x1 - x0), 0.5 * core * (y1 - y0)
    h, w = shape
    u0, u1 = max(int(np.ceil(cx - hw)), 0), min(int(np.floor(cx + hw)) + 1, w)
    v0, v1 = max(int(np.ceil(cy - hh)), 0), min(int(np.floor(cy + hh)) + 1, h)
    region = np.zeros(shape, dtype=bool)
    region[v0:v1, u0:u1] = True
    return region


def inlier_depths(z: np.ndarray, mad_k: float, band: float) -> np.ndarray:
    """Boolean mask of depths within max(mad_k robust sigmas, band) of the median."""
    med = np.median(z)
    spread = MAD_TO_SIGMA * np.median(np.abs(z - med))
    return np.abs(z - med) <= max(mad_k * spread, band)


def ray_covariance(ray_base: np.ndarray, var_depth: float, var_lateral: float) -> np.ndarray:
    """xy block of var_lateral I + (var_depth - var_lateral) r r^T for the unit ray r (base
    frame): depth variance along the ray's ground projection, lateral across it (sec. 2.6)."""
    r = ray_base / np.linalg.norm(ray_base)
    rxy = r[:2]
    return var_lateral * np.eye(2) + (var_depth - var_lateral) * np.outer(rxy, rxy)


def estimate_position(
    depth_m: np.ndarray,
    region: np.ndarray,
    camera: PinholeCamera,
    config: PerceptionConfig,
) -> DepthEstimate:
    """Robust object position from the depth pixels (metres) inside a boolean `region`.

    Raises DepthRejectedError (kind 'no_depth' or 'beyond_range') when there is no position.
    """
    if depth_m.shape != region.shape:
        raise ValueError(f"depth image {depth_m.shape} and mask {region.shape} differ in size")
    v, u = np.nonzero(region)
    z = depth_m[v, u]
    far = config.max_range  # a depth beyond the range cut-off cannot belong to a kept object
    valid = np.isfinite(z) & (z >= config.min_depth) & (z <= far)
    if np.count_nonzero(valid) < config.min_pixels:
        n_far = np.count_nonzero(np.isfinite(z) & (z > far))
        if n_far >= config.min_pixels:
            raise DepthRejectedError("beyond_range", f"depth beyond max_range {far} m")
        raise DepthRejectedError(
            "no_depth",
            f"{np.count_nonzero(valid)} valid depth pixels of {z.size} in the mask "
            f"(need {config.min_pixels})",
        )
    u, v, z = u[valid], v[valid], z[valid]
    keep = inlier_depths(z, config.outlier_mad, config.outlier_band)
    points = camera.back_project(u[keep] + 0.0, v[keep] + 0.0, z[keep])
    point_cam = points.mean(axis=0)
    rng = float(np.linalg.norm(point_cam))
    if rng > config.max_range:  # App. A: objects farther than 2.5 m are not considered
        raise DepthRejectedError("beyond_range", f"range {rng:.2f} m beyond max_range {far} m")
    # depth spread of the kept points widens the along-ray uncertainty (object extent)
    var_depth = config.sigma_depth**2 + float(np.var(points[:, 2]))
    ray_base = camera.camera_to_base[:3, :3] @ point_cam
    return DepthEstimate(
        point_cam=point_cam,
        point_base=camera.to_base(point_cam)[0],
        cov=ray_covariance(ray_base, var_depth, config.sigma_lateral**2),
        range=rng,
        n_pixels=int(points.shape[0]),
    )
