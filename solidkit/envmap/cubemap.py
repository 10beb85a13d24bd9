"""Equirectangular <-> cube map (six 90° pinhole faces), seam-free in both directions.

Faces, in this order (``CUBE_FACES``), each a square ``S x S`` pinhole view with a 90° field
of view, ``K = intrinsics_from_fov(pi/2, S, S)`` (pixel centres at integers, conventions §1),
and orientation ``R_k = rotation_from_ypr(yaw_k, pitch_k, 0)`` (conventions §4):

=====  ========  ====  =====  ==========================================
index  name      yaw   pitch  image "up" (row 0 side) points to
=====  ========  ====  =====  ==========================================
0      front       0°    0°   up (zenith)
1      right      90°    0°   up
2      back      180°    0°   up
3      left      -90°    0°   up
4      up          0°   90°   back (the face is seen by tilting the head up)
5      down        0°  -90°   front
=====  ========  ====  =====  ==========================================

So the side faces are upright photos looking forward, right, back and left; the up face joins
the front face along its bottom edge and the down face joins it along its top edge (the usual
horizontal-cross layout ``. U . . / L F R B / . D . .``). Face pixel ``(x, y)`` shows direction
``R_k K⁻¹ (x, y, 1)``. This is py360convert's face order (F R B L U D).

Back to equirect, each direction is looked up on the face it hits (largest component along
the face axes). Faces are first padded with their neighbours' pixels (re-projected across
the cube edges), so interpolation at face edges and corners mixes the true neighbours.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np

from solidkit.envmap.coords import direction_grid, rotation_from_ypr
from solidkit.envmap.perspective import intrinsics_from_fov, perspective_crop, pixel_rays, project_to_pixels
from solidkit.envmap.resample import _cached_direction_grid, _check_interp, _is_torch, _remap, _torch_remap, _vecmat
from solidkit.errors import InputError

__all__ = ["CUBE_FACES", "CUBE_FACE_YPR", "cube_face_rotations", "cube_from_equirect", "equirect_from_cube"]

CUBE_FACES = ("front", "right", "back", "left", "up", "down")
#: (yaw, pitch) of each face's optical axis, degrees (roll 0).
CUBE_FACE_YPR = ((0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (-90.0, 0.0), (0.0, 90.0), (0.0, -90.0))
_FACE_PAD = 2  # enough for bicubic


@lru_cache(maxsize=1)
def _rotations() -> np.ndarray:
    R = np.stack([rotation_from_ypr(math.radians(y), math.radians(p), 0.0) for y, p in CUBE_FACE_YPR])
    R.setflags(write=False)
    return R


def cube_face_rotations() -> np.ndarray:
    """Camera-to-panorama rotations of the six faces, ``(6, 3, 3)``, in ``CUBE_FACES`` order."""
    return _rotations().copy()


def cube_from_equirect(pano: Any, size: int, interp: str = "linear") -> Any:
    """Six ``size x size`` cube faces of a panorama (order and orientation: module docstring).

    Parameters
    ----------
    pano : ndarray (H, 2H[, C]) or tensor (B, C, H, 2H) / (C, H, 2H)
    size : int
        Face side ``S`` in pixels.
    interp : {"nearest", "linear", "cubic"}

    Returns
    -------
    ndarray (6, S, S[, C]) or tensor (B, 6, C, S, S) / (6, C, S, S).
    """
    size = int(size)
    if size < 1:
        raise InputError(f"cube face size must be >= 1, got {size}")
    faces = [perspective_crop(pano, R, (size, size), fov=math.pi / 2, interp=interp) for R in cube_face_rotations()]
    if _is_torch(pano):
        import torch

        return torch.stack(faces, dim=-4)
    return np.stack(faces)


def _face_lookup(d: Any, size: int) -> tuple[Any, Any, Any]:
    """Face index and face pixel coordinates (OpenCV, centres at integers) of directions ``d (..., 3)``."""
    K = intrinsics_from_fov(math.pi / 2, size, size)
    R = _rotations()
    if _is_torch(d):
        import torch

        Rt = torch.as_tensor(R.copy(), dtype=d.dtype, device=d.device)
        c = _vecmat(d[..., None, :], Rt)  # Rₖᵀ d for every face, (..., 6, 3)
        face = torch.argmax(c[..., 2], dim=-1)
        c = torch.take_along_dim(c, face[..., None, None].expand(*face.shape, 1, 3), dim=-2)[..., 0, :]
    else:
        c = np.einsum("...i,kij->...kj", d, R)
        face = np.argmax(c[..., 2], axis=-1)
        c = np.take_along_axis(c, face[..., None, None], axis=-2)[..., 0, :]
    x, y, _ = project_to_pixels(K, c)
    return face, x, y


def _padded_atlas(faces: Any, size: int, interp_pad: str = "linear") -> Any:
    """Faces padded by ``_FACE_PAD`` with re-projected neighbour pixels, stacked vertically.

    NumPy: ``(6 (S + 2P), S + 2P[, C])``; torch: ``(B, C, 6 (S + 2P), S + 2P)``.
    """
    P, n = _FACE_PAD, size + 2 * _FACE_PAD
    K = intrinsics_from_fov(math.pi / 2, size, size)
    Kp = K.copy()
    Kp[:2, 2] += P  # padded pixel (i, j) is face pixel (i - P, j - P)
    torch_in = _is_torch(faces)
    if torch_in:
        import torch

        rays = pixel_rays(Kp, n, n, torch, dtype=faces.dtype, device=faces.device)
        Rt = torch.as_tensor(cube_face_rotations(), dtype=faces.dtype, device=faces.device)
        d = _vecmat(rays, Rt.transpose(-1, -2)[:, None, None])  # R_k ray, (6, n, n, 3)
    else:
        d = np.einsum("kij,hwj->khwi", _rotations(), pixel_rays(Kp, n, n))
    face, x, y = _face_lookup(d, size)
    # clamp inside the source face so that interpolation never bleeds into the next atlas tile
    x = x.clip(0, size - 1)
    y = y.clip(0, size - 1) + face * size
    if torch_in:
        b, _, ch = faces.shape[:3]
        atlas = faces.transpose(1, 2).reshape(b, ch, 6 * size, size)
        out = _torch_remap(atlas, x.expand(b, *x.shape), y.expand(b, *y.shape), interp_pad, "replicate")
        return out.reshape(b, ch, 6 * n, n)  # (B, C, 6, n, n) -> stacked
    atlas = faces.reshape(6 * size, size, *faces.shape[3:])
    out = _remap(atlas, x, y, interp_pad, "replicate")
    return out.reshape(6 * n, n, *faces.shape[3:])


def equirect_from_cube(faces: Any, height: int, interp: str = "linear") -> Any:
    """Equirectangular panorama ``(height, 2 height)`` from six cube faces (module docstring).

    Parameters
    ----------
    faces : ndarray (6, S, S[, C]) or tensor (B, 6, C, S, S) / (6, C, S, S)
    height : int
        Output height ``H``.
    interp : {"nearest", "linear", "cubic"}

    Returns
    -------
    ndarray (H, 2H[, C]) or tensor (B, C, H, 2H) / (C, H, 2H). Differentiable for tensors.
    """
    _check_interp(interp)
    height = int(height)
    if height < 1:
        raise InputError(f"panorama height must be >= 1, got {height}")
    torch_in = _is_torch(faces)
    unbatched = torch_in and faces.ndim == 4
    if torch_in:
        import torch

        if unbatched:
            faces = faces[None]
        if faces.ndim != 5 or faces.shape[1] != 6 or faces.shape[-1] != faces.shape[-2]:
            raise InputError(f"torch cube faces must be (B, 6, C, S, S), got {tuple(faces.shape)}")
        if faces.dtype not in (torch.float32, torch.float64):
            faces = faces.float()
        size = faces.shape[-1]
        d = direction_grid(height, torch, dtype=faces.dtype, device=faces.device)
    else:
        faces = np.asarray(faces)
        if faces.ndim not in (3, 4) or faces.shape[0] != 6 or faces.shape[1] != faces.shape[2]:
            raise InputError(f"cube faces must be (6, S, S[, C]), got {faces.shape}")
        size = faces.shape[1]
        d = _cached_direction_grid(height)
    if 6 * (size + 2 * _FACE_PAD) >= 32767:
        raise InputError(f"cube face size {size} too large (max 5456)")
    atlas = _padded_atlas(faces, size)
    face, x, y = _face_lookup(d, size)
    n = size + 2 * _FACE_PAD
    x = x + _FACE_PAD
    y = y + _FACE_PAD + face * n
    if torch_in:
        b = faces.shape[0]
        out = _torch_remap(atlas, x.expand(b, *x.shape), y.expand(b, *y.shape), interp)
        return out[0] if unbatched else out
    return _remap(atlas, x, y, interp)
