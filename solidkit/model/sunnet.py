"""The sun from a small copy of the image: a low-resolution network beside I-Net (``config.sun_net``).

The sun head on I-Net's own features (:class:`solidkit.model.sunhead.SunHead`) learnt the sun's
direction only where the sun is in the image: beside or behind the camera its azimuth stayed at chance
after 35-48k training samples (docs/training.md), and each sample costs a pass of I-Net's encoder and
sky decoder at 240 x 320. The cues to a hidden sun (which facades are lit, where cast shadows fall, the
sky's gradient) are large and low in frequency, so :class:`SunNet` reads them at ``96 x 128``, ~6x fewer
pixels, in its own small encoder, trainable on its own (stage ``sun`` of :mod:`solidkit.model.trainer`):
5.5x the samples per second of I-Net's crop step in the same benchmark run, ~15x in the training run of
checkpoint v5 (``benchmarks/results/train.md``).

Inputs: the image resized to ``config.sun_net_size`` plus, per pixel, the unit direction of its ray in
the camera's level panorama frame (``R_cam K^-1 (x, y, 1)``, conventions §2/§4), so the network knows
where every pixel looks whatever the field of view, pitch and roll. Outputs are the
:class:`~solidkit.model.sunhead.SunHead` outputs (I-Net renders them into the sky the same way):

- logits over the ``pano_height / 2`` panorama: a coarse ``16 x 32`` map from the pooled features
  (any direction, behind the camera too) plus, inside the image's own footprint, a 1x1 convolution of
  the ``1/4``-resolution features placed at the directions they see (a sun in the image is located at
  the image's resolution, ~2° at 60° hfov);
- the direction (mode-local soft-argmax), energy, angular size and visibility, from the pooled features.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from solidkit.envmap.coords import direction_grid
from solidkit.envmap.perspective import pixel_rays, project_to_pixels, scale_intrinsics
from solidkit.model.blocks import Encoder, resize_to
from solidkit.model.sunhead import SIGMA_MAX, SIGMA_MIN, local_soft_argmax
from solidkit.model.warp import camera_rotation

__all__ = ["SunNet", "ray_directions", "image_grid_on_panorama"]


def _scaled_intrinsics(K: torch.Tensor, image_size: tuple[int, ...], size: tuple[int, int]) -> torch.Tensor:
    """``K (B, 3, 3)`` of an image of ``image_size = (H, W)`` for the same view resized to ``size``."""
    sy, sx = size[0] / image_size[0], size[1] / image_size[1]
    scaled = np.stack([scale_intrinsics(k, sx, sy) for k in K.detach().cpu().double().numpy()])
    return torch.as_tensor(scaled, dtype=K.dtype, device=K.device)


def ray_directions(K: torch.Tensor, pitch: torch.Tensor, roll: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Unit ray of every pixel centre of a ``size = (H, W)`` image, panorama frame: ``(B, 3, H, W)``.

    ``R_cam K^-1 (x, y, 1)`` with ``R_cam = camera_rotation(pitch, roll)`` (the camera's yaw is the
    panorama's forward direction); ``K (B, 3, 3)`` in pixels of this image.
    """
    h, w = size
    cam = pixel_rays(K, w, h, torch, dtype=K.dtype, device=K.device).reshape(K.shape[0], -1, 3)  # (B, HW, 3)
    world = torch.einsum("bij,bnj->bni", camera_rotation(pitch, roll).to(K.dtype), cam)
    return F.normalize(world, dim=-1).transpose(1, 2).reshape(-1, 3, h, w)


