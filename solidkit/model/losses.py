"""The SOLID-Net losses (paper §4.3), as small functions over torch tensors.

- ``L_sup1`` (I-Net direct supervision): L2 albedo, cosine normal (``mean(1 - n~ . n)``), L1 plane
  distance, L2 shadow, L1 sky. Pixel terms accept a validity mask (e.g. non-sky pixels: sky has no
  albedo, normal or plane).
- ``L_sup2`` (P-Net direct supervision): L1 local panorama.
- ``L_dif``: ``mean_i [D(H_g, i) - diag(alpha_o) L b(N_ll(i))]^2`` with ``alpha_o = [1, 1, 1]``,
  using :func:`solidkit.envmap.sh.diffuse_convolution` (``D``) and
  :func:`solidkit.envmap.sh.lambertian_sphere` (``L b(N_ll)``).
- ``L_rec``: ``|| M_ncs ⊙ (I - (A ⊙ L B(N))^(1/2.2)) ||_2`` (mean of squares over the mask) with
  ``M_ncs`` the non-shadowed pixels: shadow map above its Otsu threshold
  (:func:`kornia.filters.otsu_threshold`), intersected with the valid-geometry mask. N is rotated
  from the camera into the panorama frame (``R_cam``) before ``B(N)``, since ``L`` is in that frame.
- ``L_tom``: kornia SSIM loss (``(1 - SSIM) / 2``, 11x11 window) between
  ``T(H) = clip((2^e H)^(1/2.2), 0, 1)``, ``e = -0.3`` (:func:`solidkit.envmap.io.tonemap`).

HDR terms and the output parameterisation (:data:`solidkit.model.blocks.HDR_PARAMETERISATION`): the L1
terms on H_g and H_l compare ``log1p`` values (the model's output ``y`` against ``log1p`` of the
ground-truth radiance); L_dif and L_tom use radiance ``H = expm1(y)`` as the paper defines them.

Shadow maps are visibility ratios: 1 = lit, 0 = fully shadowed (the synthetic generator's convention).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from kornia.filters import otsu_threshold
from kornia.losses import ssim_loss

from solidkit.envmap.io import PAPER_EXPOSURE, PAPER_GAMMA, tonemap
from solidkit.envmap.sh import diffuse_convolution, lambertian_sphere, sh_render
from solidkit.model.blocks import log_from_radiance

__all__ = [
    "masked_mean",
    "albedo_loss",
    "normal_loss",
    "distance_loss",
    "shadow_loss",
    "hdr_l1_loss",
    "sup1_loss",
    "sup2_loss",
    "diffuse_loss",
    "sh_shading",
    "non_shadow_mask",
    "reconstruction_loss",
    "tonemapped_ssim_loss",
    "solidnet_losses",
]


def masked_mean(x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean of ``x (B, C, H, W)`` over the pixels where ``mask (B, 1, H, W)`` is true (all when None).

    An empty mask gives 0 (with a gradient path), never NaN.
    """
    if mask is None:
        return x.mean()
    m = mask.to(x.dtype).expand_as(x)
    return (x * m).sum() / m.sum().clamp_min(1.0)


def albedo_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """L2 (mean squared error) on diffuse albedo ``(B, 3, H, W)``."""
    return masked_mean((pred - target) ** 2, mask)


def normal_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Cosine loss ``mean(1 - n~ . n)`` on unit normals ``(B, 3, H, W)`` (0 when aligned, 2 when opposite)."""
    cos = (F.normalize(pred, dim=1, eps=1e-6) * F.normalize(target, dim=1, eps=1e-6)).sum(1, keepdim=True)
    return masked_mean(1.0 - cos, mask)


def distance_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """L1 on plane distance ``(B, 1, H, W)`` (metres)."""
    return masked_mean((pred - target).abs(), mask)


def shadow_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """L2 on the shadow map ``(B, 1, H, W)``."""
    return masked_mean((pred - target) ** 2, mask)


def hdr_l1_loss(pred_log: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L1 between the model's ``y = log1p(H~)`` and ``log1p(H)`` of the target radiance."""
    return (pred_log - log_from_radiance(target)).abs().mean()


