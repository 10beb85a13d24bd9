"""Perspective (pinhole) views of a panorama, and the inverse: embedding a photo into a panorama.

Camera model (conventions §1): OpenCV frame (x right, y down, z forward), intrinsics
``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, pixel centres at *integer* coordinates (an ideal
``w x h`` camera has ``cx = (w - 1)/2``); the ray through pixel ``(x, y)`` is
``K⁻¹ (x, y, 1)``, evaluated as ``y' = (y - cy)/fy``, ``x' = (x - cx - s y')/fx`` (the form
kornia's ``unproject_points`` and OpenCV use). This module is the one home of the ideal ``K``
(:func:`ideal_intrinsics`, :func:`intrinsics_from_fov`), its rescaling (:func:`scale_intrinsics`)
and the pixel rays (:func:`pixel_rays`), for NumPy and torch alike. A camera orientation ``R``
maps camera-frame vectors to panorama-frame vectors (conventions §4):
``R = rotation_from_ypr(yaw, pitch, roll)`` looks at azimuth ``yaw`` and elevation ``pitch``.

NumPy images are ``(h, w[, C])``; torch images are ``(B, C, h, w)`` or ``(C, h, w)``, and the
torch functions are differentiable w.r.t. the images and ``R``.
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np

from solidkit.envmap.coords import direction_grid, module_namespace, namespace
from solidkit.envmap.resample import (
    cached_direction_grid,
    check_interp,
    is_torch,
    remap,
    sample_panorama,
    torch_remap,
    vecmat,
)
from solidkit.errors import InputError

__all__ = [
    "ideal_intrinsics",
    "intrinsics_from_fov",
    "scale_intrinsics",
    "scale_pixel_coordinates",
    "pixel_rays",
    "project_to_pixels",
    "rays_through_pixels",
    "perspective_crop",
    "embed_perspective",
]


def ideal_intrinsics(width: int, height: int, fx: float, fy: float | None = None) -> np.ndarray:
    """``K`` (3, 3) with focal lengths ``fx``, ``fy`` (px; ``fy = fx`` by default) and the principal point
    at the image centre ``((width - 1)/2, (height - 1)/2)`` (pixel centres at integers; conventions §1).

    Examples
    --------
    >>> ideal_intrinsics(640, 480, 500.0)
    array([[500. ,   0. , 319.5],
           [  0. , 500. , 239.5],
           [  0. ,   0. ,   1. ]])
    """
    fy = fx if fy is None else fy
    return np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def intrinsics_from_fov(fov: float, width: int, height: int) -> np.ndarray:
    """``K`` of an ideal ``width x height`` pinhole camera with horizontal field of view ``fov``.

    ``fov`` (radians, in ``(0, pi)``) spans the image edge to edge: ``fx = fy = (width / 2) / tan(fov / 2)``,
    ``cx = (width - 1) / 2``, ``cy = (height - 1) / 2`` (square pixels; conventions §1).
    Raises :class:`~solidkit.errors.InputError` for a field of view outside ``(0, pi)`` or an empty image.

    Examples
    --------
    >>> K = intrinsics_from_fov(math.radians(90.0), 320, 240)
    >>> float(K[0, 0]), float(K[0, 2]), float(K[1, 2])  # fx = 160 / tan(45°)
    (160.00000000000003, 159.5, 119.5)
    """
    if not 0.0 < float(fov) < math.pi:
        raise InputError(f"field of view must be in (0, 180) degrees, got {math.degrees(float(fov)):.4g}")
    if int(width) < 1 or int(height) < 1:
        raise InputError(f"image size must be positive, got {width}x{height}")
    return ideal_intrinsics(width, height, (width / 2.0) / math.tan(float(fov) / 2.0))


def scale_pixel_coordinates(x: Any, s: float) -> Any:
    """A pixel coordinate (centres at integers, conventions §1) after resizing the image by ``s``:
    ``(x + 0.5) s - 0.5``.

    The image edge at ``-0.5`` stays at ``-0.5``; works on scalars and arrays alike.

    Examples
    --------
    >>> scale_pixel_coordinates(319.5, 0.5)  # the centre of a 640-px row -> the centre of a 320-px row
    159.5
    """
    return (x + 0.5) * s - 0.5


def scale_intrinsics(K: Any, sx: float, sy: float | None = None) -> np.ndarray:
    """``K`` after resizing the image by ``(sx, sy)`` (``sy = sx`` by default).

    With pixel centres at integers the image edge is at ``-0.5``: ``f' = f s``, ``s' = s_skew sx``,
    ``c' = (c + 0.5) s - 0.5`` (:func:`scale_pixel_coordinates`), so that the same physical ray hits
    the same relative image position.

    Examples
    --------
    >>> scale_intrinsics(ideal_intrinsics(640, 480, 500.0), 0.5)[:2]  # the 320x240 camera
    array([[250. ,   0. , 159.5],
           [  0. , 250. , 119.5]])
    """
    sy = sx if sy is None else sy
    K2 = np.array(K, dtype=np.float64, copy=True)
    K2[0, 0] *= sx
    K2[0, 1] *= sx
    K2[1, 1] *= sy
    K2[0, 2] = scale_pixel_coordinates(K2[0, 2], sx)
    K2[1, 2] = scale_pixel_coordinates(K2[1, 2], sy)
    return K2


def _check_K(K: Any) -> None:
    if tuple(K.shape) != (3, 3):
        raise InputError(f"K must be a 3x3 intrinsics matrix, got shape {tuple(K.shape)}")


def pixel_rays(K: Any, width: int, height: int, xp: Any = np, **kw: Any) -> Any:
    """Camera-frame rays ``K⁻¹ (x, y, 1)`` through every pixel centre, ``(..., height, width, 3)`` (z = 1).

    ``K`` is ``(3, 3)`` or a batch ``(..., 3, 3)`` (any skew ``K[0, 1]``); ``xp`` is ``numpy``
    (default, float64) or ``torch`` (``kw``: ``dtype``, ``device``; differentiable w.r.t. ``K``).
    Evaluated as ``y' = (y - cy) / fy``, ``x' = (x - cx - s y') / fx``.

    Examples
    --------
    >>> K = ideal_intrinsics(4, 2, 2.0)
    >>> pixel_rays(K, 4, 2)[1, 3]  # pixel (x=3, y=1): ((3 - 1.5)/2, (1 - 0.5)/2, 1)
    array([0.75, 0.25, 1.  ])
    """
    ns = module_namespace(xp)
    kw.setdefault("dtype", xp.float64 if xp is np else xp.float32)
    K = ns.asarray(K, **kw)
    if tuple(K.shape[-2:]) != (3, 3):
        raise InputError(f"K must be a 3x3 intrinsics matrix (or a batch of them), got shape {tuple(K.shape)}")
    ys, xs = ns.meshgrid(ns.arange(height, **kw), ns.arange(width, **kw), indexing="ij")
    fx, s, cx = (K[..., 0, j][..., None, None] for j in range(3))
    fy, cy = K[..., 1, 1][..., None, None], K[..., 1, 2][..., None, None]
    y = (ys - cy) / fy
    x = (xs - cx - s * y) / fx
    return ns.stack([x, ns.broadcast_to(y, x.shape), ns.ones_like(x)], axis=-1)


def rays_through_pixels(K: Any, x: Any, y: Any) -> np.ndarray:
    """Camera-frame rays ``K⁻¹ (x, y, 1)`` through pixel points ``x, y`` (any equal shapes), ``(..., 3)`` (z = 1).

    The point form of :func:`pixel_rays` (same formula, skew included) and the inverse of
    :func:`project_to_pixels`; OpenCV pixel coordinates (centres at integers). NumPy, float64.

    Examples
    --------
    >>> K = ideal_intrinsics(4, 2, 2.0)
    >>> rays_through_pixels(K, np.array([3.0, 1.5]), np.array([1.0, 0.5]))
    array([[0.75, 0.25, 1.  ],
           [0.  , 0.  , 1.  ]])
    """
    K = np.asarray(K, np.float64)
    _check_K(K)
    y_ = (np.asarray(y, np.float64) - K[1, 2]) / K[1, 1]
    x_ = (np.asarray(x, np.float64) - K[0, 2] - K[0, 1] * y_) / K[0, 0]
    return np.stack([x_, y_, np.ones_like(x_)], axis=-1)


def project_to_pixels(K: Any, c: Any) -> tuple[Any, Any, Any]:
    """Pixel coordinates of camera-frame directions ``c (..., 3)``: ``K c / c_z``.

    Returns ``(x, y, in_front)``: OpenCV pixel coordinates (centres at integers) and a boolean
    mask of directions with ``c_z > 0``; behind the camera ``x, y`` are meaningless.

    Examples
    --------
    >>> K = ideal_intrinsics(640, 480, 500.0)
    >>> x, y, front = project_to_pixels(K, np.array([[0.0, 0.0, 1.0], [0.1, -0.2, 1.0], [0.0, 0.0, -1.0]]))
    >>> x[:2], y[:2], front
    (array([319.5, 369.5]), array([239.5, 139.5]), array([ True,  True, False]))
    """
    xp = namespace(c)
    p = vecmat(c, xp.asarray(K, dtype=c.dtype, **({"device": c.device} if is_torch(c) else {})).T)
    z = p[..., 2]
    in_front = c[..., 2] > 1e-12
    safe = xp.where(in_front, z, xp.ones_like(z))
    return p[..., 0] / safe, p[..., 1] / safe, in_front


def _intrinsics(K: Any, fov: float | None, size: tuple[int, int]) -> np.ndarray:
    if (K is None) == (fov is None):
        raise InputError("give exactly one of K or fov")
    return intrinsics_from_fov(cast(float, fov), *size) if K is None else np.asarray(K)


def perspective_crop(
    pano: Any,
    R: Any,
    size: tuple[int, int],
    *,
    K: Any = None,
    fov: float | None = None,
    interp: str = "linear",
) -> Any:
    """Render the pinhole view of a panorama seen by a camera with orientation ``R``.

    Parameters
    ----------
    pano : ndarray (H, 2H[, C]) or tensor (B, C, H, 2H) / (C, H, 2H)
        Equirectangular panorama.
    R : array (3, 3), or for tensors also (B, 3, 3)
        Camera-to-panorama rotation, e.g. ``rotation_from_ypr(yaw, pitch, roll)``.
    size : (width, height)
        Output image size in pixels.
    K : array (3, 3), optional
        Intrinsics (OpenCV convention, conventions §1).
    fov : float, optional
        Horizontal field of view in radians (instead of ``K``): :func:`intrinsics_from_fov`.
    interp : {"nearest", "linear", "cubic"}

    Returns
    -------
    ndarray (height, width[, C]) or tensor (B, C, height, width) / (C, height, width).
    Pixel ``(x, y)`` shows the panorama in direction ``R K⁻¹ (x, y, 1)``.

    Examples
    --------
    >>> from solidkit.envmap.coords import rotation_from_ypr
    >>> pano = np.zeros((64, 128, 3), np.float32)
    >>> pano[:32] = 1.0  # bright sky, dark ground
    >>> photo = perspective_crop(pano, rotation_from_ypr(0.0, 0.0), (8, 6), fov=math.radians(90.0))
    >>> photo.shape
    (6, 8, 3)
    >>> photo[:, 0, 0]  # top rows see the sky, bottom rows the ground
    array([1., 1., 1., 0., 0., 0.], dtype=float32)
    """
    check_interp(interp)
    width, height = (int(s) for s in size)
    K = _intrinsics(K, fov, (width, height))
    if is_torch(pano):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        dtype = pano.dtype if pano.dtype in (torch.float32, torch.float64) else torch.float32
        Rt = torch.as_tensor(R, dtype=dtype, device=pano.device)
        rays = pixel_rays(K, width, height, torch, dtype=dtype, device=pano.device)
        if Rt.shape[-2:] != (3, 3) or Rt.ndim not in (2, 3):
            raise InputError(f"R must be (3, 3) or (B, 3, 3), got {tuple(Rt.shape)}")
        d = vecmat(rays, Rt.T if Rt.ndim == 2 else Rt.transpose(-1, -2)[:, None, None])
        return sample_panorama(pano, d, interp, per_item=Rt.ndim == 3)
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise InputError(f"R must be a 3x3 matrix, got shape {R.shape}")
    return sample_panorama(pano, pixel_rays(K, width, height) @ R.T, interp)


def embed_perspective(photo: Any, K: Any, R: Any, height: int, interp: str = "linear") -> tuple[Any, Any]:
    """Project a pinhole photo onto the sphere: the inverse of :func:`perspective_crop`.

    Parameters
    ----------
    photo : ndarray (h, w[, C]) or tensor (B, C, h, w) / (C, h, w)
    K : array (3, 3)
        The photo's intrinsics (OpenCV convention).
    R : array (3, 3), or for tensors also (B, 3, 3)
        Camera-to-panorama rotation.
    height : int
        Output panorama height ``H`` (width ``2H``).
    interp : {"nearest", "linear", "cubic"}

    Returns
    -------
    (pano, mask)
        ``pano``: ndarray (H, 2H[, C]) / tensor (B, C, H, 2H), zero outside the photo.
        ``mask``: coverage, 1 where the pixel centre's direction projects inside the photo
        (within ``[-0.5, w - 0.5] x [-0.5, h - 0.5]``, in front of the camera), else 0;
        ndarray (H, 2H) float32 / tensor (B, 1, H, 2H).

    Examples
    --------
    >>> photo = np.ones((6, 8, 3), np.float32)
    >>> pano, covered = embed_perspective(photo, intrinsics_from_fov(math.radians(90.0), 8, 6), np.eye(3), 16)
    >>> pano.shape, covered.shape
    ((16, 32, 3), (16, 32))
    >>> bool(covered[8, 16]), bool(covered[8, 0])  # forward is covered, backward is not
    (True, False)
    """
    check_interp(interp)
    height = int(height)
    if height < 1:
        raise InputError(f"panorama height must be >= 1, got {height}")
    if is_torch(photo):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        unbatched = photo.ndim == 3
        img = photo[None] if unbatched else photo
        dtype = img.dtype if img.dtype in (torch.float32, torch.float64) else torch.float32
        img = img.to(dtype)
        Rt = torch.as_tensor(R, dtype=dtype, device=img.device)
        d = direction_grid(height, torch, dtype=dtype, device=img.device)
        c = vecmat(d, Rt if Rt.ndim == 2 else Rt[:, None, None])  # Rᵀ d as row vectors
        c = c.expand(img.shape[0], *c.shape) if c.ndim == 3 else c
        x, y, front = project_to_pixels(torch.as_tensor(K, dtype=dtype), c)
        h, w = img.shape[-2:]
        inside = front & (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
        out = torch_remap(img, torch.where(inside, x, 0.0), torch.where(inside, y, 0.0), interp, "replicate")
        mask = inside[:, None].to(dtype)
        out = out * mask
        return (out[0], mask[0]) if unbatched else (out, mask)
    R = np.asarray(R, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    _check_K(K)
    if R.shape != (3, 3):
        raise InputError(f"R must be a 3x3 matrix, got shape {R.shape}")
    photo = np.asarray(photo)
    if photo.ndim not in (2, 3):
        raise InputError(f"photo must be (h, w) or (h, w, C), got shape {photo.shape}")
    h, w = photo.shape[:2]
    x, y, front = project_to_pixels(K, cached_direction_grid(height) @ R)
    inside = front & (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
    out = remap(photo, np.where(inside, x, 0.0), np.where(inside, y, 0.0), interp, "replicate")
    mask = inside.astype(np.float32)
    out = out * (mask if out.ndim == 2 else mask[..., None]).astype(out.dtype)
    return out, mask
