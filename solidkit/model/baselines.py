"""Baselines of the paper's comparisons (§5.1, supplementary §3), on the same code paths.

- :class:`LENetReg` (``lenet_reg``): direct regression of the global HDR sky from the image with one
  encoder, an FC bottleneck and a panorama decoder; no intrinsics, no SH, no sky features. Its output
  (``sky_log``, ``sky``) is trained with the same sky term of ``L_sup1``
  (:func:`solidkit.model.losses.solidnet_losses` skips the terms it has no output for).
- P-Net input ablations (paper Table 2): a :class:`~solidkit.model.solidnet.SolidNet` whose
  ``config.pnet_inputs`` is ``col`` (W_col only, NeurIllum-like), ``col+sha``, ``col+sh`` (W_SH,
  the relit Lambertian sphere), ``col+sky`` or ``full`` (``col+sha+sky``, the paper's model).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from solidkit.model.blocks import ConvBlock, Encoder, radiance_from_log
from solidkit.model.config import ConfigError, SolidNetConfig, preset
from solidkit.model.solidnet import SolidNet

__all__ = ["BASELINES", "PNET_ABLATIONS", "LENetReg", "build_baseline"]

PNET_ABLATIONS: dict[str, tuple[str, ...]] = {
    "col": ("col",),
    "col+sha": ("col", "sha"),
    "col+sh": ("col", "sh"),
    "col+sky": ("col", "sky"),
    "full": ("col", "sha", "sky"),
}
BASELINES = ("lenet_reg", *PNET_ABLATIONS)


class LENetReg(nn.Module):
    """``LENet_reg``: image ``(B, 3, H, W)`` -> ``{"sky_log", "sky"}`` ``(B, 3, Hp, 2Hp)`` by direct regression.

    Encoder (``config.widths``) -> global pooling -> FC to a ``latent``-vector -> FC to a
    ``(C, Hp/32, Hp/16)`` panorama seed -> five (x2 upsample, panorama conv) stages -> softplus head
    (``y = log1p(H_g)``, as every HDR output of the package).
    """

    def __init__(self, config: SolidNetConfig, latent: int = 64) -> None:
        super().__init__()
        if config.pano_height % 32:
            raise ConfigError(f"LENetReg needs pano_height divisible by 32, got {config.pano_height}")
        self.config = config
        w = config.widths
        self.encoder = Encoder(3, w)
        self.pool = nn.AdaptiveAvgPool2d((3, 4))
        self.fc = nn.Sequential(nn.Linear(w[-1] * 12, latent), nn.ELU(inplace=True))
        self.seed_hw = (config.pano_height // 32, config.pano_height // 16)
        c0 = config.sky_widths[0]
        self.seed = nn.Linear(latent, c0 * self.seed_hw[0] * self.seed_hw[1])
        chans = [c0, c0, *config.sky_widths[1:], config.sky_widths[-1]]
        self.ups = nn.ModuleList(ConvBlock(chans[i], chans[i + 1], panorama=True) for i in range(5))
        self.head = nn.Conv2d(chans[-1], 3, 1)

    def forward(self, image: torch.Tensor) -> dict[str, torch.Tensor]:
        feats = self.encoder(image * 2.0 - 1.0)
        z = self.fc(torch.flatten(self.pool(feats[-1]), 1))
        y = self.seed(z).view(image.shape[0], -1, *self.seed_hw)
        for up in self.ups:
            y = up(F.interpolate(y, scale_factor=2.0, mode="bilinear", align_corners=False))
        sky_log = F.softplus(self.head(y))
        return {"sky_log": sky_log, "sky": radiance_from_log(sky_log)}


def build_baseline(name: str, config: SolidNetConfig | str = "small") -> nn.Module:
    """The baseline ``name`` (one of :data:`BASELINES`) built on ``config`` (a config or preset name)."""
    cfg = preset(config) if isinstance(config, str) else config
    if name == "lenet_reg":
        return LENetReg(cfg.replace(name=f"{cfg.name}-lenet_reg"))
    if name in PNET_ABLATIONS:
        return SolidNet(cfg.replace(pnet_inputs=PNET_ABLATIONS[name]))
    raise ConfigError(f"unknown baseline {name!r}; choose one of {BASELINES}")
