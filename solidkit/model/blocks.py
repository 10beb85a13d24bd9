"""Convolutional building blocks shared by I-Net, P-Net and the baselines.

Every block is ``conv -> GroupNorm -> ELU`` (GroupNorm keeps batch-1 training and inference
identical). Panorama blocks pad the azimuth axis circularly (the ±180° seam is continuous) and the
elevation axis with zeros.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "ConvBlock",
    "Encoder",
    "UNetDecoder",
    "resize_to",
    "HDR_PARAMETERISATION",
    "radiance_from_log",
    "log_from_radiance",
]

HDR_PARAMETERISATION = "log1p"
"""How every HDR output of the model maps to radiance.

The heads that predict ``H_g`` and ``H_l`` end in a softplus and output ``y >= 0``; the radiance is
``H = expm1(y)`` (linear RGB, in the units of the training panoramas, relative when those are
relative). Working in ``y = log1p(H)`` keeps a sun of 10^4 and a shadowed ground of 10^-2 within a
few units of each other, so the L1 terms on H_g and H_l (computed on ``y``) train stably, while the
physically defined terms (L_dif, L_tom) are computed on ``H`` itself.
"""


def radiance_from_log(y: torch.Tensor) -> torch.Tensor:
    """Radiance ``H = expm1(y)`` of the model's HDR output ``y = log1p(H)`` (see HDR_PARAMETERISATION)."""
    return torch.expm1(y)


def log_from_radiance(h: torch.Tensor) -> torch.Tensor:
    """``y = log1p(max(H, 0))``: radiance to the model's HDR parameterisation."""
    return torch.log1p(h.clamp_min(0.0))


def _groups(channels: int) -> int:
    return math.gcd(channels, 8)


class ConvBlock(nn.Module):
    """``conv3x3(stride) -> GroupNorm -> ELU``; ``panorama=True`` pads azimuth circularly."""

    def __init__(self, cin: int, cout: int, stride: int = 1, panorama: bool = False) -> None:
        super().__init__()
        self.panorama = panorama
        self.conv = nn.Conv2d(cin, cout, 3, stride=stride, padding=0 if panorama else 1, bias=False)
        self.norm = nn.GroupNorm(_groups(cout), cout)
        self.act = nn.ELU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.panorama:
            x = F.pad(x, (1, 1, 0, 0), mode="circular")
            x = F.pad(x, (0, 0, 1, 1))
        return self.act(self.norm(self.conv(x)))


def resize_to(x: torch.Tensor, size: tuple[int, ...]) -> torch.Tensor:
    """Bilinear resize of ``(B, C, h, w)`` to ``size`` (no-op when already that size)."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


class Encoder(nn.Module):
    """Strided encoder: level ``k`` has ``widths[k]`` channels at ``1/2**(k+1)`` resolution.

    ``forward`` returns the list of the features of every level (the skip links).
    """

    def __init__(self, cin: int, widths: tuple[int, ...], panorama: bool = False) -> None:
        super().__init__()
        levels = []
        prev = cin
        for w in widths:
            levels.append(nn.Sequential(ConvBlock(prev, w, 2, panorama), ConvBlock(w, w, 1, panorama)))
            prev = w
        self.levels = nn.ModuleList(levels)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = []
        for level in self.levels:
            x = level(x)
            feats.append(x)
        return feats


class UNetDecoder(nn.Module):
    """Decoder mirroring an :class:`Encoder`: upsample, concatenate the skip, convolve; full-res head.

    ``extra_in`` channels (e.g. the raw input) are concatenated at full resolution before the head.
    Returns the head's raw output ``(B, cout, H, W)`` at the size ``out_size`` given to ``forward``.
    """

    def __init__(self, widths: tuple[int, ...], cout: int, extra_in: int = 0, panorama: bool = False) -> None:
        super().__init__()
        rev = list(reversed(widths))
        self.ups = nn.ModuleList(ConvBlock(rev[i] + rev[i + 1], rev[i + 1], 1, panorama) for i in range(len(rev) - 1))
        self.final = ConvBlock(rev[-1] + extra_in, rev[-1], 1, panorama)
        self.head = nn.Conv2d(rev[-1], cout, 1)

    def forward(
        self, feats: list[torch.Tensor], out_size: tuple[int, int], extra: torch.Tensor | None = None
    ) -> torch.Tensor:
        x = feats[-1]
        for up, skip in zip(self.ups, reversed(feats[:-1])):
            x = up(torch.cat([resize_to(x, skip.shape[-2:]), skip], dim=1))
        x = resize_to(x, out_size)
        if extra is not None:
            x = torch.cat([x, extra], dim=1)
        return self.head(self.final(x))
