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

Variant ``"located"`` (``config.loss_variant``; needs the sun head, :mod:`solidkit.model.sunhead`).
The paper's L1 on the whole ``log1p`` sky makes a one-pixel sun ~3e-4 of the loss and is minimised by
a sunless median whenever the sun's position is uncertain by more than a pixel or so; its plane-distance
L1 in metres (up to ~90 m) dominates the total. So:

- ``sky``: L1 on ``log1p`` of the *non-parametric* sky outside a ``SUN_CAP`` cap about the true sun;
- ``sun_dir``: cross-entropy of the sun head's distribution ``p ∝ exp(logit) Omega`` against a
  Gaussian of ``sun_sigma`` (default ``SUN_TARGET_SIGMA``) at the true sun (skies with a visible sun),
  divided by ``log(H W)`` so that a uniform guess scores 1. A 2° target over 64 x 128 bins is nearly
  one-hot: early in training it rewards only the bin of the sun and says nothing about a guess 30°
  off against one 150° off. The trainer can anneal ``sun_sigma`` from a wide target (coarse to fine);
- ``sun_cos``: ``1 - cos`` of the angle between the soft-argmax of ``p`` over the whole sphere (the
  normalised mean direction) and the true sun: smooth in the error however far off the guess is;
- ``sun_vis``: binary cross-entropy of the sun head's visibility logit against ``sun_visible``;
- ``sun_energy``: L1 on ``log(E + SUN_ENERGY_EPS)`` (RGB) against the true sun energy
  (:func:`sun_energy`; 0 for skies without a visible sun; only skies with one when the model predicts
  the visibility, which then decides whether a sun is rendered);
