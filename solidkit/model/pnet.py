"""P-Net (SOLID-Net stage 2, paper §4.2): a U-Net completing the local HDR panorama ``H_l``.

Inputs, all ``(B, ·, H, 2H)`` panoramas centred at the probe, chosen by
``config.pnet_inputs`` (paper Table 2; the full model uses ``col``, ``sha`` and ``sky``):

- ``col``: the warped LDR image ``W_col`` (3 channels) and its observed mask (1);
- ``sha``: the warped shadow map ``W_sha`` (1);
- ``sh``: the Lambertian sphere relit with ``P_SH`` (``W_SH``, :func:`solidkit.envmap.sh.lambertian_sphere`),
  as ``log1p(max(., 0))`` (3);
- ``sky``: the global sky ``H_g`` as ``y = log1p(H_g)`` (3).

Output ``y = log1p(H_l)`` (softplus head); radiance ``H_l = expm1(y)``. Convolutions pad the azimuth
axis circularly.
"""

from __future__ import annotations

from typing import cast

import torch
import torch.nn.functional as F
from torch import nn

from solidkit.envmap.sh import lambertian_sphere
from solidkit.model.blocks import Encoder, UNetDecoder, log_from_radiance, radiance_from_log
from solidkit.model.config import SolidNetConfig

__all__ = ["PNet", "PNET_CHANNELS", "pnet_input"]

PNET_CHANNELS = {"col": 4, "sha": 1, "sh": 3, "sky": 3}


def pnet_input(
    inputs: tuple[str, ...],
    warped_image: torch.Tensor,
    mask: torch.Tensor,
    warped_shadow: torch.Tensor | None = None,
    sh: torch.Tensor | None = None,
    sky_log: torch.Tensor | None = None,
) -> torch.Tensor:
    """Concatenate the P-Net inputs named in ``inputs`` (see module docstring), ``(B, C, H, 2H)``.

    ``warped_image (B, 3, H, 2H)``, ``mask (B, 1, H, 2H)``, ``warped_shadow (B, 1, H, 2H)``,
    ``sh (B, 3, 9)`` and ``sky_log (B, 3, H, 2H)``; those not named may be None.
    """
    parts: list[torch.Tensor | None] = [warped_image, mask]
    height = warped_image.shape[-2]
    for name in inputs:
        if name == "sha":
            parts.append(warped_shadow)
        elif name == "sh":
            parts.append(log_from_radiance(lambertian_sphere(sh, height)))
        elif name == "sky":
            parts.append(sky_log)
    if any(p is None for p in parts):
        raise ValueError(f"P-Net inputs {inputs} need tensors that were not given")
    return torch.cat(cast(list[torch.Tensor], parts), dim=1)


class PNet(nn.Module):
    """U-Net ``(B, C_in, H, 2H) -> {"local_log": log1p(H_l), "local": H_l}`` (each ``(B, 3, H, 2H)``)."""

    def __init__(self, config: SolidNetConfig) -> None:
        super().__init__()
        self.config = config
        self.in_channels = sum(PNET_CHANNELS[k] for k in config.pnet_inputs)
        self.encoder = Encoder(self.in_channels, config.pnet_widths, panorama=True)
        self.decoder = UNetDecoder(config.pnet_widths, 3, extra_in=self.in_channels, panorama=True)

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        if x.shape[1] != self.in_channels:
            raise ValueError(
                f"P-Net expects {self.in_channels} input channels ({self.config.pnet_inputs}), got {x.shape[1]}"
            )
        y = F.softplus(self.decoder(self.encoder(x), tuple(x.shape[-2:]), x))
        return {"local_log": y, "local": radiance_from_log(y)}
