"""Equirect <-> cube faces: documented face order/orientation, seam-free round trips, NumPy and torch."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from solidkit.envmap import coords as C
from solidkit.envmap.cubemap import CUBE_FACES, cube_face_rotations, cube_from_equirect, equirect_from_cube
from solidkit.envmap.perspective import intrinsics_from_fov, pixel_rays
from solidkit.errors import InputError
from tests.envmap.test_resample import blob, smooth_field, smooth_pano, spherical_centroid, to_numpy, to_torch

H = 96
S = 64


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def analytic_faces(size: int) -> np.ndarray:
    rays = unit(pixel_rays(intrinsics_from_fov(math.pi / 2, size, size), size, size))
    return np.stack([smooth_field(rays @ R.T) for R in cube_face_rotations()]).astype(np.float32)


def test_face_order_and_orientation_are_as_documented():
    assert CUBE_FACES == ("front", "right", "back", "left", "up", "down")
    R = cube_face_rotations()
    axes = {
        "front": [0, 0, 1],
        "right": [1, 0, 0],
        "back": [0, 0, -1],
        "left": [-1, 0, 0],
        "up": [0, -1, 0],
        "down": [0, 1, 0],
    }
    image_up = {"front": "up", "right": "up", "back": "up", "left": "up", "up": "back", "down": "front"}
    for k, name in enumerate(CUBE_FACES):
        np.testing.assert_allclose(R[k] @ [0, 0, 1], axes[name], atol=1e-12)  # optical axis
        np.testing.assert_allclose(R[k] @ [0, -1, 0], axes[image_up[name]], atol=1e-12)  # row-0 side
    # a marker straight ahead lands at the centre of the front face; one to the right in the right face
    d = C.direction_grid(H)
    for k, name in enumerate(CUBE_FACES):
        faces = cube_from_equirect(blob(d, np.array(axes[name], float), 0.05).astype(np.float32), S)
        assert np.unravel_index(faces.reshape(6, -1).sum(-1).argmax(), (6,))[0] == k
        peak = np.unravel_index(faces[k].argmax(), (S, S))
        assert abs(peak[0] - (S - 1) / 2) <= 0.5 and abs(peak[1] - (S - 1) / 2) <= 0.5


def test_faces_match_the_analytic_views():
    p = smooth_pano(H)
    faces = cube_from_equirect(p, S)
    assert faces.shape == (6, S, S, 3)
    truth = analytic_faces(S)
    assert np.abs(faces - truth).mean() < 2e-3 and np.abs(faces - truth).max() < 2e-2


@pytest.mark.parametrize("interp", ["linear", "cubic"])
def test_equirect_from_cube_is_seam_free(interp):
    """From exact faces, every panorama pixel (face edges, cube corners, poles) is accurate."""
    out = equirect_from_cube(analytic_faces(S), H, interp)
    truth = smooth_field(C.direction_grid(H))
    assert out.shape == (H, 2 * H, 3)
    rng = truth.max() - truth.min()
    err = np.abs(out - truth)
    assert err.mean() / rng < 2e-4 and err.max() / rng < 2e-3


def test_cube_round_trip_returns_the_panorama():
    p = smooth_pano(H, seed=6)
    back = equirect_from_cube(cube_from_equirect(p, S), H)
    rng = p.max() - p.min()
    assert np.abs(back - p).mean() / rng < 1e-3 and np.abs(back - p).max() / rng < 5e-3


@pytest.mark.parametrize("direction", [[1, -1, 1], [-1, 1, -1], [0.0, -1.0, 1.0], [1.0, 0.0, -1.0]])
def test_marker_on_a_cube_corner_or_edge_survives_the_round_trip(direction):
    d0 = unit(np.array(direction, float))
    p = blob(C.direction_grid(H), d0, 2 * math.pi / H).astype(np.float32)
    back = equirect_from_cube(cube_from_equirect(p, S), H)
    assert float(C.angular_distance(spherical_centroid(back), d0)) < 0.5 * math.pi / H
    assert np.abs(back - p).max() < 0.08  # two bilinear resamplings of a 2-px disk


def test_torch_matches_numpy_and_is_differentiable():
    p = smooth_pano(H)
    t = to_torch(p).requires_grad_()
    faces_t = cube_from_equirect(t, S)
    assert faces_t.shape == (1, 6, 3, S, S)
    faces_n = cube_from_equirect(p, S)
    np.testing.assert_allclose(faces_t[0].detach().permute(0, 2, 3, 1).numpy(), faces_n, atol=1e-4)
    back_t = equirect_from_cube(faces_t, H)
    np.testing.assert_allclose(to_numpy(back_t), equirect_from_cube(faces_n, H), atol=2e-4)
    back_t.sum().backward()
    assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0
    assert equirect_from_cube(faces_t[0].detach(), H).shape == (3, H, 2 * H)


def test_bad_input():
    with pytest.raises(InputError):
        equirect_from_cube(np.zeros((5, 8, 8, 3)), 16)
    with pytest.raises(InputError):
        equirect_from_cube(np.zeros((6, 8, 9, 3)), 16)
    with pytest.raises(InputError):
        cube_from_equirect(smooth_pano(16), 0)
