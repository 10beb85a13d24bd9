"""Resampling equirectangular panoramas: sampling at directions, rotation, energy-preserving resizing.

Every sampling coordinate comes from :mod:`solidkit.envmap.coords` (conventions §3-4); the two
back-ends differ only in the interpolation kernel call:

* **NumPy / OpenCV** (large images in the pipeline): images are ``(H, W)`` or ``(H, W, C)``,
  sampled with ``cv2.remap`` (float32 maps).
* **torch** (batches for the model; any device; differentiable w.r.t. the image *and* the
  rotation): images are ``(B, C, H, W)`` or ``(C, H, W)``, sampled with
  ``torch.nn.functional.grid_sample(align_corners=False)``.

Seam and poles. Before sampling, the panorama is padded by :func:`pad_panorama`: ``pad``
wrapped columns on the left and right (the ±180° seam), and ``pad`` rows above the top and
below the bottom that continue the image *across the pole*: the row ``k`` pixels beyond the
pole is row ``k - 1`` inside it, mirrored vertically and shifted by ``W/2`` (the pixel on the
other side of the pole). Interpolation near the seam or a pole therefore mixes the true
spherical neighbours, instead of clamping (skylibs) or mixing one padded row (py360convert).
The padded image is sampled with a constant (zero) border that is never reached.

Pixel centres. Panorama pixel ``(u, v)`` has its centre at continuous coordinates
``(u + 0.5, v + 0.5)`` (conventions §3). ``cv2.remap`` puts pixel centres at integers, so a
continuous coordinate ``x`` of the padded image is map value ``x - 0.5``; ``grid_sample`` with
``align_corners=False`` spans the image edges, so ``x`` is grid value ``2 x / W_padded - 1``.

Building blocks :mod:`solidkit.envmap.perspective` and :mod:`solidkit.envmap.cubemap` sample with
too (outside ``__all__``: not part of the envmap API): :func:`is_torch`, :func:`vecmat`,
:func:`check_interp`, :func:`panorama_height`, :func:`remap` / :func:`torch_remap` (one kernel
call per back-end), :func:`blockwise_maps` / :func:`cv2_maps` (float32 ``cv2.remap`` maps) and
:func:`cached_direction_grid`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

from solidkit.envmap.coords import (
    angles_from_coords,
    coords_from_direction,
    direction_grid,
    module_namespace,
    solid_angle,
)
from solidkit.errors import InputError, PanoramaError

__all__ = [
    "INTERPOLATIONS",
    "pad_panorama",
    "sample_image",
    "sample_panorama",
    "rotate",
    "downsample",
    "resize",
]

#: Interpolation names accepted by every resampling function.
INTERPOLATIONS = ("nearest", "linear", "cubic")
_CV2_INTERP = {"nearest": cv2.INTER_NEAREST, "linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
_TORCH_INTERP = {"nearest": "nearest", "linear": "bilinear", "cubic": "bicubic"}
#: Padding used for sampling: bicubic reads 2 pixels on each side of a sample.
PAD = 2
# cv2.remap asserts that the source and destination sides are below SHRT_MAX.
_CV2_MAX_SIDE = 32767
_CV2_ROW = 4096


def is_torch(x: Any) -> bool:
    """True for a torch tensor (without importing torch)."""
    return type(x).__module__.startswith("torch")


def vecmat(v: Any, M: Any) -> Any:
    """Row vectors times matrices, ``v (..., 3) @ M (..., 3, 3)`` with broadcasting, as 3 fused
    element-wise terms: tiny torch matmuls stall on a busy multi-threaded CPU, this never does."""
    return v[..., 0:1] * M[..., 0, :] + v[..., 1:2] * M[..., 1, :] + v[..., 2:3] * M[..., 2, :]


def check_interp(interp: str) -> None:
    """:class:`~solidkit.errors.InputError` unless ``interp`` is one of :data:`INTERPOLATIONS`."""
    if interp not in INTERPOLATIONS:
        raise InputError(f"unknown interpolation '{interp}'; expected one of {', '.join(INTERPOLATIONS)}")


def panorama_height(pano: Any) -> int:
    """Height of a NumPy ``(H, W[, C])`` or torch ``(..., C, H, W)`` panorama; checks ``W = 2H``."""
    if is_torch(pano):
        if pano.ndim < 3:
            raise PanoramaError(f"torch panoramas are (B, C, H, W) or (C, H, W); got shape {tuple(pano.shape)}")
        h, w = pano.shape[-2:]
    else:
        if pano.ndim not in (2, 3):
            raise PanoramaError(f"NumPy panoramas are (H, W) or (H, W, C); got shape {pano.shape}")
        h, w = pano.shape[:2]
    if w != 2 * h:
        raise PanoramaError(f"not an equirectangular panorama: {w}x{h} (width must be 2 x height)")
    return int(h)


def pad_panorama(pano: Any, pad: int = PAD) -> Any:
    """Pad a panorama with its spherical neighbours (seam wrap and pole crossing).

    Parameters
    ----------
    pano : ndarray (H, W[, C]) or tensor (..., C, H, W)
        Equirectangular panorama, ``W = 2H`` (even).
    pad : int
        Pixels added on every side, ``0 <= pad <= H``.

    Returns
    -------
    Same type, ``(H + 2 pad, W + 2 pad[, C])`` or ``(..., C, H + 2 pad, W + 2 pad)``.
    Row ``-1 - k`` (above the top) is row ``k`` shifted by ``W/2`` columns, and likewise below
    the bottom; columns wrap around. Differentiable for tensors.

    Examples
    --------
    >>> pano = np.arange(8.0).reshape(2, 4, 1) * np.ones(3)
    >>> padded = pad_panorama(pano, 1)
    >>> padded.shape
    (4, 6, 3)
    >>> padded[1, :, 0]  # the row wraps around the seam
    array([3., 0., 1., 2., 3., 0.])
    """
    h = panorama_height(pano)
    if not 0 <= pad <= h:
        raise InputError(f"pad must be in [0, {h}], got {pad}")
    if pad == 0:
        return pano
    if is_torch(pano):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        xp, rows, cols = module_namespace(torch), -2, -1

        def idx(a: int, b: int) -> Any:
            return torch.arange(a, b, device=pano.device)
    else:
        xp, rows, cols = module_namespace(np), 0, 1

        def idx(a: int, b: int) -> Any:
            return np.arange(a, b)

    w = 2 * h
    # across a pole: padded row -1-k is row k, shifted by W/2 (likewise below the bottom)
    top = xp.roll(xp.flip(xp.take(pano, idx(0, pad), axis=rows), axis=rows), w // 2, axis=cols)
    bottom = xp.roll(xp.flip(xp.take(pano, idx(h - pad, h), axis=rows), axis=rows), w // 2, axis=cols)
    tall = xp.concat([top, pano, bottom], axis=rows)
    # across the seam: columns wrap
    left = xp.take(tall, idx(w - pad, w), axis=cols)
    right = xp.take(tall, idx(0, pad), axis=cols)
    return xp.concat([left, tall, right], axis=cols)


def remap(
    img: np.ndarray,
    map_x: np.ndarray,
    map_y: np.ndarray,
    interp: str,
    border: str = "constant",
    border_value: float = 0.0,
) -> np.ndarray:
    """``cv2.remap`` for maps of any shape ``(...)``; returns ``(..., [C])``.

    Map values are OpenCV pixel coordinates (pixel centres at integers). ``border`` is
    ``"constant"`` (``border_value``) or ``"replicate"``.
    """
    shape = map_x.shape
    if max(img.shape[:2]) >= _CV2_MAX_SIDE:
        raise InputError(f"image side {max(img.shape[:2])} too large for cv2.remap (max {_CV2_MAX_SIDE - 1})")
    if not (len(shape) == 2 and max(shape) < _CV2_MAX_SIDE and min(shape) > 0):
        n = int(np.prod(shape))
        rows = max(1, -(-n // _CV2_ROW))
        pad = rows * _CV2_ROW - n
        map_x = np.concatenate([map_x.reshape(-1), np.zeros(pad, map_x.dtype)]).reshape(rows, _CV2_ROW)
        map_y = np.concatenate([map_y.reshape(-1), np.zeros(pad, map_y.dtype)]).reshape(rows, _CV2_ROW)
    dtype = img.dtype
    work = img.astype(np.float32) if dtype == np.float16 else img
    out = cv2.remap(
        work,
        np.ascontiguousarray(map_x, dtype=np.float32),
        np.ascontiguousarray(map_y, dtype=np.float32),
        _CV2_INTERP[interp],
        borderMode=cv2.BORDER_REPLICATE if border == "replicate" else cv2.BORDER_CONSTANT,
        borderValue=border_value,
    )
    if img.ndim == 3 and out.ndim == 2:  # cv2 drops a trailing channel axis of size 1
        out = out[..., None]
    out = out.reshape(-1, *img.shape[2:])[: int(np.prod(shape))]
    return out.reshape(*shape, *img.shape[2:]).astype(dtype, copy=False)


def sample_image(
    image: np.ndarray, x: Any, y: Any, interp: str = "linear", *, border: str = "constant", border_value: float = 0.0
) -> np.ndarray:
    """Samples of an image ``(H, W[, C])`` at pixel coordinates ``x, y`` of any (equal) shape ``(...)``.

    Coordinates are OpenCV's (pixel centres at integers; conventions §1); ``interp`` is one of
    :data:`INTERPOLATIONS`; outside the image the value is ``border_value`` (``border="constant"``,
    e.g. ``np.nan`` to mark such samples) or the nearest edge pixel (``"replicate"``). Returns
    ``(..., [C])`` in the image's dtype (``cv2.remap``, any number of points).

    Examples
    --------
    >>> img = np.array([[0.0, 1.0], [2.0, 3.0]], dtype=np.float32)
    >>> sample_image(img, np.array([0.5, 5.0]), np.array([0.5, 0.0]), border_value=np.nan)
    array([1.5, nan], dtype=float32)
    """
    check_interp(interp)
    x, y = np.asarray(x, dtype=np.float32), np.asarray(y, dtype=np.float32)
    if x.shape != y.shape:
        raise InputError(f"x and y must have one shape, got {x.shape} and {y.shape}")
    return remap(np.asarray(image), x, y, interp, border, border_value)


def _padded_coords(directions: Any, height: int, pad: int) -> tuple[Any, Any]:
    """Continuous coordinates of ``directions`` in the padded panorama (conventions §3)."""
    x, y = coords_from_direction(directions, height)
    return x + pad, y + pad


def sample_panorama(pano: Any, directions: Any, interp: str = "linear", *, per_item: bool | None = None) -> Any:
    """Radiance of a panorama in arbitrary directions (interpolated, seam- and pole-aware).

    Parameters
    ----------
    pano : ndarray (H, W[, C]) or tensor (B, C, H, W) / (C, H, W)
        Equirectangular panorama (conventions §3).
    directions : array (..., 3)
        Directions in the panorama frame (need not be unit).
    per_item : bool, optional
        Tensors only: ``True`` when ``directions`` is ``(B, ..., 3)``, one set per batch item;
        ``False`` when one ``(..., 3)`` set is shared by the batch. Default: per item when
        ``directions.ndim >= 3`` and its first axis equals ``B``.
    interp : {"nearest", "linear", "cubic"}
        Interpolation kernel (cubic: Keys a = -0.75 in both back-ends; it can overshoot).

    Returns
    -------
    ndarray (..., [C]) for NumPy input; tensor (B, C, ...) / (C, ...) for torch input.

    Examples
    --------
    >>> import math
    >>> pano = np.zeros((32, 64, 3), np.float32)
    >>> pano[:, 48:] = 1.0  # the right quarter (azimuth 90-180°)
    >>> d = np.array([[1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]]) / math.sqrt(2.0)  # azimuth 45° and -45°
    >>> sample_panorama(pano, d)[:, 0]
    array([0., 0.], dtype=float32)
    >>> sample_panorama(pano, np.array([[1.0, 0.0, -1.0]]) / math.sqrt(2.0))[:, 0]  # azimuth 135°
    array([1.], dtype=float32)
    """
    check_interp(interp)
    h = panorama_height(pano)
    if is_torch(pano):
        return _sample_torch(pano, directions, h, interp, per_item)
    directions = np.asarray(directions, dtype=np.float64)
    if directions.shape[-1:] != (3,) or directions.ndim < 1:
        raise InputError(f"directions must have shape (..., 3), got {directions.shape}")
    rows = directions if directions.ndim > 1 else directions[None]
    map_x, map_y = cv2_maps(lambda a, b: rows[a:b], rows.shape[:-1], h)
    return remap(pad_panorama(pano, PAD), map_x, map_y, interp).reshape(*directions.shape[:-1], *pano.shape[2:])


def blockwise_maps(
    maps_rows: Callable[[int, int], tuple[np.ndarray, np.ndarray]], shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``cv2.remap`` maps of ``shape``, computed by ``maps_rows(a, b)`` for rows ``a:b``.

    The rows are processed in blocks of ~64k pixels (temporaries stay in cache) spread over a
    few threads (NumPy releases the GIL); each block is computed in float64, then rounded.
    """
    map_x = np.empty(shape, np.float32)
    map_y = np.empty(shape, np.float32)
    n = shape[0]
    block = max(1, (1 << 16) // max(1, int(np.prod(shape[1:]))))

    def work(a: int) -> None:
        map_x[a : a + block], map_y[a : a + block] = maps_rows(a, min(a + block, n))

    starts = range(0, n, block)
    workers = min(os.cpu_count() or 1, 8, len(starts))
    if workers > 1:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(work, starts))
    else:
        for a in starts:
            work(a)
    return map_x, map_y


