"""The sun in the image itself: a sun-like saturated blob, and the network's sun put on it.

A sun in the field of view is the easiest case for a person and the one a network trained at 96 x 128
gets only roughly (its in-image term sees ~2° per pixel and its soft-argmax blends neighbouring modes).
The photometric cue is direct: the sun is many stops brighter than anything else outdoors, so in any
exposure that keeps the scene visible it is a compact clipped blob, whose centroid's ray is the sun's
direction to a fraction of its apparent size (Hold-Geoffroy et al. 2017 label the sun of SUN360 the same
way, from the brightest blob of each panorama).

The blob alone is not a sun detector (a white wall, a glint, a street lamp clip too), so the network
decides whether a sun is visible and roughly where; :func:`put_sun_on_blob` then moves its direction onto
the most sun-like blob within ``gate_deg`` of it. Sizes are angles, so the rule is the same at every image
size and field of view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from solidkit.envmap.coords import coords_from_direction, rotation_from_ypr
from solidkit.envmap.perspective import rays_through_pixels

__all__ = [
    "BlobSun",
    "image_sun_blobs",
    "put_sun_on_blob",
    "CLIP_LEVEL",
    "MAX_RADIUS_DEG",
    "MIN_INSCRIBED_DEG",
    "MIN_FILL",
    "GATE_DEG",
    "LOGIT_MARGIN",
]

CLIP_LEVEL = 0.98
"""Tonemapped value (mean of R, G, B, in [0, 1]) at or above which a pixel counts as clipped."""
MAX_RADIUS_DEG = 10.0
"""Largest equivalent radius (degrees) of a sun blob: the disc (0.27°) plus the clipped glow of a clear sky
(5-7° in metered crops of real clear-sky panoramas)."""
MIN_INSCRIBED_DEG = 0.5
"""Smallest radius (degrees) of the largest disc inside a sun blob: sparkles, stars and distant lamps clip a
pixel or two (~0.2° at 60° over 320 px)."""
MIN_FILL = 0.3
"""Smallest ``area / (pi r_max^2)`` of a sun blob (a disc is 1, a disc cut in half by the image edge ~0.45;
a sky strip along a roofline is far less)."""
GATE_DEG = 60.0
"""The network's sun moves onto a small blob only within this angle of its own direction."""
LOGIT_MARGIN = 1.0
"""...or where the network's own logit at the blob is within this of its highest logit (its distribution
finds the blob nearly as likely as its mode, though its soft-argmax lies elsewhere)."""


@dataclass(frozen=True)
class BlobSun:
    """A sun-like blob: unit ``direction (3,)`` in the camera's level panorama frame, its equivalent
    ``radius_deg``, ``inscribed_deg`` (radius of the largest disc inside it), ``fill`` and ``area`` (pixels)."""

    direction: np.ndarray
    radius_deg: float
    inscribed_deg: float
    fill: float
    area: int


def image_sun_blobs(
    image: np.ndarray,
    K: np.ndarray,
    pitch: float,
    roll: float,
    *,
    level: float = CLIP_LEVEL,
    max_radius_deg: float = MAX_RADIUS_DEG,
    min_inscribed_deg: float = MIN_INSCRIBED_DEG,
    min_fill: float = MIN_FILL,
) -> list[BlobSun]:
    """Sun-like saturated blobs of ``image (H, W, 3)`` (tonemapped, [0, 1]) with intrinsics ``K (3, 3)``
    (pixels of this image) and the camera's ``pitch``, ``roll`` (radians, conventions §4), largest
    inscribed disc first.

    A blob is a connected set (8-neighbours) of pixels whose mean channel is ``>= level``, of equivalent
    radius ``sqrt(area / pi) / f`` at most ``max_radius_deg``, with a disc of ``min_inscribed_deg`` inside
    it and compactness at least ``min_fill``. Its direction is the ray through its deepest point (the
    centre of its largest inscribed disc, Euclidean distance transform; the mean of the deepest pixels):
    the clipped glow around a low sun spreads along the horizon and an occluder cuts the disc, both of which
    pull a centroid off the sun more than the deepest point.
    """
    img = np.asarray(image, np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3), got {img.shape}")
    mask = (img.mean(axis=2) >= level).astype(np.uint8)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return []
    depth = cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    f = float(math.sqrt(abs(K[0, 0] * K[1, 1])))
    R = np.asarray(rotation_from_ypr(0.0, float(pitch), float(roll)))
    out = []
    for k in range(1, n):
        area = int(stats[k, cv2.CC_STAT_AREA])
        radius = math.degrees(math.sqrt(area / math.pi) / f)
        if radius > max_radius_deg:
            continue
        ys, xs = np.nonzero(labels == k)
        dk = depth[ys, xs]
        inscribed = math.degrees(float(dk.max()) / f)
        if inscribed < min_inscribed_deg:
            continue
        cx, cy = centroids[k]
        r_max = float(np.sqrt(((xs - cx) ** 2 + (ys - cy) ** 2).max())) + 0.5
        fill = area / (math.pi * r_max**2)
        if fill < min_fill:
            continue
        deep = dk >= dk.max() - 0.5
        ray = np.asarray(rays_through_pixels(K, np.array([xs[deep].mean()]), np.array([ys[deep].mean()])))[0]
        d = R @ (ray / np.linalg.norm(ray))
        out.append(BlobSun(d.astype(np.float32), radius, inscribed, fill, area))
    return sorted(out, key=lambda b: -b.inscribed_deg)


