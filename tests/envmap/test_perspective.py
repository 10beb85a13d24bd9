"""Perspective crops of a panorama and their inverse (embedding a photo), NumPy and torch."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from solidkit.envmap import coords as C
from solidkit.envmap.perspective import (
    embed_perspective,
    intrinsics_from_fov,
    perspective_crop,
    pixel_rays,
    project_to_pixels,
)
from solidkit.errors import InputError
from tests.envmap.test_resample import PITCH, blob, smooth_field, smooth_pano, spherical_centroid, to_numpy, to_torch

H = 128
CAMERAS = [
    C.rotation_from_ypr(0.5, 0.2, 0.1),
    C.rotation_from_ypr(math.radians(175.0), math.radians(-30.0), math.radians(-20.0)),  # across the seam
    C.rotation_from_ypr(math.radians(-40.0), math.radians(75.0), 0.0),  # looking near the zenith
]


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_intrinsics_from_fov_span_the_image_edges():
    K = intrinsics_from_fov(math.radians(90.0), 100, 60)
    assert K[0, 0] == pytest.approx(50.0) and K[1, 1] == pytest.approx(50.0)
    assert (K[0, 2], K[1, 2]) == (49.5, 29.5)
    rays = unit(pixel_rays(K, 100, 60))
    np.testing.assert_allclose(unit(np.linalg.inv(K) @ [49.5, 29.5, 1.0]), [0, 0, 1])
    left_edge = unit(np.linalg.inv(K) @ [-0.5, 29.5, 1.0])
    assert math.degrees(math.acos(left_edge[2])) == pytest.approx(45.0)
    x, y, front = project_to_pixels(K, rays)
    np.testing.assert_allclose(x, np.broadcast_to(np.arange(100), (60, 100)), atol=1e-9)
    np.testing.assert_allclose(y, np.broadcast_to(np.arange(60)[:, None], (60, 100)), atol=1e-9)
    assert front.all()


@pytest.mark.parametrize("cam", range(len(CAMERAS)))
def test_crop_matches_the_analytic_view(cam):
    p = smooth_pano(H)
    R = CAMERAS[cam]
    K = intrinsics_from_fov(math.radians(80.0), 120, 90)
    truth = smooth_field(unit(pixel_rays(K, 120, 90) @ R.T))
    crop = perspective_crop(p, R, (120, 90), K=K)
    assert crop.shape == (90, 120, 3)
    assert np.abs(crop - truth).mean() < 2e-3 and np.abs(crop - truth).max() < 2e-2
    t = perspective_crop(to_torch(p), torch.from_numpy(R), (120, 90), fov=math.radians(80.0))
    np.testing.assert_allclose(to_numpy(t), crop, atol=1e-4)


@pytest.mark.parametrize("cam", range(len(CAMERAS)))
def test_marker_lands_at_the_projected_pixel(cam):
    R = CAMERAS[cam]
    K = intrinsics_from_fov(math.radians(70.0), 160, 120)
    rng = np.random.default_rng(cam)
    x0, y0 = rng.uniform(30, 130), rng.uniform(25, 95)
    d0 = unit(R @ np.linalg.inv(K) @ [x0, y0, 1.0])
    p = blob(C.direction_grid(256), d0, math.radians(1.2)).astype(np.float32)
    crop = perspective_crop(p, R, (160, 120), K=K)
    cy, cx = ndimage.center_of_mass(crop)
    assert math.hypot(cx - x0, cy - y0) < 0.5, (cx - x0, cy - y0)
    x, y, front = project_to_pixels(K, R.T @ d0)
    assert front and math.hypot(float(x) - x0, float(y) - y0) < 1e-9


def test_roll_sign_turns_the_view():
    """roll > 0 turns the camera's right axis down, so a level point to the right appears higher."""
    p = blob(C.direction_grid(H), C.direction_from_angles(math.radians(15.0), 0.0), 2 * PITCH)
    crop = perspective_crop(
        p.astype(np.float32), C.rotation_from_ypr(0.0, 0.0, math.radians(20.0)), (101, 101), fov=math.radians(60)
    )
    cy, cx = ndimage.center_of_mass(crop)
    assert cx > 50 and cy < 50 - 5


