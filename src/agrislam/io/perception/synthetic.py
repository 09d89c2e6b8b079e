"""Ray-cast RGB-D frames of simple scenes (a ground plane and plant-like shapes), to test the
front end against known object positions. Depth is along the optical axis, as RGB-D cameras
report it; the instance image marks object k with k + 1."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agrislam.io.perception.camera import PinholeCamera

GROUND_RGB = (110, 80, 50)  # soil
PLANT_RGB = (40, 160, 40)


@dataclass(frozen=True, slots=True)
class Sphere:
    center: np.ndarray  # (3,) base frame
    radius: float


@dataclass(frozen=True, slots=True)
class FacingDisc:
    """A flat disc parallel to the image plane: every pixel on it has the same depth, so
    the mean of its back-projected pixels is its centre (up to pixel quantisation)."""

    center: np.ndarray  # (3,) base frame
    radius: float


Shape = Sphere | FacingDisc


def _camera_rays(camera: PinholeCamera) -> np.ndarray:
    """(H*W, 3) optical-frame rays (x, y, 1) through the pixel centres, row-major."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    xy = camera.normalised(u.ravel() + 0.0, v.ravel() + 0.0)
    return np.column_stack([xy, np.ones(len(xy))])


def _hit_depth(shape: Shape, origin: np.ndarray, rays_cam: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Optical depth (= ray parameter, since rays have z = 1) of each ray's hit, inf if none."""
    center_cam = R.T @ (np.asarray(shape.center, dtype=float) - origin)
    if isinstance(shape, FacingDisc):
        t = np.full(len(rays_cam), center_cam[2])
        off = rays_cam * t[:, None] - center_cam
        inside = (center_cam[2] > 0) & (np.einsum("ij,ij->i", off, off) <= shape.radius**2)
        return np.where(inside, t, np.inf)
    # sphere: |t r - c|^2 = rad^2 -> (r.r) t^2 - 2 (r.c) t + c.c - rad^2 = 0, nearest root
    a = np.einsum("ij,ij->i", rays_cam, rays_cam)
    b = rays_cam @ center_cam
    disc = b * b - a * (center_cam @ center_cam - shape.radius**2)
    with np.errstate(invalid="ignore"):
        t = (b - np.sqrt(disc)) / a
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def render_depth(
    camera: PinholeCamera, shapes: Sequence[Shape], ground_z: float | None = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) in metres (0 where nothing is hit) and the instance image (int32)."""
    rays = _camera_rays(camera)
    R, origin = camera.camera_to_base[:3, :3], camera.camera_to_base[:3, 3]
    depth = np.full(len(rays), np.inf)
    instance = np.zeros(len(rays), dtype=np.int32)
    if ground_z is not None:
        dz = rays @ R[2]  # base z component of each ray
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ground_z - origin[2]) / dz
        depth = np.where((t > 0) & np.isfinite(t), t, np.inf)
    for k, shape in enumerate(shapes):
        t = _hit_depth(shape, origin, rays, R)
        closer = t < depth
        depth[closer] = t[closer]
        instance[closer] = k + 1
    depth[~np.isfinite(depth)] = 0.0
    shape_hw = (camera.height, camera.width)
    return depth.reshape(shape_hw), instance.reshape(shape_hw)


def render_rgb(instance: np.ndarray) -> np.ndarray:
    """A colour image for an instance image: soil-brown background, green plants."""
    rgb = np.empty((*instance.shape, 3), dtype=np.uint8)
    rgb[:] = GROUND_RGB
    rgb[instance > 0] = PLANT_RGB
    return rgb


def instance_box(instance: np.ndarray, k: int) -> np.ndarray:
    """Tight box (x0, y0, x1, y1) around the pixels of instance k (pixel centres)."""
    v, u = np.nonzero(instance == k)
    if u.size == 0:
        raise ValueError(f"instance {k} is not visible")
    return np.array([u.min(), v.min(), u.max(), v.max()], dtype=float)
