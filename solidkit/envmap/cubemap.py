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

The NumPy paths cache their ``cv2.remap`` maps per (face size, panorama height): repeated
conversions of one size only pay for padding and ``cv2.remap``.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any, cast

import numpy as np

from solidkit.envmap.coords import direction_grid, rotation_from_ypr
from solidkit.envmap.perspective import intrinsics_from_fov, pixel_rays, project_to_pixels
from solidkit.envmap.resample import (
    PAD,
    blockwise_maps,
    cached_direction_grid,
    check_interp,
    cv2_maps,
    is_torch,
    pad_panorama,
    panorama_height,
    remap,
    sample_panorama,
    torch_remap,
    vecmat,
)
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
    """Camera-to-panorama rotations of the six faces, ``(6, 3, 3)``, in ``CUBE_FACES`` order.

    Examples
    --------
    >>> R = cube_face_rotations()
    >>> R.shape, [str(f) for f in CUBE_FACES]
    ((6, 3, 3), ['front', 'right', 'back', 'left', 'up', 'down'])
    >>> np.round(R[0] @ [0.0, 0.0, 1.0], 12) + 0.0  # the first face's optical axis
    array([0., 0., 1.])
    """
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

    Examples
    --------
    >>> faces = cube_from_equirect(np.ones((32, 64, 3), np.float32), 8)
    >>> faces.shape
    (6, 8, 8, 3)
    >>> float(faces.min()), float(faces.max())
    (1.0, 1.0)
    """
    size = int(size)
    if size < 1:
        raise InputError(f"cube face size must be >= 1, got {size}")
    check_interp(interp)
    if is_torch(pano):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        dtype = pano.dtype if pano.dtype in (torch.float32, torch.float64) else torch.float32
        d = torch.as_tensor(_face_directions(size), dtype=dtype, device=pano.device)
        out = sample_panorama(pano, d, interp, per_item=False)
        return out.transpose(-4, -3)  # (B, C, 6, S, S) -> (B, 6, C, S, S)
    h = panorama_height(pano)
    map_x, map_y = _equirect_to_cube_maps(size, h)
    return remap(pad_panorama(pano, PAD), map_x, map_y, interp)


def _face_directions(size: int) -> np.ndarray:
    """Directions of every face pixel, ``(6, S, S, 3)``: the six 90° pinhole views' rays ``R_k K⁻¹ (x, y, 1)``."""
    rays = pixel_rays(intrinsics_from_fov(math.pi / 2, size, size), size, size)
    return np.stack([rays @ R.T for R in _rotations()])


