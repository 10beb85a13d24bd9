"""Pins docs/conventions.md: mapping, directions, solid angles, rotations (NumPy and torch)."""

import math

import numpy as np
import pytest
import torch

from solidkit.envmap import coords as C

H = 64
W = 2 * H


def test_centre_column_is_forward_and_right_is_three_quarters():
    d = C.direction_from_coords(np.array([W / 2, 3 * W / 4, W / 4]), np.array([H / 2] * 3), H)
    np.testing.assert_allclose(d, [[0, 0, 1], [1, 0, 0], [-1, 0, 0]], atol=1e-12)


def test_pixel_centre_formulas():
    u, v = 10, 5
    phi, theta = C.angles_from_coords(u + 0.5, v + 0.5, H)
    assert phi == pytest.approx(2 * math.pi * (u + 0.5) / W - math.pi)
    assert theta == pytest.approx(math.pi / 2 - math.pi * (v + 0.5) / H)


def test_top_row_is_up_and_seam_is_back():
    d_top = C.direction_from_coords(np.array(W / 2), np.array(0.0), H)
    np.testing.assert_allclose(d_top, [0, -1, 0], atol=1e-12)
    d_seam = C.direction_from_coords(np.array(0.0), np.array(H / 2), H)
    np.testing.assert_allclose(d_seam, [0, 0, -1], atol=1e-12)


def test_marker_directions_land_at_documented_pixels():
    rng = np.random.default_rng(0)
    u = rng.integers(0, W, 50)
    v = rng.integers(0, H, 50)
    d = C.direction_from_coords(u + 0.5, v + 0.5, H)
    x, y = C.coords_from_direction(d, H)
    np.testing.assert_allclose(np.floor(x), u)
    np.testing.assert_allclose(np.floor(y), v)
    np.testing.assert_allclose(x, u + 0.5, atol=1e-9)


def test_solid_angles_sum_to_4pi_numpy_and_torch():
    for h in (8, 64, 513):
        assert abs(C.solid_angle(h).sum() / (4 * math.pi) - 1) < 1e-4
    t = C.solid_angle(128, torch, dtype=torch.float32)
    assert t.shape == (128, 256) and abs(float(t.sum()) / (4 * math.pi) - 1) < 1e-4


def test_numpy_and_torch_grids_agree():
    dn = C.direction_grid(16)
    dt = C.direction_grid(16, torch, dtype=torch.float64)
    np.testing.assert_allclose(dn, dt.numpy(), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(dn, axis=-1), 1.0, atol=1e-12)


def test_rotation_signs():
    fwd = np.array([0.0, 0.0, 1.0])
    right = np.array([1.0, 0.0, 0.0])
    yaw = C.rotation_from_ypr(math.radians(30))
    phi, theta = C.angles_from_direction(yaw @ fwd)
    assert math.degrees(phi) == pytest.approx(30) and theta == pytest.approx(0)
    pitch = C.rotation_from_ypr(0, math.radians(20))
    phi, theta = C.angles_from_direction(pitch @ fwd)
    assert math.degrees(theta) == pytest.approx(20)
    roll = C.rotation_from_ypr(0, 0, math.radians(10))
    assert (roll @ right)[1] > 0  # right axis turns down (+y)


def test_ypr_round_trip_numpy_and_batched_torch():
    rng = np.random.default_rng(1)
    ypr = np.stack([rng.uniform(-3, 3, 20), rng.uniform(-1.5, 1.5, 20), rng.uniform(-3, 3, 20)])
    R = C.rotation_from_ypr(*ypr)
    assert R.shape == (20, 3, 3)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.stack(C.ypr_from_rotation(R)), ypr, atol=1e-9)
    Rt = C.rotation_from_ypr(*torch.tensor(ypr, requires_grad=True))
    np.testing.assert_allclose(Rt.detach().numpy(), R, atol=1e-12)


def test_angular_distance():
    a = C.direction_from_angles(np.array(0.1), np.array(0.2))
    b = C.direction_from_angles(np.array(0.1 + 1e-7), np.array(0.2))
    assert C.angular_distance(a, a) == pytest.approx(0, abs=1e-12)
    assert C.angular_distance(a, b) == pytest.approx(1e-7 * math.cos(0.2), rel=1e-5)
    assert C.angular_distance(a, -a) == pytest.approx(math.pi)


def test_torch_gradients_flow():
    phi = torch.tensor([0.3], requires_grad=True)
    d = C.direction_from_angles(phi, torch.tensor([0.1]))
    d[..., 0].sum().backward()
    assert phi.grad is not None and phi.grad.abs().item() > 0


def test_azimuth_of_back_direction_is_minus_pi():
    for d in (np.array([0.0, 0.0, -1.0]), np.array([1e-17, 0.0, -1.0]), np.array([-0.0, 0.0, -1.0])):
        phi, _ = C.angles_from_direction(d)
        assert -math.pi <= float(phi) < math.pi
    phi_t, _ = C.angles_from_direction(torch.tensor([1e-17, 0.0, -1.0], dtype=torch.float64))
    assert float(phi_t) == pytest.approx(-math.pi)


def test_rotation_mixes_tensor_and_float_angles():
    yaw = torch.tensor([0.3, -0.2], dtype=torch.float64)
    R = C.rotation_from_ypr(yaw, 0.1)
    assert isinstance(R, torch.Tensor) and R.shape == (2, 3, 3) and R.dtype == torch.float64
    np.testing.assert_allclose(R[0].numpy(), C.rotation_from_ypr(0.3, 0.1), atol=1e-12)
    assert C.rotation_from_ypr(np.float32(0.3), 0.1, 0.0).dtype == np.float32