def cv2_maps(
    direction_rows: Callable[[int, int], np.ndarray], shape: tuple[int, ...], height: int
) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``cv2.remap`` maps into the ``PAD``-padded panorama for directions of ``shape + (3,)``.

    ``direction_rows(a, b)`` returns the directions of rows ``a:b`` (float64). Computed in
    float64, so a yaw by whole pixels gives exactly integral map values.
    """

    def maps_rows(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        x, y = _padded_coords(direction_rows(a, b), height, PAD)
        return x - 0.5, y - 0.5  # pixel centres: continuous x <-> cv2 x - 0.5

    return blockwise_maps(maps_rows, shape)


def _sample_torch(pano: Any, directions: Any, height: int, interp: str, per_item: bool | None) -> Any:
    import torch  # lazy: only torch inputs need it (NumPy users never import torch)

    unbatched = pano.ndim == 3
    if pano.ndim not in (3, 4):
        raise PanoramaError(f"torch panoramas are (B, C, H, W) or (C, H, W); got shape {tuple(pano.shape)}")
    img = pano[None] if unbatched else pano
    b = img.shape[0]
    dtype = img.dtype if img.dtype in (torch.float32, torch.float64) else torch.float32
    d = torch.as_tensor(directions, dtype=dtype, device=img.device)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise InputError(f"directions must have shape (..., 3), got {tuple(d.shape)}")
    if per_item is None:
        per_item = not unbatched and d.ndim >= 3 and d.shape[0] == b
    if per_item and (unbatched or d.ndim < 2 or d.shape[0] != b):
        raise InputError(f"per-item directions must be (B={b}, ..., 3), got {tuple(d.shape)}")
    x, y = _padded_coords(d, height, PAD)
    if not per_item:
        x, y = x.expand(b, *x.shape), y.expand(b, *y.shape)
    out = torch_remap(pad_panorama(img.to(dtype), PAD), x - 0.5, y - 0.5, interp)
    return out[0] if unbatched else out


def torch_remap(img: Any, x: Any, y: Any, interp: str, border: str = "constant") -> Any:
    """``grid_sample`` at OpenCV pixel coordinates (centres at integers), the torch twin of :func:`remap`.

    ``img (B, C, Hi, Wi)``, ``x, y (B, ...)``; returns ``(B, C, ...)``. ``align_corners=False``
    spans the pixel edges: OpenCV coordinate ``x`` is grid value ``2 (x + 0.5) / Wi - 1``.
    """
    import torch  # lazy: only torch inputs need it (NumPy users never import torch)
    import torch.nn.functional as F  # lazy, as above

    grid = torch.stack([2 * (x + 0.5) / img.shape[-1] - 1, 2 * (y + 0.5) / img.shape[-2] - 1], dim=-1)
    b, spatial = grid.shape[0], grid.shape[1:-1]
    out = F.grid_sample(
        img,
        grid.reshape(b, -1, 1, 2).to(img.dtype),
        mode=_TORCH_INTERP[interp],
        padding_mode="border" if border == "replicate" else "zeros",
        align_corners=False,
    )
    return out.reshape(b, img.shape[1], *spatial)


@lru_cache(maxsize=2)
def cached_direction_grid(height: int) -> np.ndarray:
    """:func:`~solidkit.envmap.coords.direction_grid` of ``height`` ``(H, 2H, 3)``, read-only (the last two
    heights cached)."""
    grid: np.ndarray = direction_grid(height)
    grid.setflags(write=False)
    return grid


def rotate(pano: Any, R: Any, interp: str = "linear", height: int | None = None) -> Any:
    """Rotate a panorama by a 3x3 rotation ``R`` (conventions §4).

    The content seen in direction ``d`` moves to direction ``R d``: ``out(d) = in(Rᵀ d)``.
    With ``R = rotation_from_ypr(yaw, 0, 0)`` the image content moves ``yaw`` to the right
    (azimuth increases); a yaw that is a multiple of the pixel pitch ``2 pi / W`` is an exact
    column roll (NumPy path).

    Parameters
    ----------
    pano : ndarray (H, W[, C]) or tensor (B, C, H, W) / (C, H, W)
        Equirectangular panorama.
    R : array (3, 3), or for tensors also (B, 3, 3)
        Rotation matrix acting on column vectors (``rotation_from_ypr``). For tensors the
        result is differentiable w.r.t. both ``pano`` and ``R``.
    interp : {"nearest", "linear", "cubic"}
        Interpolation (``cv2.INTER_*`` / ``grid_sample`` modes). Cubic may overshoot: HDR
        images can get small negative values next to very bright pixels.
    height : int, optional
        Output height (width ``2 height``); default: the input's.

    Returns
    -------
    Same type and layout as ``pano``, ``(height, 2 height)`` spatially.

    Examples
    --------
    >>> import math
    >>> from solidkit.envmap.coords import rotation_y
    >>> pano = np.zeros((32, 64, 1), np.float32)
    >>> pano[16, 32] = 1.0  # forward, at the horizon
    >>> turned = rotate(pano, rotation_y(math.pi / 2))  # content moves 90° to the right
    >>> tuple(int(i) for i in np.unravel_index(int(np.argmax(turned)), turned.shape)[:2])  # row 16, column 48
    (16, 48)
    """
    check_interp(interp)
    h = panorama_height(pano)
    out_h = h if height is None else int(height)
    if out_h < 1:
        raise InputError(f"output height must be >= 1, got {height}")
    if is_torch(pano):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        dtype = pano.dtype if pano.dtype in (torch.float32, torch.float64) else torch.float32
        Rt = torch.as_tensor(R, dtype=dtype, device=pano.device)
        if Rt.shape[-2:] != (3, 3):
            raise InputError(f"R must be (3, 3) or (B, 3, 3), got {tuple(Rt.shape)}")
        d = direction_grid(out_h, torch, dtype=dtype, device=pano.device)
        # row vectors times R = (Rᵀ d)ᵀ; (B, 3, 3) -> (B, H, W, 3)
        src = vecmat(d, Rt if Rt.ndim == 2 else Rt[:, None, None])
        if Rt.ndim == 3 and pano.ndim == 3:
            raise InputError("a batch of rotations needs a batched (B, C, H, W) panorama")
        return sample_panorama(pano, src, interp, per_item=Rt.ndim == 3)
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise InputError(f"R must be a 3x3 matrix for NumPy panoramas, got shape {R.shape}")
    grid = cached_direction_grid(out_h)
    map_x, map_y = cv2_maps(lambda a, b: grid[a:b] @ R, grid.shape[:-1], h)
    return remap(pad_panorama(pano, PAD), map_x, map_y, interp)


# ----------------------------------------------------------------------------------------
# Energy-preserving resizing
# ----------------------------------------------------------------------------------------


def _row_solid_angles(height: int) -> np.ndarray:
    return np.asarray(solid_angle(height))[:, 0]


def downsample(pano: Any, factor: int) -> Any:
    """Integer-factor area downsampling that preserves ``sum(radiance x solid angle)`` exactly.

    Each output pixel is the *solid-angle-weighted* mean of the ``factor x factor`` input
    pixels it covers (rows near the poles subtend less solid angle than rows near the
    horizon, so a plain box filter over-weights them). Since the output pixel's solid angle
    is exactly the sum of its input pixels' (conventions §3), the radiance integral
    ``sum L Omega`` is unchanged up to floating-point rounding (computed in float64).

    Parameters
    ----------
    pano : ndarray (H, W[, C]) or tensor (..., C, H, W)
        Equirectangular panorama; ``H`` must be divisible by ``factor``.
    factor : int
        Downsampling factor (>= 1).

    Returns
    -------
    Same type/layout and dtype, ``(H / factor, W / factor)`` spatially. Differentiable for tensors.

    Examples
    --------
    >>> from solidkit.envmap.coords import solid_angle
    >>> pano = np.random.default_rng(0).random((64, 128, 3)).astype(np.float32)
    >>> small = downsample(pano, 4)
    >>> small.shape
    (16, 32, 3)
    >>> integral = lambda p: (p * solid_angle(p.shape[0])[..., None]).sum(axis=(0, 1))
    >>> bool(np.allclose(integral(small), integral(pano), rtol=1e-5))
    True
    """
    h = panorama_height(pano)
    factor = int(factor)
    if factor < 1 or h % factor:
        raise InputError(f"downsampling factor must be >= 1 and divide the height {h}, got {factor}")
    if factor == 1:
        return pano
    ho, wo = h // factor, 2 * h // factor
    omega = _row_solid_angles(h)
    weight = omega / np.repeat(omega.reshape(ho, factor).sum(1), factor) / factor  # sums to 1 per block
    if is_torch(pano):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        x = pano.to(torch.float64) if pano.dtype != torch.float64 else pano
        wt = torch.as_tensor(weight, dtype=torch.float64, device=pano.device)
        x = (x * wt[:, None]).reshape(*x.shape[:-2], ho, factor, wo, factor).sum(dim=(-3, -1))
        return x.to(pano.dtype)
    x = np.asarray(pano, dtype=np.float64)
    x = x * weight.reshape(h, *([1] * (x.ndim - 1)))
    x = x.reshape(ho, factor, wo, factor, *x.shape[2:]).sum(axis=(1, 3))
    return x.astype(pano.dtype if np.issubdtype(pano.dtype, np.floating) else np.float32)


def _overlap_weights(edges_in: np.ndarray, edges_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact box-overlap resampling weights between two partitions of the same interval.

    Returns ``(idx, w)``, both ``(n_out, k)``: output cell ``o`` is ``sum_j w[o, j] x[idx[o, j]]``
    with ``w[o, j] = |cell_in(idx[o, j]) ∩ cell_out(o)| / |cell_out(o)|`` (zero-padded to ``k``).
    """
    n_out = len(edges_out) - 1
    first = np.clip(np.searchsorted(edges_in, edges_out[:-1], side="right") - 1, 0, len(edges_in) - 2)
    last = np.clip(np.searchsorted(edges_in, edges_out[1:], side="left") - 1, 0, len(edges_in) - 2)
    k = int((last - first).max()) + 1
    idx = np.minimum(first[:, None] + np.arange(k)[None], len(edges_in) - 2)
    lo = np.maximum(edges_in[idx], edges_out[:-1, None])
    hi = np.minimum(edges_in[idx + 1], edges_out[1:, None])
    w = np.clip(hi - lo, 0.0, None) * (np.arange(k)[None] <= (last - first)[:, None])
    w /= (edges_out[1:] - edges_out[:-1])[:, None]
    assert w.shape == (n_out, k)
    return idx, w