@lru_cache(maxsize=2)
def _equirect_to_cube_maps(size: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    d = _face_directions(size)
    maps = cv2_maps(lambda a, b: d[a:b], d.shape[:-1], height)
    for m in maps:
        m.setflags(write=False)
    return cast(tuple[np.ndarray, np.ndarray], maps)


def _face_lookup(d: Any, size: int) -> tuple[Any, Any, Any]:
    """Face index and face pixel coordinates (OpenCV, centres at integers) of directions ``d (..., 3)``.

    A direction belongs to the face whose optical axis ``R_k e_z`` it is closest to, i.e. the
    face with the largest camera-frame ``z``; its coordinates are ``K R_kᵀ d / z``.
    """
    K = intrinsics_from_fov(math.pi / 2, size, size)
    R = _rotations()
    if is_torch(d):  # differentiable: every face's projection, selected per direction
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        Rt = torch.as_tensor(R.copy(), dtype=d.dtype, device=d.device)
        face = torch.argmax(vecmat(d, Rt[:, :, 2].T), dim=-1)
        x = y = None
        for k in range(6):
            xk, yk, _ = project_to_pixels(K, vecmat(d, Rt[k]))
            x = xk if x is None else torch.where(face == k, xk, x)
            y = yk if y is None else torch.where(face == k, yk, y)
        return face, x, y
    face = np.argmax(d @ R[:, :, 2].T, axis=-1)
    x = np.empty(d.shape[:-1])
    y = np.empty(d.shape[:-1])
    for k in range(6):
        m = face == k
        x[m], y[m], _ = project_to_pixels(K, d[m] @ R[k])
    return face, x, y


@lru_cache(maxsize=4)
def _ring_maps(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Border ring of a padded face and where its pixels are on the unpadded face atlas."""
    P, n = _FACE_PAD, size + 2 * _FACE_PAD
    Kp = intrinsics_from_fov(math.pi / 2, size, size)
    Kp[:2, 2] += P  # padded pixel (i, j) is face pixel (i - P, j - P)
    ring = np.ones((n, n), bool)
    ring[P:-P, P:-P] = False
    rays = pixel_rays(Kp, n, n)[ring]  # (M, 3), camera frame
    d = np.einsum("kij,mj->kmi", _rotations(), rays)  # R_k ray, (6, M, 3)
    face, x, y = _face_lookup(d, size)
    # clamp inside the source face so that interpolation never bleeds into the next atlas tile
    x = x.clip(0, size - 1)
    y = y.clip(0, size - 1) + face * size
    for a in (ring, x, y):
        a.setflags(write=False)
    return ring, x, y


def _padded_atlas(faces: Any, size: int, interp_pad: str = "linear") -> Any:
    """Faces padded by ``_FACE_PAD`` with re-projected neighbour pixels, stacked vertically.

    The interior of each padded tile is the face itself; only the border ring is looked up on
    the neighbouring faces. NumPy: ``(6 (S + 2P), S + 2P[, C])``; torch: ``(B, C, 6 (S + 2P), S + 2P)``.
    """
    P, n = _FACE_PAD, size + 2 * _FACE_PAD
    ring, x, y = _ring_maps(size)
    if is_torch(faces):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        b, _, ch = faces.shape[:3]
        atlas = faces.transpose(1, 2).reshape(b, ch, 6 * size, size)
        xt = torch.tensor(x, dtype=faces.dtype, device=faces.device)
        yt = torch.tensor(y, dtype=faces.dtype, device=faces.device)
        border = torch_remap(atlas, xt.expand(b, *xt.shape), yt.expand(b, *yt.shape), interp_pad, "replicate")
        padded = faces.new_zeros(b, ch, 6, n, n)
        padded[..., P:-P, P:-P] = faces.transpose(1, 2)
        padded[..., torch.tensor(ring, device=faces.device)] = border
        return padded.reshape(b, ch, 6 * n, n)
    atlas = faces.reshape(6 * size, size, *faces.shape[3:])
    padded = np.empty((6, n, n, *faces.shape[3:]), faces.dtype)
    padded[:, P:-P, P:-P] = faces
    padded[:, ring] = remap(atlas, x, y, interp_pad, "replicate")
    return padded.reshape(6 * n, n, *faces.shape[3:])


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

    Examples
    --------
    >>> pano = (direction_grid(32) * 0.5 + 0.5).astype(np.float32)  # a smooth panorama
    >>> back = equirect_from_cube(cube_from_equirect(pano, 32), 32)
    >>> back.shape
    (32, 64, 3)
    >>> bool(np.abs(back - pano).max() < 0.02)  # a round trip changes a smooth panorama little
    True
    """
    check_interp(interp)
    height = int(height)
    if height < 1:
        raise InputError(f"panorama height must be >= 1, got {height}")
    torch_in = is_torch(faces)
    unbatched = torch_in and faces.ndim == 4
    if torch_in:
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

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
    if 6 * (size + 2 * _FACE_PAD) >= 32767:
        raise InputError(f"cube face size {size} too large (max 5456)")
    atlas = _padded_atlas(faces, size)
    if torch_in:
        b = faces.shape[0]
        x, y = _atlas_coords(d, size)
        out = torch_remap(atlas, x.expand(b, *x.shape), y.expand(b, *y.shape), interp)
        return out[0] if unbatched else out
    map_x, map_y = _cube_to_equirect_maps(size, height)
    return remap(atlas, map_x, map_y, interp)


def _atlas_coords(d: Any, size: int) -> tuple[Any, Any]:
    """Coordinates of directions ``d`` on the padded atlas (face tiles stacked vertically)."""
    face, x, y = _face_lookup(d, size)
    return x + _FACE_PAD, y + _FACE_PAD + face * (size + 2 * _FACE_PAD)


@lru_cache(maxsize=2)
def _cube_to_equirect_maps(size: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    d = cached_direction_grid(height)
    maps = blockwise_maps(lambda a, b: _atlas_coords(d[a:b], size), d.shape[:-1])
    for m in maps:
        m.setflags(write=False)
    return maps