def put_sun_on_blob(
    sun_dir: torch.Tensor,
    visible: torch.Tensor,
    image: torch.Tensor,
    K: torch.Tensor,
    pitch: torch.Tensor,
    roll: torch.Tensor,
    threshold: float,
    *,
    logits: torch.Tensor | None = None,
    gate_deg: float = GATE_DEG,
    logit_margin: float = LOGIT_MARGIN,
    promote: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The network's ``sun_dir (B, 3)`` moved onto a sun-like blob of ``image (B, 3, H, W)`` where its
    ``visible (B,)`` probability is ``>= threshold`` and the blob is one the network agrees with: within
    ``gate_deg`` of its direction, or (with its ``logits (B, 1, h, 2h)``) where its logit is within
    ``logit_margin`` of its highest; of those the nearest to its direction.

    ``promote`` (0: off; at most ``threshold``): where the probability is in ``[promote, threshold)`` and the
    image has exactly one sun-like blob, that blob alone makes the sun visible and the sun goes onto it,
    whatever the gate: a clipped compact disc is the sun's own signature, and there is one sun (gaps in a
    canopy and lamps clip in many places; in the real validation crops they gave 2-25 blobs, a sun 1).
    Returns ``(sun_dir (B, 3), on_blob (B,) bool, promoted (B,) bool)``.
    ``K (B, 3, 3)`` in pixels of ``image``; ``pitch``, ``roll (B,)`` radians."""
    out = sun_dir.clone()
    on = torch.zeros(sun_dir.shape[0], dtype=torch.bool, device=sun_dir.device)
    promoted = torch.zeros_like(on)
    cos_gate = math.cos(math.radians(gate_deg))
    imgs = image.detach().permute(0, 2, 3, 1).cpu().numpy()
    for i in range(sun_dir.shape[0]):
        p = float(visible[i])
        if p < threshold and not (0.0 < promote <= p):
            continue
        blobs = image_sun_blobs(imgs[i], K[i].detach().cpu().double().numpy(), float(pitch[i]), float(roll[i]))
        if not blobs:
            continue
        net = sun_dir[i].detach().cpu().double().numpy()
        if p < threshold:
            if len(blobs) == 1:
                out[i] = torch.as_tensor(blobs[0].direction, dtype=sun_dir.dtype, device=sun_dir.device)
                on[i] = promoted[i] = True
            continue
        agree = [float(np.dot(b.direction, net)) >= cos_gate for b in blobs]
        if logits is not None:
            lg = logits[i, 0].detach().cpu().numpy()
            for k, b in enumerate(blobs):
                x, y = coords_from_direction(b.direction.astype(np.float64), lg.shape[0])
                v = lg[min(int(y), lg.shape[0] - 1), int(x) % lg.shape[1]]
                agree[k] = agree[k] or bool(v >= lg.max() - logit_margin)
        cands = [b for b, ok in zip(blobs, agree) if ok]
        if cands:
            pick = max(cands, key=lambda b: float(np.dot(b.direction, net)))
            out[i] = torch.as_tensor(pick.direction, dtype=sun_dir.dtype, device=sun_dir.device)
            on[i] = True
    return out, on, promoted