def _apply_weights(x: Any, idx: np.ndarray, w: np.ndarray, axis: int) -> Any:
    """``out[.., o, ..] = sum_j w[o, j] x[.., idx[o, j], ..]`` along ``axis`` (NumPy or torch)."""
    torch_in = is_torch(x)
    if torch_in:
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        idx_t = torch.as_tensor(idx, device=x.device)
        w_t = torch.as_tensor(w, dtype=x.dtype, device=x.device)
    shape = [1] * x.ndim
    shape[axis] = idx.shape[0]
    out = 0
    for j in range(idx.shape[1]):
        if torch_in:
            term = x.index_select(axis, idx_t[:, j]) * w_t[:, j].reshape(shape)
        else:
            term = np.take(x, idx[:, j], axis=axis) * w[:, j].reshape(shape)
        out = out + term
    return out


def resize(pano: Any, height: int) -> Any:
    """Resize a panorama to ``(height, 2 height)`` preserving the radiance integral exactly.

    Exact area (conservative) resampling on the sphere: each output pixel is the
    solid-angle-weighted mean of the radiance over its footprint, treating every input pixel
    as constant over its own footprint. An equirect pixel is a rectangle in
    ``(azimuth, sin(elevation))``, whose area *is* its solid angle, so the overlaps are
    separable: a 1-D box-overlap along azimuth and one along ``sin(elevation)``. Consequently
    ``sum(out * Omega_out) == sum(in * Omega_in)`` up to floating-point rounding (float64
    arithmetic: relative error ~1e-15, ~1e-7 after casting back to float32), for any output
    height, down or up. Upsampling replicates pixels (piecewise constant), it does not
    interpolate. For integer factors this equals :func:`downsample`.

    Parameters
    ----------
    pano : ndarray (H, W[, C]) or tensor (..., C, H, W)
    height : int
        Output height ``>= 1``.

    Returns
    -------
    Same type/layout and dtype. Differentiable for tensors.

    Examples
    --------
    >>> sky = np.random.default_rng(1).random((64, 128, 1)).astype(np.float32)
    >>> resize(sky, 24).shape  # 24 does not divide 64: overlapping rows and columns are weighted
    (24, 48, 1)
    >>> bool(np.allclose(resize(sky, 16), downsample(sky, 4), atol=1e-6))  # a divisor: area downsampling
    True
    """
    h = panorama_height(pano)
    height = int(height)
    if height < 1:
        raise InputError(f"output height must be >= 1, got {height}")
    # edges in azimuth and in -sin(elevation) (increasing down the image), from coords
    phi_in = angles_from_coords(np.arange(2 * h + 1, dtype=np.float64), 0.0, h)[0]
    phi_out = angles_from_coords(np.arange(2 * height + 1, dtype=np.float64), 0.0, height)[0]
    s_in = -np.sin(angles_from_coords(0.0, np.arange(h + 1, dtype=np.float64), h)[1])
    s_out = -np.sin(angles_from_coords(0.0, np.arange(height + 1, dtype=np.float64), height)[1])
    s_in[0], s_in[-1], s_out[0], s_out[-1] = -1.0, 1.0, -1.0, 1.0
    phi_out[0], phi_out[-1] = phi_in[0], phi_in[-1]
    rows = _overlap_weights(s_in, s_out)
    cols = _overlap_weights(phi_in, phi_out)
    if is_torch(pano):
        import torch  # lazy: only torch inputs need it (NumPy users never import torch)

        x = pano.to(torch.float64)
        x = _apply_weights(_apply_weights(x, *rows, axis=x.ndim - 2), *cols, axis=x.ndim - 1)
        return x.to(pano.dtype)
    x = np.asarray(pano, dtype=np.float64)
    x = _apply_weights(_apply_weights(x, *rows, axis=0), *cols, axis=1)
    return x.astype(pano.dtype if np.issubdtype(pano.dtype, np.floating) else np.float32)
