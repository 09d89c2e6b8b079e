"""Camera model and object position from the depth inside a mask (sec. 2.3, App. A)."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.config import AgrislamConfig
from agrislam.geometry.se2 import quaternion_from_yaw, yaw_from_quaternion
from agrislam.io.perception.camera import (
    PinholeCamera,
    camera_mount,
    rotation_from_quaternion,
)
from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.perception.mask_depth import (
    DepthRejectedError,
    box_region,
    estimate_position,
    green_pixels,
    inlier_depths,
)
from agrislam.io.perception.synthetic import (
    FacingDisc,
    Sphere,
    instance_box,
    render_depth,
    render_rgb,
)

K = [500.0, 0.0, 320.0, 0.0, 400.0, 240.0, 0.0, 0.0, 1.0]


def level_camera(width: int = 320, height: int = 240) -> PinholeCamera:
    """A camera 0.5 m up at the front of the base, looking straight ahead."""
    k = [300.0, 0.0, width / 2, 0.0, 300.0, height / 2, 0.0, 0.0, 1.0]
    return PinholeCamera.from_camera_info(
        k, width, height, camera_to_base=camera_mount([0.3, 0.0, 0.5])
    )


def tilted_camera() -> PinholeCamera:
    k = [300.0, 0.0, 160.0, 0.0, 300.0, 120.0, 0.0, 0.0, 1.0]
    return PinholeCamera.from_camera_info(
        k, 320, 240, camera_to_base=camera_mount([0.3, 0.0, 0.8], pitch=0.5)
    )


# ------------------------------------------------------------------------------- camera


def test_projection_by_hand() -> None:
    cam = PinholeCamera.from_camera_info(K, 640, 480)
    # u = fx x/z + cx = 500 * 0.1 + 320 = 370, v = fy y/z + cy = 400 * -0.05 + 240 = 220
    np.testing.assert_allclose(cam.project([[0.2, -0.1, 2.0]]), [[370.0, 220.0]])
    np.testing.assert_allclose(
        cam.back_project(np.array([370.0]), np.array([220.0]), np.array([2.0])), [[0.2, -0.1, 2.0]]
    )


def test_distortion_round_trip() -> None:
    cam = PinholeCamera.from_camera_info(K, 640, 480, d=[0.1, -0.05, 0.001, 0.002, 0.0])
    points = np.array([[0.3, -0.2, 1.5], [-0.4, 0.25, 2.0], [0.0, 0.0, 1.0]])
    uv = cam.project(points)
    assert not np.allclose(uv, PinholeCamera.from_camera_info(K, 640, 480).project(points))
    back = cam.back_project(uv[:, 0], uv[:, 1], points[:, 2])
    np.testing.assert_allclose(back, points, atol=1e-7)


def test_zero_focal_length_is_rejected() -> None:
    with pytest.raises(ValueError, match="focal length"):
        PinholeCamera.from_camera_info([0.0, 0, 320, 0, 0.0, 240, 0, 0, 1], 640, 480)


def test_camera_mount_axes() -> None:
    ahead = camera_mount([0.3, 0.0, 0.8])
    # optical axis (z) -> base x, image right (x) -> base -y, image down (y) -> base -z
    np.testing.assert_allclose(ahead[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(ahead[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(ahead[:3, :3] @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    down = camera_mount([0.0, 0.0, 1.0], pitch=np.pi / 2)
    np.testing.assert_allclose(down[:3, :3] @ [0, 0, 1], [0, 0, -1], atol=1e-12)
    left = camera_mount([0.0, 0.0, 1.0], yaw=np.pi / 2)
    np.testing.assert_allclose(left[:3, :3] @ [0, 0, 1], [0, 1, 0], atol=1e-12)


def test_quaternion_helpers() -> None:
    q = quaternion_from_yaw(0.7)
    assert yaw_from_quaternion(q) == pytest.approx(0.7)
    R = rotation_from_quaternion(q)
    np.testing.assert_allclose(
        R, [[np.cos(0.7), -np.sin(0.7), 0], [np.sin(0.7), np.cos(0.7), 0], [0, 0, 1]], atol=1e-12
    )
    with pytest.raises(ValueError, match="quaternion"):
        rotation_from_quaternion([0, 0, 0, 0])


# ---------------------------------------------------------------------- mask position


def test_box_region_counts_pixel_centres() -> None:
    full = box_region(np.array([10.0, 20.0, 20.0, 30.0]), (50, 50), core=1.0)
    assert full.sum() == 11 * 11  # centres 10..20 inclusive
    core = box_region(np.array([10.0, 20.0, 20.0, 30.0]), (50, 50), core=0.5)
    assert core.sum() == 5 * 5  # centre 15, half width 2.5 -> 13..17
    v, u = np.nonzero(core)
    assert (u.mean(), v.mean()) == (15.0, 25.0)


def test_known_position_from_synthetic_depth() -> None:
    cam = tilted_camera()
    truth = np.array([1.5, 0.2, 0.15])
    depth, instance = render_depth(cam, [FacingDisc(truth, 0.1)])
    est = estimate_position(depth, instance == 1, cam, PerceptionConfig())
    np.testing.assert_allclose(est.point_base, truth, atol=2e-3)
    np.testing.assert_allclose(est.xy, truth[:2], atol=2e-3)
    assert est.range == pytest.approx(np.linalg.norm(truth - cam.position_in_base), abs=2e-3)


def test_invalid_depth_pixels_do_not_bias() -> None:
    cam = tilted_camera()
    truth = np.array([1.5, -0.3, 0.15])
    depth, instance = render_depth(cam, [FacingDisc(truth, 0.12)])
    mask = instance == 1
    clean = estimate_position(depth, mask, cam, PerceptionConfig())

    rng = np.random.default_rng(3)
    v, u = np.nonzero(mask)
    pick = rng.permutation(len(u))
    n = len(u)
    zero, nan, far = np.split(pick[: n * 65 // 100], [n * 45 // 100, n * 55 // 100])
    bad = depth.copy()
    bad[v[zero], u[zero]] = 0.0  # no return: the majority of the mask
    bad[v[nan], u[nan]] = np.nan
    bad[v[far], u[far]] = 65.535  # a 16-bit sensor's "max", far beyond range
    est = estimate_position(bad, mask, cam, PerceptionConfig())
    # exactly as if the invalid pixels had not been in the mask at all
    only_valid = mask.copy()
    only_valid[v[pick[: n * 65 // 100]], u[pick[: n * 65 // 100]]] = False
    same = estimate_position(depth, only_valid, cam, PerceptionConfig())
    np.testing.assert_allclose(est.point_base, same.point_base, atol=1e-12)
    assert est.n_pixels == same.n_pixels == n - n * 65 // 100
    np.testing.assert_allclose(est.xy, truth[:2], atol=1e-2)
    np.testing.assert_allclose(clean.xy, truth[:2], atol=2e-3)
    # the naive average over the mask (what the test guards against) is far off
    naive = np.nanmean(bad[mask])
    assert abs(naive - np.nanmean(depth[mask])) > 0.1


def test_background_through_the_mask_is_rejected() -> None:
    cam = tilted_camera()
    truth = np.array([1.4, 0.0, 0.15])
    depth, instance = render_depth(cam, [FacingDisc(truth, 0.12)])
    mask = instance == 1
    v, u = np.nonzero(mask)
    leaky = depth.copy()
    sel = np.random.default_rng(0).permutation(len(u))[: len(u) // 4]
    leaky[v[sel], u[sel]] += 0.8  # soil seen between the leaves
    est = estimate_position(leaky, mask, cam, PerceptionConfig())
    np.testing.assert_allclose(est.xy, truth[:2], atol=3e-3)
    plain = cam.to_base(cam.back_project(u + 0.0, v + 0.0, leaky[v, u]).mean(axis=0))[0]
    assert np.linalg.norm(plain[:2] - truth[:2]) > 0.1


def test_inlier_band_by_hand() -> None:
    z = np.array([1.0, 1.01, 0.99, 1.0, 3.0])
    # median 1.0, MAD 0.01 -> sigma 0.014826, 3 sigma = 0.0445 > band 0.03
    np.testing.assert_array_equal(inlier_depths(z, 3.0, 0.03), [True, True, True, True, False])
    np.testing.assert_array_equal(inlier_depths(z, 3.0, 5.0), [True] * 5)


def test_covariance_depth_along_the_ray() -> None:
    cam = level_camera()
    truth = np.array([1.8, 0.6, 0.5])  # at camera height: the viewing ray is horizontal
    depth, instance = render_depth(cam, [FacingDisc(truth, 0.08)], ground_z=None)
    cfg = PerceptionConfig(sigma_depth=0.1, sigma_lateral=0.03)
    est = estimate_position(depth, instance == 1, cam, cfg)
    ray = est.xy - cam.position_in_base[:2]
    ray /= np.linalg.norm(ray)
    lateral = np.array([-ray[1], ray[0]])
    # flat disc: no depth spread, so exactly sigma_depth^2 along, sigma_lateral^2 across
    assert ray @ est.cov @ ray == pytest.approx(0.01, rel=1e-6)
    assert lateral @ est.cov @ lateral == pytest.approx(0.0009, rel=1e-6)
    assert ray @ est.cov @ lateral == pytest.approx(0.0, abs=1e-12)


def test_sphere_bias_is_towards_the_camera_and_widens_depth_variance() -> None:
    cam = tilted_camera()
    center = np.array([1.4, -0.4, 0.1])
    depth, instance = render_depth(cam, [Sphere(center, 0.1)])
    est = estimate_position(depth, instance == 1, cam, PerceptionConfig())
    to_cam = cam.position_in_base - center
    along = (est.point_base - center) @ to_cam / np.linalg.norm(to_cam)
    assert 0.0 < along < 0.1  # the visible surface is nearer than the centre (sec. 2.3)
    w = np.linalg.eigvalsh(est.cov)
    assert w[1] > 0.1**2 * 0.5 and w[0] == pytest.approx(0.03**2)


def test_range_cut_off_is_configurable() -> None:
    cam = level_camera()
    truth = np.array([3.3, 0.0, 0.5])
    depth, instance = render_depth(cam, [FacingDisc(truth, 0.15)], ground_z=None)
    with pytest.raises(DepthRejectedError) as err:
        estimate_position(depth, instance == 1, cam, PerceptionConfig())
    assert err.value.kind == "beyond_range"
    est = estimate_position(depth, instance == 1, cam, PerceptionConfig(max_range=3.5))
    np.testing.assert_allclose(est.xy, truth[:2], atol=3e-3)
    from_run = PerceptionConfig.from_config(
        AgrislamConfig.model_validate({"sensor": {"max_range": 4.0}})
    )
    assert from_run.max_range == 4.0


def test_no_valid_depth_names_the_count() -> None:
    cam = level_camera()
    depth = np.zeros((cam.height, cam.width))
    mask = box_region(np.array([100.0, 100.0, 120.0, 120.0]), depth.shape)
    with pytest.raises(DepthRejectedError, match="0 valid depth pixels of 441") as err:
        estimate_position(depth, mask, cam, PerceptionConfig())
    assert err.value.kind == "no_depth"


def test_green_filter_tightens_a_box() -> None:
    cam = tilted_camera()
    truth = np.array([1.5, 0.1, 0.15])
    depth, instance = render_depth(cam, [FacingDisc(truth, 0.1)])
    rgb = render_rgb(instance)
    np.testing.assert_array_equal(green_pixels(rgb, 0.05), instance > 0)
    box = instance_box(instance, 1)
    region = box_region(box, depth.shape, core=1.0)  # the box corners show soil
    cfg = PerceptionConfig(outlier_mad=1e6, outlier_band=1e6)  # no outlier rejection
    loose = estimate_position(depth, region, cam, cfg)
    tight = estimate_position(depth, region & green_pixels(rgb, 0.05), cam, cfg)
    assert np.linalg.norm(tight.xy - truth[:2]) < 2e-3
    assert np.linalg.norm(loose.xy - truth[:2]) > 5e-3


def test_config_refuses_depth_tighter_than_lateral() -> None:
    with pytest.raises(ValueError, match="sigma_depth"):
        PerceptionConfig(sigma_depth=0.01, sigma_lateral=0.03)
