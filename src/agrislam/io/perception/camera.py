"""Pinhole camera model from CameraInfo-style intrinsics, and the camera-to-base transform
that App. A's position estimate uses.

Camera points are in the ROS optical frame (z forward along the optical axis, x right,
y down); base points in the robot base frame (x forward, y left, z up)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

# rotation from the optical frame (z fwd, x right, y down) to a body-style camera link
# frame (x fwd, y left, z up): x_link = z_opt, y_link = -x_opt, z_link = -y_opt
OPTICAL_TO_LINK = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rotation_from_quaternion(q: Sequence[float]) -> np.ndarray:
    """3x3 rotation of a quaternion given as (x, y, z, w), as in geometry_msgs."""
    x, y, z, w = (float(v) for v in q)
    n = x * x + y * y + z * z + w * w
    if not n > 0.0 or not np.isfinite(n):
        raise ValueError(f"quaternion {tuple(q)} has no rotation (zero or non-finite norm)")
    s = 2.0 / n
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )


def rigid_transform(rotation: np.ndarray, translation: Sequence[float]) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = np.asarray(translation, dtype=float)
    return T


def camera_mount(translation: Sequence[float], yaw: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """Optical-frame-to-base transform of a camera at `translation` (base frame) that looks
    along the base x axis turned by `yaw` (left positive) and tilted down by `pitch`."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    r_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    r_pitch = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # +pitch looks down
    return rigid_transform(r_yaw @ r_pitch @ OPTICAL_TO_LINK, translation)


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics K (3x3), plumb-bob distortion D (k1, k2, p1, p2, k3), image size, and the
    optical-frame-to-base transform `camera_to_base` (4x4)."""

    K: np.ndarray
    width: int
    height: int
    D: np.ndarray = field(default_factory=lambda: np.zeros(5))
    camera_to_base: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float).reshape(3, 3)
        fx, fy = K[0, 0], K[1, 1]
        if not (np.isfinite(fx) and np.isfinite(fy) and fx > 0.0 and fy > 0.0):
            raise ValueError(f"focal length must be positive and finite, got fx={fx}, fy={fy}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        D = np.zeros(5)
        d = np.asarray(self.D, dtype=float).ravel()[:5]
        D[: d.size] = d
        T = np.asarray(self.camera_to_base, dtype=float).reshape(4, 4)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "camera_to_base", T)

    @classmethod
    def from_camera_info(
        cls,
        k: Sequence[float],
        width: int,
        height: int,
        d: Sequence[float] = (),
        camera_to_base: np.ndarray | None = None,
    ) -> PinholeCamera:
        """From the fields of a sensor_msgs/CameraInfo (row-major 9-element `k`, `d`)."""
        return cls(
            K=np.asarray(k, dtype=float).reshape(3, 3),
            width=int(width),
            height=int(height),
            D=np.asarray(d, dtype=float) if len(d) else np.zeros(5),
            camera_to_base=np.eye(4) if camera_to_base is None else camera_to_base,
        )

    def with_mount(self, camera_to_base: np.ndarray) -> PinholeCamera:
        return PinholeCamera(self.K, self.width, self.height, self.D, camera_to_base)

    @property
    def distorted(self) -> bool:
        return bool(np.any(self.D != 0.0))

    def _distort_normalised(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k1, k2, p1, p2, k3 = self.D
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (n, 2) of camera-frame points (n, 3) with z > 0."""
        p = np.atleast_2d(np.asarray(points_cam, dtype=float))
        x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        if self.distorted:
            x, y = self._distort_normalised(x, y)
        K = self.K
        return np.column_stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]])

    def normalised(self, u: np.ndarray, v: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Undistorted normalised image coordinates (n, 2) of pixels (u, v)."""
        K = self.K
        y = (np.asarray(v, dtype=float) - K[1, 2]) / K[1, 1]
        x = (np.asarray(u, dtype=float) - K[0, 2] - K[0, 1] * y) / K[0, 0]
        if self.distorted:  # fixed-point inversion of the plumb-bob model
            xd, yd = x, y
            for _ in range(iterations):
                fx, fy = self._distort_normalised(x, y)
                x, y = x + (xd - fx), y + (yd - fy)
        return np.column_stack([x, y])

    def back_project(self, u: np.ndarray, v: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (n, 3) of pixels (u, v) at depth z (along the optical axis)."""
        xy = self.normalised(u, v)
        z = np.asarray(depth, dtype=float).ravel()
        return np.column_stack([xy[:, 0] * z, xy[:, 1] * z, z])

    def to_base(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points (n, 3) in the base frame."""
        T = self.camera_to_base
        return np.atleast_2d(points_cam) @ T[:3, :3].T + T[:3, 3]

    @property
    def position_in_base(self) -> np.ndarray:
        return self.camera_to_base[:3, 3].copy()
