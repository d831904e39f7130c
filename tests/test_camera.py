"""The camera convention of SPEC.md, checked on exact cases (numpy and torch)."""
import numpy as np
import pytest
import torch

from sc3d_data.geometry import camera


def test_ptn_poses_default():
    az, el = camera.ptn_poses()
    assert az.shape == el.shape == (24,)
    np.testing.assert_allclose(az, 15.0 * np.arange(24))
    np.testing.assert_allclose(el, 30.0)


@pytest.mark.parametrize("az,expected", [(0, [0, 0, 2]), (90, [2, 0, 0]), (180, [0, 0, -2]), (270, [-2, 0, 0])])
def test_camera_centre_azimuth_counter_clockwise_from_front(az, expected):
    np.testing.assert_allclose(camera.camera_center(az, 0.0, 2.0), expected, atol=1e-12)


def test_rotation_is_proper_and_looks_at_origin():
    cams = camera.ViewSettings().cameras()
    R, t = cams["R"], cams["t"]
    np.testing.assert_allclose(R @ R.swapaxes(1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0)
    # the origin sits on the optical axis at the camera distance
    np.testing.assert_allclose(t, np.tile([0, 0, 2.0], (24, 1)), atol=1e-12)


def test_projection_axes_front_view():
    """Camera at azimuth 0 (on +Z): world +X appears to the right, world +Y appears up."""
    K = camera.intrinsics(64, 49.13)
    R, t = camera.extrinsics(0.0, 0.0, 2.0)
    uv, z = camera.project_points(np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]], float), K, R, t)
    np.testing.assert_allclose(uv[0], [32, 32])
    assert uv[1, 0] > 32 and abs(uv[1, 1] - 32) < 1e-9
    assert uv[2, 1] < 32 and abs(uv[2, 0] - 32) < 1e-9
    np.testing.assert_allclose(z, 2.0)


def test_elevation_puts_camera_above():
    R, t = camera.extrinsics(0.0, 30.0, 2.0)
    K = camera.intrinsics()
    uv, _ = camera.project_points(np.array([[0, 0, 0.3]]), K, R, t)  # front point
    assert uv[0, 1] > 32  # seen from above, a point towards the camera is lower in the image


def test_intrinsics_fov_and_scaling():
    K = camera.intrinsics(64, 49.13)
    assert camera.fov_from_focal(K[0, 0], 64) == pytest.approx(49.13)
    K48 = camera.scale_intrinsics(K, 48, 64)
    np.testing.assert_allclose(K48, camera.intrinsics(48, 49.13))


def test_numpy_and_torch_agree_and_torch_is_differentiable():
    az = np.array([0.0, 37.0, 359.0])
    R_np, t_np = camera.extrinsics(az, 30.0, 2.0)
    az_t = torch.tensor(az, dtype=torch.float64, requires_grad=True)
    R_t, t_t = camera.extrinsics(az_t, torch.tensor(30.0, dtype=torch.float64), torch.tensor(2.0, dtype=torch.float64))
    np.testing.assert_allclose(R_t.detach().numpy(), R_np, atol=1e-12)
    np.testing.assert_allclose(t_t.detach().numpy(), t_np, atol=1e-12)
    R_t.sum().backward()
    assert az_t.grad is not None and torch.isfinite(az_t.grad).all()


def test_pixel_rays_pass_through_projected_points():
    K = camera.intrinsics(32)
    R, t = camera.extrinsics(40.0, 30.0, 2.0)
    origin, dirs = camera.pixel_rays(K, R, t, 32)
    np.testing.assert_allclose(origin, camera.camera_center(40.0, 30.0, 2.0), atol=1e-12)
    # the centre of pixel (u=5, v=20) back-projected to depth 1.7 projects back onto that pixel centre
    d = dirs[20 * 32 + 5]
    cam_z = (R @ d)[2]
    point = origin + d * (1.7 / cam_z)
    uv, z = camera.project_points(point[None], K, R, t)
    np.testing.assert_allclose(uv[0], [5.5, 20.5], atol=1e-9)
    np.testing.assert_allclose(z, 1.7)
    R_t = torch.tensor(R)
    o_t, d_t = camera.pixel_rays(torch.tensor(K), R_t, torch.tensor(t), 32)
    np.testing.assert_allclose(d_t.numpy(), dirs, atol=1e-12)
