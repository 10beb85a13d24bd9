"""Geometry from normals and plane distances, and the panoramic forward warping (paper §4.2).

Frames (docs/conventions.md): the camera frame is OpenCV's (x right, y down, z forward); the
panorama frame is the gravity-aligned one, ``d_pano = R_cam d_cam`` with
``R_cam = rotation_from_ypr(0, pitch, roll)``. All lengths are metres.

- :func:`points_from_plane_distance`: ``P = -p / (v . n) v``, ``v = ((x - cx)/fx, (y - cy)/fy, 1)``
  (the plane ``n . P + p = 0``; a surface facing the camera has ``v . n < 0`` and ``p > 0``).
- :func:`probe_centres`: the 3D point of each query pixel moved ``offset`` (0.10 m) along its normal.
- :func:`forward_warp`: splats per-pixel values into an equirect panorama centred at a probe with a
  z-buffer (``scatter_reduce(amin)`` of the packed key ``depth << 32 | source index``: the nearest
  point wins each panorama pixel, ties go to the lower source index); unreached pixels are 0 and
  a mask marks the observed ones. Batched, any device; gradients flow to the warped values (not to
  the geometry, which only selects where they go).
"""

from __future__ import annotations

import torch

from solidkit.envmap.coords import coords_from_direction, rotation_from_ypr
from solidkit.envmap.perspective import pixel_rays
from solidkit.errors import InputError

__all__ = [
    "points_from_plane_distance",
    "camera_rotation",
    "sample_at_pixels",
    "probe_centres",
    "forward_warp",
    "warp_to_probes",
    "DEPTH_QUANTUM",
]

DEPTH_QUANTUM = 1e-4
"""Metres per z-buffer depth step (depths up to 2^31 steps, about 214 km, are distinguished)."""

_MAX_DEPTH_STEPS = (1 << 31) - 1