- ``sun_peak``: L1 on ``log1p`` of the full predicted sky (sun included) over the target's brightest
  0.1 % of pixels (the sun's peak);
- ``sun_size``: L1 on the log of the sun's angular size against the true sun's (:func:`sun_size`). The
  size gets no gradient from the radiance terms (the sun is rendered with a detached size): measured
  in training, a size free to follow the peak L1 grows to the largest allowed (4°) while the direction
  is uncertain, a hedge that leaves a blob the detector rightly refuses as a sun;
- ``distance``: L1 of plane distance divided by the scene's median plane distance (per image).

The truth sun (``batch["sun_dir"] (B, 3)``, ``batch["sun_visible"] (B,)``) is what the default
detector (:func:`solidkit.envmap.detect_sun`) finds in the target sky.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.filters import otsu_threshold
from kornia.losses import ssim_loss

from solidkit.envmap.coords import direction_grid, solid_angle
from solidkit.envmap.io import PAPER_EXPOSURE, PAPER_GAMMA, tonemap
from solidkit.envmap.sh import diffuse_convolution, lambertian_sphere, sh_render
from solidkit.model.blocks import log_from_radiance
from solidkit.model.sunhead import SIGMA_MAX, SIGMA_MIN, log_solid_angle

__all__ = [
    "masked_mean",
    "albedo_loss",
    "normal_loss",
    "distance_loss",
    "shadow_loss",
    "hdr_l1_loss",
    "sup1_loss",
    "sun_terms",
    "sup2_loss",
    "diffuse_loss",
    "sh_shading",
    "non_shadow_mask",
    "reconstruction_loss",
    "tonemapped_ssim_loss",
    "solidnet_losses",
    "relative_distance_loss",
    "sun_energy",
    "sun_direction_loss",
    "sun_cosine_loss",
    "sun_visibility_loss",
    "sun_energy_loss",
    "sun_peak_loss",
    "sun_size",
    "sun_size_loss",
    "sky_away_from_sun_loss",
    "SUN_CAP",
    "SUN_TARGET_SIGMA",
    "SUN_ENERGY_EPS",
]

SUN_CAP = math.radians(3.0)
"""Radius of the cap about the sun that holds its energy at the model's resolution (radians)."""
SUN_ANNULUS = (math.radians(4.0), math.radians(8.0))
"""Ring about the sun whose median radiance is the sky under the sun (radians)."""
SUN_TARGET_SIGMA = math.radians(2.0)
"""Standard deviation of the Gaussian target of the sun-direction cross-entropy (radians)."""
SUN_ENERGY_EPS = 1e-2
"""Offset of the log in the sun-energy loss (radiance x sr; skies are scaled to irradiance ~pi)."""


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


def relative_distance_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """L1 on plane distance ``(B, 1, H, W)`` divided by each image's median target distance (over ``mask``).

    Unitless and scale-free: a 1 m error on a facade 5 m away weighs as much as 10 m on one 50 m
    away, and no far plane dominates the total loss.
    """
    b = target.shape[0]
    m = torch.ones_like(target, dtype=torch.bool) if mask is None else mask.bool().expand_as(target)
    scales = []
    for i in range(b):
        vals = target[i][m[i]]
        scales.append(vals.median() if vals.numel() else target.new_tensor(1.0))
    scale = torch.stack(scales).clamp_min(0.5).detach()[:, None, None, None]
    return masked_mean((pred - target).abs() / scale, m)


def _cos_to(directions: torch.Tensor, height: int) -> torch.Tensor:
    """``cos`` of the angle between every pixel of a ``(height, 2 height)`` panorama and ``directions (B, 3)``."""
    grid = direction_grid(height, torch, dtype=directions.dtype, device=directions.device)
    return torch.einsum("hwk,bk->bhw", grid, directions)


def sun_energy(
    sky: torch.Tensor,
    direction: torch.Tensor,
    visible: torch.Tensor | None = None,
    cap: float = SUN_CAP,
    annulus: tuple[float, float] = SUN_ANNULUS,
) -> torch.Tensor:
    """Energy ``(B, C)`` (radiance x sr) of the sun at ``direction (B, 3)`` in ``sky (B, C, H, 2H)``.

    ``sum over the cap of max(L - L_bg, 0) Omega`` with ``L_bg`` the per-channel median of the
    ``annulus`` about the sun (the sky under it); 0 where ``visible (B,)`` is false. On coarse grids the
    cap is widened to 1.5 pixels and the annulus moved out with it (a cap must hold a pixel centre).
    """
    b, c, h, w = sky.shape
    px = math.pi / h
    cap = max(cap, 1.5 * px)
    annulus = (max(annulus[0], cap + px), max(annulus[1], cap + 4 * px))
    cos = _cos_to(direction, h)
    omega = solid_angle(h, torch, dtype=sky.dtype, device=sky.device)
    ring = (cos < math.cos(annulus[0])) & (cos > math.cos(annulus[1]))
    bg = torch.stack([sky[i][:, ring[i]].median(dim=1).values if ring[i].any() else sky.new_zeros(c) for i in range(b)])
    inside = (cos > math.cos(cap)).to(sky.dtype)
    e = ((sky - bg[:, :, None, None]).clamp_min(0.0) * (inside * omega)[:, None]).sum(dim=(2, 3))
    if visible is not None:
        e = e * (visible > 0.5).to(e.dtype)[:, None]
    return e


def sun_size(
    sky: torch.Tensor, direction: torch.Tensor, cap: float = SUN_CAP, annulus: tuple[float, float] = SUN_ANNULUS
) -> torch.Tensor:
    """Angular standard deviation ``(B,)`` (radians) of the sun at ``direction (B, 3)`` in ``sky (B, C, H, 2H)``.

    ``sqrt(sum w (1 - cos t) / sum w)`` over the cap, ``w`` the luminance above the annulus median
    times the solid angle: for ``L ∝ exp((cos t - 1) / sigma^2)`` this is ``sigma`` (the model's
    parameterisation, :func:`solidkit.model.sunhead.render_sun`).
    """
    b, c, h, w = sky.shape
    px = math.pi / h
    cap = max(cap, 1.5 * px)
    annulus = (max(annulus[0], cap + px), max(annulus[1], cap + 4 * px))
    lum = sky.mean(dim=1)
    cos = _cos_to(direction, h)
    omega = solid_angle(h, torch, dtype=sky.dtype, device=sky.device)
    ring = (cos < math.cos(annulus[0])) & (cos > math.cos(annulus[1]))
    bg = torch.stack([lum[i][ring[i]].median() if ring[i].any() else lum.new_zeros(()) for i in range(b)])
    wgt = (lum - bg[:, None, None]).clamp_min(0.0) * (cos > math.cos(cap)).to(sky.dtype) * omega
    # float32 rounding makes 1 - cos slightly negative at a one-pixel sun's own centre
    return torch.sqrt(((wgt * (1.0 - cos)).sum(dim=(1, 2)) / wgt.sum(dim=(1, 2)).clamp_min(1e-12)).clamp_min(0.0))


def sun_size_loss(
    sigma: torch.Tensor, sky: torch.Tensor, direction: torch.Tensor, visible: torch.Tensor
) -> torch.Tensor:
    """L1 between ``log sigma~ (B,)`` and the log of the true sun's :func:`sun_size` (clamped to the head's
    range), over skies with a visible sun."""
    keep = visible > 0.5
    if not keep.any():
        return sigma.sum() * 0.0
    return _size_l1(sigma[keep], sun_size(sky[keep], direction[keep]).detach())


def _size_l1(sigma: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """Mean ``|log sigma - log true|``, ``true`` clamped to the sun head's range of sizes."""
    return (torch.log(sigma) - torch.log(true.clamp(SIGMA_MIN, SIGMA_MAX))).abs().mean()


def sun_terms(
    out: dict[str, torch.Tensor],
    direction: torch.Tensor,
    visible: torch.Tensor,
    energy: torch.Tensor,
    size: torch.Tensor,
    sun_sigma: float = SUN_TARGET_SIGMA,
) -> dict[str, torch.Tensor]:
    """The sun head's own terms from known targets (the sun stage of training, whose crops carry their
    sun's ``direction (B, 3)``, ``visible (B,)``, ``energy (B, 3)`` and angular ``size (B,)`` radians instead
    of a sky): ``sun_dir``, ``sun_cos``, ``sun_vis``, ``sun_energy`` (skies with a sun) and ``sun_size``
    (:func:`sun_size_loss`'s log L1)."""
    keep = visible > 0.5
    zero = out["sun_log_energy"].sum() * 0.0
    terms = {
        "sun_dir": sun_direction_loss(out["sun_logits"], direction, visible, sun_sigma),
        "sun_cos": sun_cosine_loss(out["sun_logits"], direction, visible),
        "sun_vis": sun_visibility_loss(out["sun_visible_logit"], visible),
    }
    if keep.any():
        terms["sun_energy"] = sun_energy_loss(out["sun_log_energy"][keep], energy[keep])
        terms["sun_size"] = _size_l1(out["sun_sigma"][keep], size[keep])
    else:
        terms["sun_energy"] = terms["sun_size"] = zero
    return terms


def sun_direction_loss(
    logits: torch.Tensor, direction: torch.Tensor, visible: torch.Tensor, sigma: float = SUN_TARGET_SIGMA
) -> torch.Tensor:
    """Cross-entropy of ``p ∝ exp(logits) Omega`` (``logits (B, 1, H, 2H)``) against a Gaussian of
    ``sigma`` radians at ``direction (B, 3)``, over skies with ``visible (B,)``, divided by ``log(H W)``."""
    b, _, h, w = logits.shape
    keep = visible > 0.5
    if not keep.any():
        return logits.sum() * 0.0
    logp = torch.log_softmax((logits[:, 0] + log_solid_angle(h, logits)).reshape(b, -1), dim=1)
    cos = _cos_to(direction, h).reshape(b, -1)
    q = torch.softmax((cos - 1.0) / sigma**2 + log_solid_angle(h, logits).reshape(1, -1), dim=1)
    ce = -(q * logp).sum(dim=1)
    return ce[keep].mean() / math.log(h * w)


def sun_cosine_loss(logits: torch.Tensor, direction: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """``1 - cos`` between the soft-argmax of ``p ∝ exp(logits) Omega`` over the whole sphere (the normalised
    probability-weighted mean direction; ``logits (B, 1, H, 2H)``) and ``direction (B, 3)``, over skies
    with ``visible (B,)``. 0 when aligned, 2 when opposite."""
    b, _, h, w = logits.shape
    keep = visible > 0.5
    if not keep.any():
        return logits.sum() * 0.0
    p = torch.softmax((logits[:, 0] + log_solid_angle(h, logits)).reshape(b, -1), dim=1)
    grid = direction_grid(h, torch, dtype=logits.dtype, device=logits.device).reshape(-1, 3)
    mean = F.normalize(p @ grid, dim=-1, eps=1e-8)
    return (1.0 - (mean * direction).sum(dim=-1))[keep].mean()


def sun_visibility_loss(logit: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the visibility ``logit (B,)`` against ``visible (B,)`` (1 = a sun is visible)."""
    return F.binary_cross_entropy_with_logits(logit, (visible > 0.5).to(logit.dtype))


def sun_energy_loss(log_energy: torch.Tensor, energy: torch.Tensor, eps: float = SUN_ENERGY_EPS) -> torch.Tensor:
    """L1 between ``log(E~ + eps)`` (from the predicted ``log E~ (B, C)``) and ``log(E + eps)``."""
    pred = torch.logaddexp(log_energy, torch.full_like(log_energy, math.log(eps)))
    return (pred - torch.log(energy + eps)).abs().mean()


def sun_peak_loss(sky_log: torch.Tensor, target: torch.Tensor, fraction: float = 1e-3) -> torch.Tensor:
    """L1 on ``log1p`` over the target's brightest ``fraction`` of pixels (by mean over channels), per image."""
    b, c, h, w = target.shape
    k = max(1, int(round(fraction * h * w)))
    idx = target.mean(dim=1).reshape(b, -1).topk(k, dim=1).indices  # (B, k)
    p = sky_log.reshape(b, c, -1).gather(2, idx[:, None].expand(b, c, k))
    t = log_from_radiance(target.reshape(b, c, -1).gather(2, idx[:, None].expand(b, c, k)))
    return (p - t).abs().mean()


def sky_away_from_sun_loss(
    sky_log: torch.Tensor, target: torch.Tensor, direction: torch.Tensor, visible: torch.Tensor, cap: float = SUN_CAP
) -> torch.Tensor:
    """L1 on ``log1p`` over the pixels farther than ``cap`` from the true sun (all pixels without one)."""
    h = target.shape[-2]
    near = (_cos_to(direction, h) > math.cos(cap)) & (visible > 0.5)[:, None, None]
    return masked_mean((sky_log - log_from_radiance(target)).abs(), ~near[:, None])


def shadow_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """L2 on the shadow map ``(B, 1, H, W)``."""
    return masked_mean((pred - target) ** 2, mask)


def hdr_l1_loss(pred_log: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L1 between the model's ``y = log1p(H~)`` and ``log1p(H)`` of the target radiance."""
    return (pred_log - log_from_radiance(target)).abs().mean()


def sup1_loss(
    out: dict[str, torch.Tensor],
    batch: dict[str, torch.Tensor],
    variant: str = "paper",
    sun_sigma: float = SUN_TARGET_SIGMA,
) -> dict[str, torch.Tensor]:
    """The terms of ``L_sup1`` (keys ``albedo, normal, distance, shadow, sky``) that both the
    model output and the batch provide (a sky-only baseline gets ``sky`` alone).

    ``variant="located"`` adds the sun terms and uses the relative plane distance (module docstring);
    ``sun_sigma`` (radians) is the width of the sun-direction target.
    """
    mask = batch.get("geometry_mask")
    located = variant == "located"
    pixel_terms = {
        "albedo": albedo_loss,
        "normal": normal_loss,
        "distance": relative_distance_loss if located else distance_loss,
        "shadow": shadow_loss,
    }
    terms = {k: f(out[k], batch[k], mask) for k, f in pixel_terms.items() if k in out and k in batch}
    if "sky_log" in out and "sky" in batch:
        if located and "sun_logits" in out and "sun_dir" in batch:
            sky, sd, vis = batch["sky"], batch["sun_dir"], batch["sun_visible"]
            terms["sky"] = sky_away_from_sun_loss(out["sky_np_log"], sky, sd, vis)
            terms["sun_dir"] = sun_direction_loss(out["sun_logits"], sd, vis, sun_sigma)
            terms["sun_cos"] = sun_cosine_loss(out["sun_logits"], sd, vis)
            if "sun_visible_logit" in out:
                terms["sun_vis"] = sun_visibility_loss(out["sun_visible_logit"], vis)
                keep = vis > 0.5
                terms["sun_energy"] = (
                    sun_energy_loss(out["sun_log_energy"][keep], sun_energy(sky[keep], sd[keep]))
                    if keep.any()
                    else out["sun_log_energy"].sum() * 0.0
                )
            else:
                terms["sun_energy"] = sun_energy_loss(out["sun_log_energy"], sun_energy(sky, sd, vis))
            terms["sun_peak"] = sun_peak_loss(out["sky_log"], sky)
            terms["sun_size"] = sun_size_loss(out["sun_sigma"], sky, sd, vis)
        else:
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
    consistent: bool = False,
) -> torch.Tensor:
    """``L_rec`` (eq. 7): masked mean of ``(I - (A ⊙ L B(N))^(1/gamma))^2`` over ``mask (B, 1, H, W)``.

    ``image (B, 3, H, W)`` is the LDR input in [0, 1]; the shading is clamped at a small positive
    value before the power (its derivative is unbounded at 0).

    ``consistent=True`` (variant ``"located"``) renders the pixel the way the input was made instead:
    ``T(A ⊙ 2 L B(N))`` with the paper's tonemap ``T`` (exposure ``2^-0.3``, clip). ``L_dif`` ties
    ``L b(n)`` to ``D = E / 2 pi`` (a cosine-weighted hemisphere *mean*), while a Lambertian pixel is
    ``A E / pi`` before the input's tonemap; eq. 7 as written asks for an ``L`` ``2 * 2^-0.3 ≈ 1.62``
    times smaller than ``L_dif`` does, and the two terms pull ``P_SH`` apart.
    """
    shading = sh_shading(normal, sh, rotation)
    if consistent:
        rendered = tonemap((albedo * 2.0 * shading).clamp_min(1e-6))
    else:
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
    variant: str = "paper",
    sun_sigma: float = SUN_TARGET_SIGMA,
) -> dict[str, torch.Tensor]:
    """All terms of ``L_I = L_sup1 + L_dif + L_rec`` and ``L_P = L_sup2 + L_tom`` for one batch.

    ``out`` is :meth:`SolidNet.forward`'s output; ``batch`` holds the ground truth (see
    :mod:`solidkit.model.solidnet`). Terms whose inputs are absent are skipped (e.g. P-Net terms
    when ``out`` has no ``local_log``). ``sun_sigma``: width of the sun-direction target (radians).
    Returns every weighted term plus ``inet``, ``pnet`` and ``total``.
    """
    w = weights or {}
    terms: dict[str, torch.Tensor] = {}
    terms.update(sup1_loss(out, batch, variant, sun_sigma))
    if "sh" in out and "sky" in out:
        terms["dif"] = diffuse_loss(out["sky"], out["sh"])
    if "sh" in out and "albedo" in out and "image" in batch and "geometry_mask" in batch:
        # sky-only samples (panorama crops, no geometry_mask) have no surfaces to reconstruct
        shadow = batch.get("shadow", out["shadow"])
        mask = non_shadow_mask(shadow, batch.get("geometry_mask"))
        terms["rec"] = reconstruction_loss(
            batch["image"],
            out["albedo"],
            out["normal"],
            out["sh"],
            mask,
            out.get("rotation"),
            consistent=variant == "located",
        )
    if "local_log" in out and "local" in batch:
        terms["local"] = sup2_loss(out["local_log"], batch["local"])
        terms["tom"] = tonemapped_ssim_loss(out["local"], batch["local"])
    weighted = {k: v * w.get(k, 1.0) for k, v in terms.items()}
    zero = next(iter(out.values())).new_zeros(())
    inet = sum((v for k, v in weighted.items() if k not in ("local", "tom")), zero)
    pnet = sum((v for k, v in weighted.items() if k in ("local", "tom")), zero)
    return {**weighted, "inet": inet, "pnet": pnet, "total": inet + pnet}