@pytest.mark.parametrize("cam", range(len(CAMERAS)))
def test_crop_then_embed_returns_the_panorama_in_the_footprint(cam):
    p = smooth_pano(H, seed=4)
    R = CAMERAS[cam]
    K = intrinsics_from_fov(math.radians(90.0), 160, 120)
    crop = perspective_crop(p, R, (160, 120), K=K)
    pano, mask = embed_perspective(crop, K, R, H)
    assert pano.shape == p.shape and mask.shape == p.shape[:2]
    # covered solid angle = the frustum's: 4 asin(sin(a/2) sin(b/2)) for a rectangular pyramid
    a, b = math.radians(90.0), 2 * math.atan(60 / 80)
    frustum = 4 * math.asin(math.sin(a / 2) * math.sin(b / 2))
    assert float((mask * C.solid_angle(H)).sum()) == pytest.approx(frustum, rel=0.01)
    inner = ndimage.binary_erosion(mask > 0, iterations=2)
    rng = p.max() - p.min()
    err = np.abs(pano - p)[inner]
    assert err.mean() / rng < 1e-3 and err.max() / rng < 1e-2
    assert (pano[mask == 0] == 0).all()
    # the footprint is the set of directions inside the frustum
    x, y, front = project_to_pixels(K, C.direction_grid(H) @ R)
    expected = front & (x >= -0.5) & (x <= 159.5) & (y >= -0.5) & (y <= 119.5)
    np.testing.assert_array_equal(mask > 0, expected)


def test_embedded_marker_goes_to_its_ray_direction():
    R, K = CAMERAS[1], intrinsics_from_fov(math.radians(60.0), 200, 150)
    photo = np.zeros((150, 200), np.float32)
    photo[40, 150] = 1000.0
    pano, mask = embed_perspective(photo, K, R, 256, interp="linear")
    target = unit(R @ np.linalg.inv(K) @ [150.0, 40.0, 1.0])
    assert float(C.angular_distance(spherical_centroid(pano), target)) < 0.5 * math.pi / 256


def test_torch_embed_and_batched_crops_match_numpy_and_are_differentiable():
    p = smooth_pano(H)
    K = intrinsics_from_fov(math.radians(70.0), 64, 48)
    Rs = torch.from_numpy(np.stack(CAMERAS[:2])).float().requires_grad_()
    t = to_torch(p)
    crops = perspective_crop(torch.cat([t, t]), Rs, (64, 48), K=K)
    assert crops.shape == (2, 3, 48, 64)
    for i in range(2):
        np.testing.assert_allclose(
            to_numpy(crops[i : i + 1]), perspective_crop(p, CAMERAS[i], (64, 48), K=K), atol=1e-4
        )
    crops.sum().backward()
    assert Rs.grad is not None and Rs.grad.abs().sum() > 0
    pano_t, mask_t = embed_perspective(crops.detach(), K, Rs.detach(), 64)
    assert pano_t.shape == (2, 3, 64, 128) and mask_t.shape == (2, 1, 64, 128)
    for i in range(2):
        pano_n, mask_n = embed_perspective(to_numpy(crops[i : i + 1]), K, CAMERAS[i], 64)
        assert (mask_t[i, 0].numpy() != mask_n).sum() <= 2  # float32 vs float64 at the frustum edge
        both = (mask_t[i, 0].numpy() > 0) & (mask_n > 0)
        np.testing.assert_allclose(to_numpy(pano_t[i : i + 1])[both], pano_n[both], atol=1e-4)


def test_bad_input():
    p = smooth_pano(32)
    with pytest.raises(InputError):
        perspective_crop(p, np.eye(3), (10, 10))  # neither K nor fov
    with pytest.raises(InputError):
        perspective_crop(p, np.eye(3), (10, 10), fov=math.radians(180.0))
    with pytest.raises(InputError):
        perspective_crop(p, np.eye(3), (10, 10), K=np.eye(2))
    with pytest.raises(InputError):
        embed_perspective(np.zeros((4, 4, 3)), np.eye(3), np.eye(3), 0)