def points_from_plane_distance(
    normal: torch.Tensor, distance: torch.Tensor, K: torch.Tensor, min_cos: float = 1e-3
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-pixel 3D points ``P = -p / (v . n) v`` in the camera frame (paper §4.2).

    Parameters
    ----------
    normal : (B, 3, H, W) unit normals (camera frame).
    distance : (B, 1, H, W) plane distances ``p`` (metres).
    K : (B, 3, 3) intrinsics.
    min_cos : pixels whose plane is seen at grazing angle (``v . n / |v| > -min_cos``) are invalid.

    Returns
    -------
    points (B, 3, H, W) metres (invalid pixels hold 0) and valid (B, 1, H, W) bool.
    """
    b, _, h, w = normal.shape
    v = pixel_rays(K.to(normal.dtype), w, h, torch, dtype=normal.dtype, device=normal.device).movedim(
        -1, -3
    )  # (B,3,H,W)
    vn = (v * normal).sum(1, keepdim=True)
    cos = vn / v.norm(dim=1, keepdim=True)
    valid = (cos < -min_cos) & (distance > 0)
    safe = torch.where(valid, vn, -torch.ones_like(vn))
    points = torch.where(valid, -distance / safe * v, torch.zeros_like(v))
    return points, valid


def camera_rotation(pitch: torch.Tensor, roll: torch.Tensor) -> torch.Tensor:
    """``R_cam = rotation_from_ypr(0, pitch, roll)`` (radians), ``(B, 3, 3)``: camera -> panorama frame."""
    return rotation_from_ypr(torch.zeros_like(pitch), pitch, roll)


def sample_at_pixels(x: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Values of ``x (B, C, H, W)`` at the nearest pixel centres of ``pixels (B, N, 2)`` ``(x, y)``: ``(B, N, C)``."""
    b, c, h, w = x.shape
    ix = pixels[..., 0].round().long()
    iy = pixels[..., 1].round().long()
    if ((ix < 0) | (ix >= w) | (iy < 0) | (iy >= h)).any():
        raise InputError(f"probe pixel outside the {w}x{h} image")
    flat = x.reshape(b, c, h * w)
    idx = (iy * w + ix)[:, None, :].expand(-1, c, -1)
    return flat.gather(2, idx).transpose(1, 2)


def probe_centres(
    points: torch.Tensor, normal: torch.Tensor, pixels: torch.Tensor, offset: float = 0.10
) -> torch.Tensor:
    """Probe centres ``(B, N, 3)``: the point at each query pixel plus ``offset`` metres along its normal.

    ``points`` and ``normal`` are ``(B, 3, H, W)`` in one frame; ``pixels (B, N, 2)`` are image
    coordinates ``(x, y)`` (nearest pixel). The normal is oriented toward the camera side
    (``n . P <= 0``), as the plane-distance geometry implies.
    """
    p = sample_at_pixels(points, pixels)
    n = torch.nn.functional.normalize(sample_at_pixels(normal, pixels), dim=-1)
    n = torch.where((n * p).sum(-1, keepdim=True) > 0, -n, n)
    return p + offset * n


def forward_warp(
    values: torch.Tensor,
    points: torch.Tensor,
    centre: torch.Tensor,
    valid: torch.Tensor | None = None,
    height: int = 128,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward-warp per-pixel ``values`` into equirect panoramas seen from ``centre``, with a z-buffer.

    Parameters
    ----------
    values : (B, C, h, w) what to splat (image, shadow, ...).
    points : (B, 3, h, w) the pixels' 3D points, in the panorama frame (metres).
    centre : (B, 3) or (B, N, 3) panorama centres in the same frame; N panoramas per image.
    valid : (B, 1, h, w) bool, optional: pixels allowed to splat.
    height : panorama height ``H`` (width ``2H``).

    Returns
    -------
    warped (B, C, H, 2H) or (B, N, C, H, 2H), zeros where nothing lands, and the observed mask
    (same leading shape, 1 channel, float 0/1). Each panorama pixel receives the value of the
    nearest point projecting into it (ties: lowest source index).
    """
    squeeze = centre.dim() == 2
    if squeeze:
        centre = centre[:, None]
    b, c, h, w = values.shape
    n = centre.shape[1]
    W = 2 * height
    if points.shape != (b, 3, h, w):
        raise InputError(f"points must be (B, 3, {h}, {w}) to match values, got {tuple(points.shape)}")
    pts = points.detach().reshape(b, 1, 3, h * w).transpose(2, 3)  # (B, 1, P, 3)
    d = pts - centre.detach()[:, :, None, :]  # (B, N, P, 3)
    depth = d.norm(dim=-1)  # (B, N, P)
    x, y = coords_from_direction(d, height)
    u = x.floor().long().clamp(0, W - 1)
    v = y.floor().long().clamp(0, height - 1)
    ok = depth > 0
    if valid is not None:
        ok = ok & valid.reshape(b, 1, h * w)
    steps = (depth / DEPTH_QUANTUM).round().clamp(0, _MAX_DEPTH_STEPS).long()
    src = torch.arange(h * w, device=values.device).expand(b, n, -1)
    key = (steps << 32) | src
    sentinel = torch.iinfo(torch.int64).max
    key = torch.where(ok, key, torch.full_like(key, sentinel))
    bn = torch.arange(b * n, device=values.device).view(b, n, 1)
    target = (bn * (height * W) + v * W + u).reshape(-1)
    buf = torch.full((b * n * height * W,), sentinel, dtype=torch.int64, device=values.device)
    buf.scatter_reduce_(0, target, key.reshape(-1), reduce="amin", include_self=True)
    hit = buf != sentinel
    winner = torch.where(hit, buf & 0xFFFFFFFF, torch.zeros_like(buf)).view(b, n, height * W)
    flat = values.reshape(b, 1, c, h * w).expand(-1, n, -1, -1)
    warped = flat.gather(3, winner[:, :, None, :].expand(-1, -1, c, -1))
    mask = hit.view(b, n, 1, height * W).to(values.dtype)
    warped = (warped * mask).view(b, n, c, height, W)
    mask = mask.view(b, n, 1, height, W)
    if squeeze:
        return warped[:, 0], mask[:, 0]
    return warped, mask


def warp_to_probes(
    values: torch.Tensor,
    normal: torch.Tensor,
    distance: torch.Tensor,
    K: torch.Tensor,
    pixels: torch.Tensor,
    pitch: torch.Tensor,
    roll: torch.Tensor,
    height: int = 128,
    offset: float = 0.10,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The whole panoramic warping of §4.2 for ``N`` query pixels per image.

    Reprojects the pixels with ``normal``/``distance`` (camera frame) and ``K``, rotates them into
    the panorama frame with the camera pitch/roll, places a probe at each query pixel's point
    moved ``offset`` along its normal, and forward-warps ``values (B, C, h, w)``.

    Returns ``(warped (B, N, C, H, 2H), mask (B, N, 1, H, 2H), centres (B, N, 3))``; centres are in
    the panorama frame, relative to the camera.
    """
    points, valid = points_from_plane_distance(normal, distance, K)
    R = camera_rotation(pitch.to(points.dtype), roll.to(points.dtype))  # (B, 3, 3)
    b, _, h, w = points.shape
    pts = (R @ points.reshape(b, 3, h * w)).reshape(b, 3, h, w)
    nrm = (R @ normal.reshape(b, 3, h * w)).reshape(b, 3, h, w)
    centres = probe_centres(pts, nrm, pixels, offset)
    warped, mask = forward_warp(values, pts, centres, valid, height)
    return warped, mask, centres
