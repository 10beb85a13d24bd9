"""The global and local map metrics of the paper, as small functions over NumPy panoramas.

Zhu et al., "Spatially-Varying Outdoor Lighting Estimation from Intrinsics", CVPR 2021, §5 and
supplementary Table 1: MAE of the (normalised) HDR global map, and SSIM / MAE of the local probes (on
LDR probes for the real set).

Global map
    :func:`global_mae`: the paper's ``xi_HDR``, the MAE of the *normalised* HDR sky maps, over the
    upper hemisphere (a real truth map, taken at the camera position, also holds the ground; the
    predicted global map is the sky). Each map is divided by its solid-angle-weighted mean radiance
    there (so the score does not depend on the prediction's absolute units, which a real capture
    does not share), then the per-pixel absolute difference is averaged over pixels and channels
    (plain pixel mean, as the paper's numbers are).

Local probes against LDR (the real set)
    A real probe is an 8-bit sRGB LDR panorama whose exposure is unknown to the model and whose
    bright pixels (the sun, bright sky) are clipped. Before comparison the HDR prediction ``H`` is

    1. *exposed*: multiplied by the scale ``s`` that best matches the probe, ``log s =
       median(log Y_probe - log Y_pred)`` over the usable pixels (not saturated, probe linear
       luminance above :data:`DARK_FLOOR`), with ``Y`` the Rec. 709 luminance and the probe
       linearised by the sRGB decoding (:func:`exposure_scale`). The comparison is therefore
       invariant to the exposure of either side;
    2. *tonemapped like the camera*: ``T(H) = srgb_encode(clip(s H, 0, 1))`` (:func:`ldr_from_hdr`);
    3. compared with the probe on the unsaturated pixels only: the prediction is set equal to the
       probe on saturated pixels (so they add no difference to any SSIM window) and the SSIM map
       (:func:`kornia.metrics.ssim`, 11 x 11 Gaussian window) and the absolute difference are
       averaged over the unsaturated pixels and the channels (:func:`local_ldr_metrics`).

    A probe pixel is saturated when any channel is at or above :data:`SATURATION_LEVEL` (or where
    the test set's saturation mask says so). For synthetic data, :func:`simulate_ldr_probe` makes
    such an LDR probe from the HDR one (auto exposure to a mean of 0.18, clipping, 8-bit sRGB), so
    that synthetic and real numbers are the same metric and the sim-to-real gap is one table.

Local probes against HDR (synthetic only)
    :func:`local_hdr_metrics`: SSIM of the paper's tonemap ``clip((2^-0.3 H)^(1/2.2), 0, 1)`` (its
    ``L_tom``) and MAE of ``log1p`` radiance, both in the training data's units.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import torch
from kornia.metrics import ssim as kornia_ssim

from solidkit.envmap.coords import solid_angle
from solidkit.envmap.io import srgb_decode, srgb_encode, tonemap
from solidkit.envmap.sun import luminance

__all__ = [
    "SATURATION_LEVEL",
    "DARK_FLOOR",
    "SSIM_WINDOW",
    "global_mae",
    "saturation_mask",
    "exposure_scale",
    "ldr_from_hdr",
    "masked_ssim",
    "local_ldr_metrics",
    "local_hdr_metrics",
    "simulate_ldr_probe",
]

SATURATION_LEVEL = 250.0 / 255.0
"""An LDR probe pixel with any channel at or above this (sRGB-encoded, [0, 1]) is saturated."""

DARK_FLOOR = 2e-3
"""Probe pixels darker than this linear luminance (8-bit quantisation and noise) do not set the exposure."""

SSIM_WINDOW = 11
"""SSIM Gaussian window (pixels), as the paper's ``L_tom`` and kornia's default."""


def _normalised(pano: np.ndarray, region: np.ndarray) -> np.ndarray:
    w = solid_angle(pano.shape[0])[:, :, None] * region[..., None]
    mean = float((pano * w).sum() / (w.sum() * pano.shape[2])) if w.sum() > 0 else 0.0
    return pano / mean if mean > 0 else np.zeros_like(pano)


def global_mae(
    predicted: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None, sky_only: bool = True
) -> float:
    """The paper's ``xi_HDR``: MAE of the normalised HDR global (sky) maps ``(H, 2H, 3)``.

    The region compared: the upper hemisphere (elevation > 0, the sky map the paper predicts; a real
    truth map taken at the camera position also holds the ground) with ``sky_only``, intersected with
    ``valid (H, 2H)`` (e.g. unsaturated truth pixels). Each map is divided by its solid-angle-weighted
    mean radiance over that region, then ``|a - b|`` is averaged over its pixels and the channels
    (plain pixel mean, as the paper's numbers are). Unitless; NaN for an empty region.
    """
    a = np.asarray(predicted, dtype=np.float64)[..., :3]
    b = np.asarray(truth, dtype=np.float64)[..., :3]
    region = np.ones(a.shape[:2], dtype=bool)
    if sky_only:
        region[a.shape[0] // 2 :] = False
    if valid is not None:
        region &= np.asarray(valid, dtype=bool)
    if not region.any():
        return float("nan")
    diff = np.abs(_normalised(a, region) - _normalised(b, region)).mean(axis=-1)
    return float(diff[region].mean())


def saturation_mask(
    probe_ldr: np.ndarray, mask: np.ndarray | None = None, level: float = SATURATION_LEVEL
) -> np.ndarray:
    """Saturated pixels ``(H, W)`` bool of an sRGB-encoded LDR probe ``(H, W, 3)`` in [0, 1].

    A pixel is saturated when any channel is ``>= level``, or where ``mask`` (e.g. the test set's
    saturation mask, any shape broadcastable to ``(H, W)``) is true.
    """
    sat = np.asarray(probe_ldr)[..., :3].max(axis=-1) >= level
    if mask is not None:
        m = np.asarray(mask)
        sat |= (m[..., 0] if m.ndim == 3 else m).astype(bool)
    return cast(np.ndarray, sat)


def exposure_scale(predicted_hdr: np.ndarray, probe_ldr: np.ndarray, saturated: np.ndarray) -> float:
    """The scale ``s`` that exposes an HDR prediction like the LDR probe (see the module docstring).

    ``log s = median(log Y_probe - log Y_pred)`` over unsaturated pixels with probe luminance above
    :data:`DARK_FLOOR` and a positive prediction; 1 when no pixel qualifies. Scaling the prediction
    by ``k`` divides ``s`` by ``k``.
    """
    y_probe = luminance(srgb_decode(np.asarray(probe_ldr, dtype=np.float32)[..., :3]))
    y_pred = luminance(np.asarray(predicted_hdr, dtype=np.float32)[..., :3])
    use = (~saturated) & (y_probe > DARK_FLOOR) & (y_pred > 0)
    if not use.any():
        return 1.0
    return float(np.exp(np.median(np.log(y_probe[use]) - np.log(y_pred[use]))))


def ldr_from_hdr(hdr: np.ndarray, scale: float) -> np.ndarray:
    """``srgb_encode(clip(scale * H, 0, 1))``: an HDR panorama as the LDR camera would record it."""
    return cast(
        np.ndarray,
        srgb_encode(np.clip(np.asarray(hdr, dtype=np.float32) * np.float32(scale), 0.0, 1.0)).astype(np.float32),
    )


def _chw(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(np.asarray(a, dtype=np.float32).transpose(2, 0, 1)))[None]


def masked_ssim(a: np.ndarray, b: np.ndarray, valid: np.ndarray | None = None, window: int = SSIM_WINDOW) -> float:
    """Mean of kornia's SSIM map between ``(H, W, 3)`` images in [0, 1] over ``valid (H, W)`` pixels."""
    m = kornia_ssim(_chw(a), _chw(b), window, max_val=1.0)[0].mean(dim=0).numpy()
    if valid is not None:
        m = m[np.asarray(valid, dtype=bool)]
    return float(m.mean()) if m.size else float("nan")


def local_ldr_metrics(
    predicted_hdr: np.ndarray, probe_ldr: np.ndarray, saturated: np.ndarray | None = None
) -> dict[str, float]:
    """SSIM and MAE of an HDR local prediction against an LDR probe (both ``(H, 2H, 3)``).

    ``probe_ldr`` is sRGB-encoded in [0, 1]; ``saturated (H, 2H)`` adds to the pixels found by
    :func:`saturation_mask`. Returns ``ssim``, ``mae`` (on the sRGB-encoded [0, 1] scale), ``scale``
    (the exposure :func:`exposure_scale` chose) and ``valid_fraction`` (unsaturated pixels). With no
    unsaturated pixel the scores are NaN.
    """
    probe = np.asarray(probe_ldr, dtype=np.float32)[..., :3]
    sat = saturation_mask(probe, saturated)
    s = exposure_scale(predicted_hdr, probe, sat)
    pred = ldr_from_hdr(np.asarray(predicted_hdr)[..., :3], s)
    pred = np.where(sat[..., None], probe, pred)  # saturated pixels carry no difference into any window
    valid = ~sat
    mae = float(np.abs(pred - probe)[valid].mean()) if valid.any() else float("nan")
    return {"ssim": masked_ssim(pred, probe, valid), "mae": mae, "scale": s, "valid_fraction": float(valid.mean())}


def local_hdr_metrics(predicted_hdr: np.ndarray, truth_hdr: np.ndarray) -> dict[str, float]:
    """Synthetic probes: SSIM of the paper's tonemap (``L_tom``'s) and MAE of ``log1p`` radiance."""
    p = np.asarray(predicted_hdr, dtype=np.float32)[..., :3]
    t = np.asarray(truth_hdr, dtype=np.float32)[..., :3]
    return {
        "ssim_tonemap": masked_ssim(tonemap(p), tonemap(t)),
        "mae_log1p": float(np.abs(np.log1p(np.clip(p, 0, None)) - np.log1p(np.clip(t, 0, None))).mean()),
    }


def simulate_ldr_probe(hdr: np.ndarray, key: float = 0.18) -> tuple[np.ndarray, np.ndarray]:
    """An LDR capture of an HDR probe: auto exposure, clipping, 8-bit sRGB.

    The exposure maps the probe's mean linear luminance to ``key`` (a camera's averaging meter aims
    at middle grey); values are then clipped to [0, 1], sRGB-encoded and quantised to 8 bits.
    Returns the probe ``(H, W, 3)`` float32 in [0, 1] and its saturation mask ``(H, W)`` bool.
    """
    hdr = np.clip(np.asarray(hdr, dtype=np.float32)[..., :3], 0.0, None)
    mean = float(luminance(hdr).mean())
    exposed = hdr * np.float32(key / mean) if mean > 0 else hdr
    ldr = np.round(srgb_encode(np.clip(exposed, 0.0, 1.0)) * 255.0) / 255.0
    return ldr.astype(np.float32), exposed.max(axis=-1) >= 1.0