def image_grid_on_panorama(
    pano_height: int, K: torch.Tensor, pitch: torch.Tensor, roll: torch.Tensor, size: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Where every panorama direction lands in a pinhole image: ``grid_sample`` grid ``(B, H, 2H, 2)``
    (normalised, ``align_corners=False``) and a mask ``(B, 1, H, 2H)`` of the directions inside the image.

    The exact projection ``K R_cam^T d`` (:func:`solidkit.envmap.perspective.project_to_pixels`), unlike
    the mirror-tiled angular footprint of :func:`solidkit.model.inet.camera_footprint_grid`.
    """
    h, w = size
    dirs = direction_grid(pano_height, torch, dtype=K.dtype, device=K.device)  # (H, 2H, 3)
    cam = torch.einsum("bji,hwj->bhwi", camera_rotation(pitch, roll).to(K.dtype), dirs)
    x, y, front = (torch.stack(v) for v in zip(*(project_to_pixels(Ki, ci) for Ki, ci in zip(K, cam))))
    gx, gy = (2.0 * x + 1.0) / w - 1.0, (2.0 * y + 1.0) / h - 1.0
    inside = front & (gx.abs() <= 1.0) & (gy.abs() <= 1.0)
    grid = torch.stack([gx, gy], dim=-1).where(inside[..., None], torch.zeros_like(gx)[..., None])
    return grid, inside[:, None].to(K.dtype)


class SunNet(nn.Module):
    """Sun direction logits, energy, size and visibility from a low-resolution copy of the image.

    Parameters
    ----------
    widths : tuple of int
        Encoder channels per level (level ``k`` at ``1/2**(k+1)`` of ``size``); at least 3 levels.
    size : (int, int)
        ``(H, W)`` the image is resized to.
    logit_height : int
        Height of the logit panorama (width twice that); a multiple of ``2 * coarse_height``.
    coarse_height : int
        Height of the coarse global logit map.
    hidden : int
        Width of the hidden layers.
    """

    def __init__(
        self,
        widths: tuple[int, ...] = (16, 32, 64, 128),
        size: tuple[int, int] = (96, 128),
        logit_height: int = 64,
        coarse_height: int = 16,
        hidden: int = 256,
    ) -> None:
        super().__init__()
        if len(widths) < 3:
            raise ValueError(f"SunNet needs at least 3 encoder levels, got {widths}")
        self.size = cast(tuple[int, int], tuple(int(s) for s in size))
        self.logit_height, self.coarse_height = logit_height, coarse_height
        self.encoder = Encoder(6, tuple(widths))
        self.pool = nn.AdaptiveAvgPool2d((3, 4))
        self.mlp = nn.Sequential(
            nn.Linear(widths[-1] * 12, hidden), nn.ELU(inplace=True), nn.Linear(hidden, hidden), nn.ELU(inplace=True)
        )
        self.coarse = nn.Linear(hidden, 2 * coarse_height**2)
        self.params = nn.Linear(hidden, 4)
        self.visible = nn.Linear(hidden, 1)
        self.fine = nn.Conv2d(widths[1] + widths[-1], 1, 1)

    def forward(
        self, image: torch.Tensor, K: torch.Tensor, pitch: torch.Tensor, roll: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """``image (B, 3, H, W)`` in [0, 1] with intrinsics ``K (B, 3, 3)`` (pixels of ``image``), ``pitch``,
        ``roll (B,)`` radians -> the :class:`~solidkit.model.sunhead.SunHead` outputs (``sun_logits
        (B, 1, logit_height, 2 logit_height)``, ``sun_dir``, ``sun_energy``, ``sun_log_energy``,
        ``sun_sigma``, ``sun_visible_logit``, ``sun_visible``)."""
        b = image.shape[0]
        Ks = _scaled_intrinsics(K.to(image), tuple(image.shape[-2:]), self.size)
        small = F.interpolate(image, size=self.size, mode="bilinear", align_corners=False, antialias=True)
        rays = ray_directions(Ks, pitch.to(image), roll.to(image), self.size)
        feats = self.encoder(torch.cat([small * 2.0 - 1.0, rays], dim=1))
        hid = self.mlp(torch.flatten(self.pool(feats[-1]), 1))
        ch, lh = self.coarse_height, self.logit_height
        coarse = F.pad(self.coarse(hid).view(b, 1, ch, 2 * ch), (1, 1, 0, 0), mode="circular")
        s = lh // ch
        logits = F.interpolate(coarse, scale_factor=float(s), mode="bilinear", align_corners=False)[..., s:-s]
        level = feats[1]
        fine = self.fine(torch.cat([level, resize_to(feats[-1], level.shape[-2:])], dim=1))
        grid, inside = image_grid_on_panorama(lh, Ks, pitch.to(image), roll.to(image), self.size)
        logits = logits + inside * F.grid_sample(
            fine, grid, mode="bilinear", padding_mode="border", align_corners=False
        )
        par = self.params(hid)
        log_energy = par[:, :3]
        vis = self.visible(hid)[:, 0]
        return {
            "sun_logits": logits,
            "sun_dir": local_soft_argmax(logits, radius=math.radians(10.0)),
            "sun_log_energy": log_energy,
            "sun_energy": torch.exp(log_energy.clamp(max=20.0)),
            "sun_sigma": SIGMA_MIN + (SIGMA_MAX - SIGMA_MIN) * torch.sigmoid(par[:, 3]),
            "sun_visible_logit": vis,
            "sun_visible": torch.sigmoid(vis),
        }