def sup1_loss(out: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The terms of ``L_sup1`` (keys ``albedo, normal, distance, shadow, sky``) that both the
    model output and the batch provide (a sky-only baseline gets ``sky`` alone)."""
    mask = batch.get("geometry_mask")
    pixel_terms = {"albedo": albedo_loss, "normal": normal_loss, "distance": distance_loss, "shadow": shadow_loss}
    terms = {k: f(out[k], batch[k], mask) for k, f in pixel_terms.items() if k in out and k in batch}
    if "sky_log" in out and "sky" in batch:
        terms["sky"] = hdr_l1_loss(out["sky_log"], batch["sky"])
    return terms


def sup2_loss(local_log: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``L_sup2``: L1 on the local panoramas (``log1p`` space), any matching shapes."""
    return hdr_l1_loss(local_log, target)


def diffuse_loss(sky: torch.Tensor, sh: torch.Tensor, height: int | None = 32) -> torch.Tensor:
    """``L_dif`` (eq. 5): mean squared difference of ``D(H_g)`` and the sphere relit with ``L``.

    ``sky (B, 3, H, 2H)`` radiance, ``sh (B, 3, 9)``. ``D`` is smooth (a cosine-lobe average), so by
    default both sides are evaluated on a 32 x 64 grid (``D`` of the area-downsampled, energy
    preserving panorama); ``height=None`` uses the panorama's own grid.
    """
    d = diffuse_convolution(sky, height=height)
    return ((d - lambertian_sphere(sh, d.shape[-2])) ** 2).mean()


def sh_shading(normal: torch.Tensor, sh: torch.Tensor, rotation: torch.Tensor | None = None) -> torch.Tensor:
    """``L B(N)``: SH shading ``(B, 3, H, W)`` of camera-frame normals ``(B, 3, H, W)``.

    ``rotation (B, 3, 3)`` maps camera to panorama frame (``R_cam``), where ``L (B, 3, 9)`` lives.
    """
    b, _, h, w = normal.shape
    n = normal.reshape(b, 3, h * w)
    if rotation is not None:
        n = rotation.to(n.dtype) @ n
    n = n.transpose(1, 2).reshape(b, h, w, 3)
    return sh_render(sh[:, None, None], n).permute(0, 3, 1, 2)


def non_shadow_mask(shadow: torch.Tensor, valid: torch.Tensor | None = None, flat_range: float = 1e-3) -> torch.Tensor:
    """``M_ncs``: pixels whose shadow map ``(B, 1, H, W)`` (1 = lit) is above its Otsu threshold.

    The Otsu split (kornia, per image) separates lit surfaces from shadows and weak inter-reflections.
    An image whose shadow map is flat (range < ``flat_range``) has no split: its pixels count as lit
    when above 0.5. ``valid`` (bool, same shape) restricts the mask further.
    """
    s = shadow.detach()
    lit, _ = otsu_threshold(s, return_mask=True)
    flat = (s.amax(dim=(1, 2, 3)) - s.amin(dim=(1, 2, 3))) < flat_range
    lit = torch.where(flat[:, None, None, None], s > 0.5, lit)
    if valid is not None:
        lit = lit & valid.bool()
    return lit


def reconstruction_loss(
    image: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    sh: torch.Tensor,
    mask: torch.Tensor,
    rotation: torch.Tensor | None = None,
    gamma: float = PAPER_GAMMA,
) -> torch.Tensor:
    """``L_rec`` (eq. 7): masked mean of ``(I - (A ⊙ L B(N))^(1/gamma))^2`` over ``mask (B, 1, H, W)``.

    ``image (B, 3, H, W)`` is the LDR input in [0, 1]; the shading is clamped at a small positive
    value before the power (its derivative is unbounded at 0).
    """
    shading = sh_shading(normal, sh, rotation)
    rendered = (albedo * shading).clamp_min(1e-6) ** (1.0 / gamma)
    return masked_mean((image - rendered) ** 2, mask)


def tonemapped_ssim_loss(
    pred: torch.Tensor, target: torch.Tensor, exposure: float = PAPER_EXPOSURE, window_size: int = 11
) -> torch.Tensor:
    """``L_tom``: kornia SSIM loss between tonemapped radiance panoramas ``(..., 3, H, W)``."""
    p = tonemap(pred.reshape(-1, *pred.shape[-3:]), exposure)
    t = tonemap(target.reshape(-1, *target.shape[-3:]), exposure)
    return ssim_loss(p, t, window_size)


def solidnet_losses(
    out: dict[str, torch.Tensor],
    batch: dict[str, torch.Tensor],
    weights: dict[str, float] | None = None,
) -> dict[str, torch.Tensor]:
    """All terms of ``L_I = L_sup1 + L_dif + L_rec`` and ``L_P = L_sup2 + L_tom`` for one batch.

    ``out`` is :meth:`SolidNet.forward`'s output; ``batch`` holds the ground truth (see
    :mod:`solidkit.model.solidnet`). Terms whose inputs are absent are skipped (e.g. P-Net terms
    when ``out`` has no ``local_log``). Returns every weighted term plus ``inet``, ``pnet`` and
    ``total``.
    """
    w = weights or {}
    terms: dict[str, torch.Tensor] = {}
    terms.update(sup1_loss(out, batch))
    if "sh" in out and "sky" in out:
        terms["dif"] = diffuse_loss(out["sky"], out["sh"])
    if "sh" in out and "albedo" in out and "image" in batch:
        shadow = batch.get("shadow", out["shadow"])
        mask = non_shadow_mask(shadow, batch.get("geometry_mask"))
        terms["rec"] = reconstruction_loss(
            batch["image"], out["albedo"], out["normal"], out["sh"], mask, out.get("rotation")
        )
    if "local_log" in out and "local" in batch:
        terms["local"] = sup2_loss(out["local_log"], batch["local"])
        terms["tom"] = tonemapped_ssim_loss(out["local"], batch["local"])
    weighted = {k: v * w.get(k, 1.0) for k, v in terms.items()}
    zero = next(iter(out.values())).new_zeros(())
    inet = sum((v for k, v in weighted.items() if k not in ("local", "tom")), zero)
    pnet = sum((v for k, v in weighted.items() if k in ("local", "tom")), zero)
    return {**weighted, "inet": inet, "pnet": pnet, "total": inet + pnet}
