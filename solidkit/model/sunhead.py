"""A parametric sun inside the non-parametric sky: I-Net's sun head and its differentiable rendering.

A per-pixel L1 on ``log1p`` radiance cannot teach a decoder of smooth upsampling stages a one-pixel
sun 10^4 times brighter than the sky: the sun is ~3e-4 of the loss, and a sunless median is the
L1 optimum as soon as its position is uncertain by more than a pixel. So the sun is predicted as
three quantities, each with a loss it can learn from (:mod:`solidkit.model.losses`):

- **direction**: a logit map over the panorama (a coarse global map from the lighting features,
  upsampled, plus a 1x1 convolution of the sky decoder's last features), trained by cross-entropy
  against a small Gaussian at the true sun (a location loss, not a per-pixel radiance loss). The
  direction is the soft-argmax of the logits restricted to a cap around their mode
  (:func:`local_soft_argmax`), sub-pixel and insensitive to a second, weaker mode;
- **energy** ``E`` (RGB, radiance x steradian, the integral over the sun's disk) from the global
  lighting features, trained in log space;
- **angular size**: a spherical Gaussian of standard deviation ``sigma`` in
  ``[SIGMA_MIN, SIGMA_MAX]``;
- **visibility** (``visibility=True``): the probability that the sky has a visible sun at all, from
  the global lighting features. In evaluation mode a sun is rendered only where it is at least 0.5
  (an overcast sky gets none); while training the rendered sun is scaled by the probability.

With ``fine=False`` the logits are the coarse global map alone. The sky decoder's features are the
image's features mirror-tiled around the panorama (:func:`solidkit.model.inet.flip_pad`), so a 1x1
convolution of them repeats any motif every two image widths and cannot place one sun behind the
camera; the global map, a function of the pooled features, can.

:func:`render_sun` writes ``E`` into the panorama as a normalised spherical Gaussian (its discrete
integral ``sum L Omega`` is exactly ``E``, however small ``sigma`` is against a pixel), and I-Net
adds it to the non-parametric sky. The sky map therefore carries the sun's energy for relighting
and any detector that reads the map (``solidkit.envmap.detect_sun``, the paper's recipe) finds it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from solidkit.envmap.coords import direction_grid, solid_angle

__all__ = [
    "CONE68_PER_SIGMA",
    "SIGMA_MIN",
    "SIGMA_MAX",
    "SunHead",
    "aureole_sigma",
    "render_sun",
    "render_sun_with_aureole",
    "local_soft_argmax",
    "log_solid_angle",
]

SIGMA_MIN = math.radians(0.3)
"""Smallest angular standard deviation of the rendered sun (radians; the disk's own is 0.11°)."""
SIGMA_MAX = math.radians(4.0)
"""Largest angular standard deviation (a sun seen through haze or thin cloud)."""
CONE68_PER_SIGMA = math.sqrt(-2.0 * math.log(1.0 - 0.68))
"""Radius of the cone holding 68 % of an isotropic 2-D Gaussian, in standard deviations (≈1.51).

The radial distance of a 2-D Gaussian is Rayleigh-distributed: ``P(r <= R) = 1 - exp(-R^2 / 2 sigma^2)``."""


def log_solid_angle(height: int, like: torch.Tensor) -> torch.Tensor:
    """``log Omega`` of every pixel of a ``(height, 2 height)`` panorama, ``(height, 2 height)``."""
    return torch.log(solid_angle(height, torch, dtype=like.dtype, device=like.device).expand(height, 2 * height))


def local_soft_argmax(logits: torch.Tensor, radius: float = math.radians(10.0)) -> torch.Tensor:
    """Unit direction ``(B, 3)`` of the probability-weighted mean over a cap about the mode.

    ``logits (B, 1, H, 2H)`` define ``p ∝ exp(logit) Omega`` over the pixels; the mean of the pixel
    directions weighted by ``p`` within ``radius`` (radians; at least 2.5 pixels) of the most probable
    pixel is normalised. Differentiable in ``logits`` (the cap itself is not).
    """
    b, _, h, w = logits.shape
    radius = max(radius, 2.5 * math.pi / h)
    dirs = direction_grid(h, torch, dtype=logits.dtype, device=logits.device).reshape(-1, 3)
    lp = (logits[:, 0] + log_solid_angle(h, logits)).reshape(b, -1)
    mode = dirs[lp.argmax(dim=1)]  # (B, 3)
    near = (dirs @ mode.T).T > math.cos(radius)  # (B, H*W)
    p = torch.softmax(lp.masked_fill(~near, -torch.inf), dim=1)
    return F.normalize(p @ dirs, dim=-1, eps=1e-8)


def render_sun(direction: torch.Tensor, energy: torch.Tensor, sigma: torch.Tensor, height: int) -> torch.Tensor:
    """Radiance ``(B, C, height, 2 height)`` of suns with ``sum L Omega = energy`` exactly.

    ``direction (B, 3)`` unit vectors (panorama frame), ``energy (B, C)`` (radiance x sr),
    ``sigma (B,)`` angular standard deviation in radians: ``L ∝ exp((cos t - 1) / sigma^2)``
    (``≈ exp(-t^2 / 2 sigma^2)``), normalised on the pixel grid.
    """
    dirs = direction_grid(height, torch, dtype=direction.dtype, device=direction.device)
    omega = solid_angle(height, torch, dtype=direction.dtype, device=direction.device)
    cos = torch.einsum("hwk,bk->bhw", dirs, direction)
    logg = (cos - 1.0) / sigma[:, None, None] ** 2
    logg = logg - logg.flatten(1).amax(dim=1)[:, None, None]
    g = torch.exp(logg)
    g = g / (g * omega).flatten(1).sum(dim=1)[:, None, None]
    return energy[:, :, None, None] * g[:, None]


def aureole_sigma(cone68_deg: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Angular standard deviation ``(B,)`` (radians) of a Gaussian whose 68 % cone is ``cone68_deg (B,)``.

    Never below the sun's own ``sigma (B,)`` (radians): a sun known to better than its size stays sharp.
    """
    return torch.maximum(torch.deg2rad(cone68_deg) / CONE68_PER_SIGMA, sigma)


def render_sun_with_aureole(
    direction: torch.Tensor,
    energy: torch.Tensor,
    sigma: torch.Tensor,
    cone68_deg: torch.Tensor,
    fraction: float,
    height: int,
) -> torch.Tensor:
    """:func:`render_sun` with ``fraction`` of ``energy`` spread over the direction's 68 % cone.

    The spread part is the sun blurred by its own direction uncertainty (a Gaussian whose 68 % cone is
    ``cone68_deg (B,)``, :func:`aureole_sigma`): the expected sun of a map whose sun is only known to
    within that cone. The sharp rest keeps the compact core a sun detector looks for, and the spread
    part makes the sun's surroundings the brightest region of the map, so the paper's recipe (largest
    bright component) finds the same sun. ``sum L Omega = energy`` still holds exactly.
    Returns ``(B, C, height, 2 height)``.
    """
    sharp = render_sun(direction, energy * (1.0 - fraction), sigma, height)
    if fraction <= 0.0:
        return sharp
    wide = render_sun(direction, energy * fraction, aureole_sigma(cone68_deg, sigma), height)
    return sharp + wide


class SunHead(nn.Module):
    """Sun logits, energy and size from I-Net's pooled lighting features and the sky decoder's features.

    Parameters
    ----------
    global_features : int
        Length of the pooled lighting feature vector.
    sky_features : int
        Channels of the sky decoder's last feature map ``(B, C, H, 2H)``.
    coarse_height : int
        Height of the coarse global logit map (width twice that).
    hidden : int
        Width of the hidden layer.
    visibility : bool
        Also predict the probability that a sun is visible (module docstring).
    fine : bool
        Add a 1x1 convolution of the sky decoder's features to the coarse global logits.
    """

    def __init__(
        self,
        global_features: int,
        sky_features: int,
        coarse_height: int = 16,
        hidden: int = 128,
        visibility: bool = False,
        fine: bool = True,
    ) -> None:
        super().__init__()
        self.coarse_height = coarse_height
        self.mlp = nn.Sequential(nn.Linear(global_features, hidden), nn.ELU(inplace=True))
        self.coarse = nn.Linear(hidden, 2 * coarse_height**2)
        self.params = nn.Linear(hidden, 4)
        self.fine = nn.Conv2d(sky_features, 1, 1) if fine else None
        self.visible = nn.Linear(hidden, 1) if visibility else None

    def forward(self, global_feat: torch.Tensor, sky_feats: torch.Tensor) -> dict[str, torch.Tensor]:
        """Returns ``sun_logits (B, 1, H, 2H)``, ``sun_dir (B, 3)``, ``sun_energy (B, 3)``,
        ``sun_log_energy (B, 3)``, ``sun_sigma (B,)`` (radians) and, with ``visibility``,
        ``sun_visible_logit (B,)`` and ``sun_visible (B,)`` (its probability)."""
        b, _, h, w = sky_feats.shape
        hid = self.mlp(global_feat)
        coarse = self.coarse(hid).view(b, 1, self.coarse_height, 2 * self.coarse_height)
        coarse = F.pad(coarse, (1, 1, 0, 0), mode="circular")  # the azimuth seam is continuous
        scale = w // (2 * self.coarse_height)
        up = F.interpolate(coarse, scale_factor=float(scale), mode="bilinear", align_corners=False)[..., scale:-scale]
        logits = up if self.fine is None else self.fine(sky_feats) + up
        par = self.params(hid)
        log_energy = par[:, :3]
        sigma = SIGMA_MIN + (SIGMA_MAX - SIGMA_MIN) * torch.sigmoid(par[:, 3])
        direction = local_soft_argmax(logits)
        out = {
            "sun_logits": logits,
            "sun_dir": direction,
            "sun_log_energy": log_energy,
            "sun_energy": torch.exp(log_energy.clamp(max=20.0)),
            "sun_sigma": sigma,
        }
        if self.visible is not None:
            vis = self.visible(hid)[:, 0]
            out.update(sun_visible_logit=vis, sun_visible=torch.sigmoid(vis))
        return out
