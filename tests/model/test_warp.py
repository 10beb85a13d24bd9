"""Geometry and panoramic forward warping (paper §4.2) against analytic ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from solidkit.envmap.coords import rotation_from_ypr
from solidkit.envmap.perspective import intrinsics_from_fov, pixel_rays
from solidkit.errors import InputError
from solidkit.model.warp import (
    camera_rotation,
    forward_warp,
    points_from_plane_distance,
    probe_centres,
    warp_to_probes,
)

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _analytic_pixel(d: np.ndarray, height: int) -> tuple[float, float]:
    """Equirect continuous coordinates of direction d, written out independently of envmap."""
    phi = math.atan2(d[0], d[2])
    theta = math.asin(-d[1] / np.linalg.norm(d))
    x = (phi + math.pi) / (2 * math.pi) * (2 * height)
    y = (math.pi / 2 - theta) / math.pi * height
    return x, y


def _K(h=240, w=320, fov=60.0):
    return torch.tensor(intrinsics_from_fov(math.radians(fov), w, h), dtype=torch.float64)[None]


def test_pixel_rays_batched_torch_match_opencv_formula():
    K = _K()
    v = pixel_rays(K, 320, 240, torch, dtype=K.dtype).movedim(-1, -3)[0]  # as model.warp uses it: (B, 3, H, W)
    fx, cx, cy = K[0, 0, 0], K[0, 0, 2], K[0, 1, 2]
    for x, y in [(0, 0), (319, 239), (17, 200)]:
        expect = torch.tensor([(x - cx) / fx, (y - cy) / fx, 1.0], dtype=torch.float64)
        assert torch.allclose(v[:, y, x], expect, atol=1e-9)


def test_points_lie_on_their_plane_and_reproject_to_their_pixel():
    K = _K()
    g = torch.Generator().manual_seed(1)
    n = torch.nn.functional.normalize(torch.tensor([0.2, -0.9, -0.4], dtype=torch.float64), dim=0)
    normal = n.view(1, 3, 1, 1).expand(1, 3, 240, 320).clone()
    normal += 0.05 * torch.randn(1, 3, 240, 320, generator=g, dtype=torch.float64)
    normal = torch.nn.functional.normalize(normal, dim=1)
    p = 1.0 + torch.rand(1, 1, 240, 320, generator=g, dtype=torch.float64)
    P, valid = points_from_plane_distance(normal, p, K)
    assert valid.float().mean() > 0.3
    on_plane = (normal * P).sum(1, keepdim=True) + p
    assert on_plane[valid].abs().max() < 1e-9
    proj = (K[0] @ P[0].reshape(3, -1)).reshape(3, 240, 320)
    xs, ys = proj[0] / proj[2], proj[1] / proj[2]
    yy, xx = torch.meshgrid(
        torch.arange(240.0, dtype=torch.float64), torch.arange(320.0, dtype=torch.float64), indexing="ij"
    )
    assert (xs - xx)[valid[0, 0]].abs().max() < 1e-6 and (ys - yy)[valid[0, 0]].abs().max() < 1e-6
    # surfaces seen edge-on or from behind are invalid, and their points are zero
    assert (P * ~valid).abs().max() == 0


def test_camera_rotation_is_conventions_ypr():
    pitch, roll = torch.tensor([0.2, -0.1]), torch.tensor([0.05, 0.3])
    R = camera_rotation(pitch, roll)
    for i in range(2):
        expect = rotation_from_ypr(0.0, float(pitch[i]), float(roll[i]))
        assert np.allclose(R[i].numpy(), expect, atol=1e-6)


@pytest.mark.parametrize("u,v", [(37, 90), (128, 64), (255, 3), (0, 127), (200, 20)])
def test_forward_warp_places_point_at_analytic_pixel(u, v):
    h = 128
    centre = torch.tensor([[0.3, -0.2, 1.0]], dtype=torch.float64)
    # direction of an off-centre spot inside pixel (u, v), then a point 4.2 m along it
    phi = 2 * math.pi * (u + 0.3) / (2 * h) - math.pi
    theta = math.pi / 2 - math.pi * (v + 0.7) / h
    d = np.array([math.cos(theta) * math.sin(phi), -math.sin(theta), math.cos(theta) * math.cos(phi)])
    point = centre[0].numpy() + 4.2 * d
    points = torch.zeros(1, 3, 2, 2, dtype=torch.float64)
    points[0, :, 1, 0] = torch.from_numpy(point)
    valid = torch.zeros(1, 1, 2, 2, dtype=torch.bool)
    valid[0, 0, 1, 0] = True
    values = torch.arange(4, dtype=torch.float64).view(1, 1, 2, 2) + 1
    warped, mask = forward_warp(values, points, centre, valid, h)
    assert warped.shape == (1, 1, h, 2 * h) and mask.shape == (1, 1, h, 2 * h)
    hits = torch.nonzero(mask[0, 0])
    assert hits.tolist() == [[v, u]]
    x, y = _analytic_pixel(point - centre[0].numpy(), h)
    assert abs(u + 0.5 - x) <= 0.5 and abs(v + 0.5 - y) <= 0.5
    assert warped[0, 0, v, u] == values[0, 0, 1, 0]
    assert warped.sum() == warped[0, 0, v, u]  # empty pixels are 0


@pytest.mark.parametrize("near_first", [True, False])
def test_forward_warp_keeps_the_nearer_point(near_first):
    d = torch.nn.functional.normalize(torch.tensor([0.3, -0.1, 0.8], dtype=torch.float64), dim=0)
    near, far = 2.0 * d, 5.0 * d
    points = torch.stack([near, far] if near_first else [far, near], dim=-1).view(1, 3, 1, 2)
    values = torch.tensor([[[[10.0, 20.0]]]], dtype=torch.float64)
    warped, mask = forward_warp(values, points, torch.zeros(1, 3, dtype=torch.float64), None, 64)
    assert mask.sum() == 1
    assert warped.max() == (10.0 if near_first else 20.0)


def test_forward_warp_batched_matches_single_and_multiple_probes():
    g = torch.Generator().manual_seed(3)
    pts = torch.randn(4, 3, 12, 16, generator=g) * 3
    vals = torch.rand(4, 2, 12, 16, generator=g)
    centres = torch.randn(4, 3, 3, generator=g) * 0.2
    warped, mask = forward_warp(vals, pts, centres, None, 32)
    assert warped.shape == (4, 3, 2, 32, 64) and mask.shape == (4, 3, 1, 32, 64)
    for b in range(4):
        for k in range(3):
            w1, m1 = forward_warp(vals[b : b + 1], pts[b : b + 1], centres[b : b + 1, k], None, 32)
            assert torch.equal(w1[0], warped[b, k]) and torch.equal(m1[0], mask[b, k])


def test_forward_warp_gradient_reaches_values():
    pts = torch.randn(1, 3, 8, 8) * 3
    vals = torch.rand(1, 3, 8, 8, requires_grad=True)
    warped, mask = forward_warp(vals, pts, torch.zeros(1, 3), None, 16)
    warped.sum().backward()
    assert vals.grad.sum() == mask.sum() * 3  # each winning source pixel gets a gradient of 1 per channel


def test_warp_to_probes_ground_plane_with_pitch():
    """A level ground plane seen by a pitched camera: the probe sits 10 cm above the ground, and the
    ground points land in the lower half of its panorama at the analytic pixels."""
    H, W = 60, 80
    K = _K(H, W, 70.0)
    pitch, roll = torch.tensor([-0.15], dtype=torch.float64), torch.tensor([0.05], dtype=torch.float64)
    R = camera_rotation(pitch, roll)[0]
    n_cam = R.T @ torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)  # ground normal (up) in the camera
    normal = n_cam.view(1, 3, 1, 1).expand(1, 3, H, W).contiguous()
    dist = torch.full((1, 1, H, W), 1.6, dtype=torch.float64)
    pixels = torch.tensor([[[40.0, 50.0]]], dtype=torch.float64)
    values = torch.rand(1, 3, H, W, dtype=torch.float64)
    warped, mask, centres = warp_to_probes(values, normal, dist, K, pixels, pitch, roll, 32, 0.10)
    assert torch.allclose(centres[0, 0, 1], torch.tensor(1.5, dtype=torch.float64))  # 1.6 m down, 0.1 m up
    rows = torch.nonzero(mask[0, 0, 0])[:, 0]
    assert rows.numel() > 0 and rows.min() >= 16  # only the lower hemisphere is observed
    # analytic: pixel (40, 50)'s ray in the panorama frame hits y = 1.6; seen from the probe
    v = torch.tensor([(40 - K[0, 0, 2]) / K[0, 0, 0], (50 - K[0, 1, 2]) / K[0, 1, 1], 1.0], dtype=torch.float64)
    for px in [(10, 55), (70, 45)]:
        ray = R @ torch.tensor(
            [(px[0] - K[0, 0, 2]) / K[0, 0, 0], (px[1] - K[0, 1, 2]) / K[0, 1, 1], 1.0], dtype=torch.float64
        )
        point = ray * (1.6 / ray[1])
        x, y = _analytic_pixel((point - centres[0, 0]).numpy(), 32)
        u, vv = int(math.floor(x)) % 64, int(math.floor(y))
        assert mask[0, 0, 0, vv, u] == 1
    assert torch.allclose(
        centres[0, 0, :], (R @ v) * (1.6 / (R @ v)[1]) + torch.tensor([0, -0.1, 0], dtype=torch.float64)
    )


def test_probe_centre_normal_faces_camera_and_bad_pixel_fails():
    pts = torch.zeros(1, 3, 4, 4)
    pts[:, 2] = 5.0
    nrm = torch.zeros(1, 3, 4, 4)
    nrm[:, 2] = 1.0  # pointing away from the camera: flipped toward it
    c = probe_centres(pts, nrm, torch.tensor([[[1.0, 2.0]]]), 0.1)
    assert torch.allclose(c, torch.tensor([[[0.0, 0.0, 4.9]]]))
    with pytest.raises(InputError):
        probe_centres(pts, nrm, torch.tensor([[[7.0, 2.0]]]), 0.1)
