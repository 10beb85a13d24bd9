"""The paper's evaluation metrics, as small functions over NumPy panoramas.

Zhu et al., "Spatially-Varying Outdoor Lighting Estimation from Intrinsics", CVPR 2021, §5 and
supplementary Table 1: sun azimuth / elevation error from the predicted global map, MAE of the
(normalised) HDR global map, and SSIM / MAE of the local probes (on LDR probes for the real set).

Sun
    The sun of a predicted map is found with :func:`solidkit.envmap.sun.detect_sun`, never with a
    second finder: ``"paper"`` is the paper's recipe taken literally (brightest 2 %, largest
    component, its centroid) and, as in the paper, it always answers (``min_contrast=0``: only a
    black or constant map has no sun); ``"core"`` is the package's default detector, which may say
    "no sun". A prediction without a sun is never dropped silently: :func:`sun_statistics` reports
    the no-sun rate next to every error statistic. Errors: azimuth ``|wrap(phi_p - phi_t)|`` in
    [0°, 180°], elevation ``|theta_p - theta_t|``, and the angle between the two directions
    (conventions §3, §6).

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

Confidence intervals
    :func:`bootstrap_ci`: percentile bootstrap (:func:`scipy.stats.bootstrap`), resampling whole
    scenes when groups are given, since probes of one scene are not independent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import torch
from kornia.metrics import ssim as kornia_ssim
from scipy import stats

from solidkit.envmap.coords import angles_from_direction, angular_distance, solid_angle
from solidkit.envmap.io import srgb_decode, srgb_encode, tonemap
from solidkit.envmap.sun import SunDetection, detect_sun, luminance

__all__ = [
    "SATURATION_LEVEL",
    "DARK_FLOOR",
    "SSIM_WINDOW",
    "SUN_METHODS",
    "SunError",
    "find_sun",
    "sun_error",
    "sun_statistics",
    "global_mae",
    "saturation_mask",
    "exposure_scale",
    "ldr_from_hdr",
    "masked_ssim",
    "local_ldr_metrics",
    "local_hdr_metrics",
    "simulate_ldr_probe",
    "bootstrap_ci",
    "summarise",
]

SATURATION_LEVEL = 250.0 / 255.0
"""An LDR probe pixel with any channel at or above this (sRGB-encoded, [0, 1]) is saturated."""

DARK_FLOOR = 2e-3
"""Probe pixels darker than this linear luminance (8-bit quantisation and noise) do not set the exposure."""

SSIM_WINDOW = 11
"""SSIM Gaussian window (pixels), as the paper's ``L_tom`` and kornia's default."""

SUN_METHODS = ("paper", "core")
"""The sun recipes evaluated: the paper's (always answers) and the package's default detector."""


# --------------------------------------------------------------------------------------------- sun


def find_sun(sky: np.ndarray, method: str) -> SunDetection:
    """The sun of a predicted global map ``(H, 2H, 3)`` linear radiance, by ``method``.

    ``"paper"`` runs :func:`~solidkit.envmap.sun.sun_paper` as the paper computes it: every map
    gets an answer (``min_contrast=0``). ``"core"`` runs the default detector unchanged.
    """
    if method == "paper":
        return detect_sun(sky, "paper", min_contrast=0.0)
    return detect_sun(sky, method)


@dataclass(frozen=True)
class SunError:
    """Sun-position errors of one prediction, degrees (``None`` when the prediction has no sun)."""

    found: bool
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    angle_deg: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {"found": self.found, "azimuth_deg": self.azimuth_deg, "elevation_deg": self.elevation_deg,
                "angle_deg": self.angle_deg}


def sun_error(predicted: np.ndarray | None, truth: np.ndarray) -> SunError:
    """Errors between a predicted sun direction ``(3,)`` (or ``None``: no sun) and the true one ``(3,)``.

    Azimuth error: ``|phi_p - phi_t|`` wrapped to [0°, 180°]; elevation error: ``|theta_p - theta_t|``;
    angle: the great-circle distance. Directions are in the panorama frame (conventions §3).
    """
    if predicted is None:
        return SunError(found=False)
    p = np.asarray(predicted, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    p, t = p / np.linalg.norm(p), t / np.linalg.norm(t)
    (phi_p, th_p), (phi_t, th_t) = angles_from_direction(p), angles_from_direction(t)
    daz = abs((float(phi_p) - float(phi_t) + math.pi) % (2 * math.pi) - math.pi)
    return SunError(True, math.degrees(daz), math.degrees(abs(float(th_p) - float(th_t))),
                    math.degrees(float(angular_distance(p, t))))


def sun_statistics(errors: Sequence[SunError]) -> dict[str, Any]:
    """Counts, the no-sun rate and the median / mean of each error over the predictions with a sun."""
    n = len(errors)
    found = [e for e in errors if e.found]
    out: dict[str, Any] = {"n": n, "found": len(found), "no_sun_rate": (1 - len(found) / n) if n else None}
    for key in ("azimuth_deg", "elevation_deg", "angle_deg"):
        v = np.array([getattr(e, key) for e in found], dtype=np.float64)
        out[key] = {"median": float(np.median(v)) if v.size else None, "mean": float(v.mean()) if v.size else None}
    return out


# --------------------------------------------------------------------------------------- global map


def _normalised(pano: np.ndarray, region: np.ndarray) -> np.ndarray:
    w = solid_angle(pano.shape[0])[:, :, None] * region[..., None]
    mean = float((pano * w).sum() / (w.sum() * pano.shape[2])) if w.sum() > 0 else 0.0
    return pano / mean if mean > 0 else np.zeros_like(pano)


def global_mae(predicted: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None, sky_only: bool = True) -> float:
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
        region[a.shape[0] // 2:] = False
    if valid is not None:
        region &= np.asarray(valid, dtype=bool)
    if not region.any():
        return float("nan")
    diff = np.abs(_normalised(a, region) - _normalised(b, region)).mean(axis=-1)
    return float(diff[region].mean())


# --------------------------------------------------------------------------------- local probes (LDR)


def saturation_mask(probe_ldr: np.ndarray, mask: np.ndarray | None = None, level: float = SATURATION_LEVEL) -> np.ndarray:
    """Saturated pixels ``(H, W)`` bool of an sRGB-encoded LDR probe ``(H, W, 3)`` in [0, 1].

    A pixel is saturated when any channel is ``>= level``, or where ``mask`` (e.g. the test set's
    saturation mask, any shape broadcastable to ``(H, W)``) is true.
    """
    sat = np.asarray(probe_ldr)[..., :3].max(axis=-1) >= level
    if mask is not None:
        m = np.asarray(mask)
        sat |= (m[..., 0] if m.ndim == 3 else m).astype(bool)
    return sat


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
    return srgb_encode(np.clip(np.asarray(hdr, dtype=np.float32) * np.float32(scale), 0.0, 1.0)).astype(np.float32)


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
    return {"ssim_tonemap": masked_ssim(tonemap(p), tonemap(t)),
            "mae_log1p": float(np.abs(np.log1p(np.clip(p, 0, None)) - np.log1p(np.clip(t, 0, None))).mean())}


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


# ------------------------------------------------------------------------------------- statistics


def _cluster_bootstrap(v: np.ndarray, group_index: np.ndarray, n_groups: int, statistic: Callable, n: int,
                       rng: np.random.Generator) -> np.ndarray | None:
    """``statistic`` (``np.mean`` or ``np.median``) of ``n`` cluster resamples, vectorised: each
    resample draws ``n_groups`` groups with replacement and takes every value of each drawn group
    (as often as it was drawn). ``None`` for another statistic."""
    idx = rng.integers(0, n_groups, size=(n, n_groups))
    counts = np.zeros((n, n_groups))
    np.add.at(counts, (np.arange(n)[:, None], idx), 1.0)
    w = counts[:, group_index]  # (n, N): how often each value is in each resample
    if statistic is np.mean:
        return (w @ v) / w.sum(axis=1)
    if statistic is np.median:
        order = np.argsort(v, kind="stable")
        vs, cum = v[order], np.cumsum(w[:, order], axis=1)
        total = cum[:, -1].astype(np.int64)
        lo = (cum <= ((total - 1) // 2)[:, None]).sum(axis=1)  # first sorted value past position (T-1)//2
        hi = (cum <= (total // 2)[:, None]).sum(axis=1)
        return 0.5 * (vs[lo] + vs[hi])
    return None


def bootstrap_ci(
    values: Sequence[float],
    statistic: Callable[[np.ndarray], float] = np.median,
    groups: Sequence[Any] | None = None,
    *,
    n_resamples: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``statistic(values)`` (NaNs dropped).

    With ``groups`` (e.g. scene ids, one per value) whole groups are resampled (cluster bootstrap),
    since values of one scene are correlated; SciPy has no cluster bootstrap, so for the mean and
    the median it is done here, vectorised (other statistics go through SciPy with the scenes as
    the resampled data). Without groups: :func:`scipy.stats.bootstrap` (``method="percentile"``).
    Returns ``(low, high)``; ``(nan, nan)`` without values; the statistic itself for a constant
    sample or a single group.
    """
    v = np.asarray(values, dtype=np.float64)
    keep = np.isfinite(v)
    v = v[keep]
    rng = np.random.default_rng(seed)
    if v.size == 0:
        return math.nan, math.nan
    if np.all(v == v[0]):
        return float(statistic(v)), float(statistic(v))
    alpha = 100 * (1 - level) / 2
    if groups is None:
        if v.size < 2:
            return float(statistic(v)), float(statistic(v))
        vec = statistic in (np.mean, np.median)
        res = stats.bootstrap((v,), statistic, n_resamples=n_resamples, confidence_level=level, method="percentile",
                              random_state=rng, vectorized=vec, **({"axis": -1} if vec else {}))
        return float(res.confidence_interval.low), float(res.confidence_interval.high)
    g = np.asarray(list(groups), dtype=object)[keep]
    names = list(dict.fromkeys(g.tolist()))
    if len(names) < 2:
        return float(statistic(v)), float(statistic(v))
    gi = np.array([names.index(x) for x in g.tolist()])
    boot = _cluster_bootstrap(v, gi, len(names), statistic, n_resamples, rng)
    if boot is None:
        members = [v[gi == k] for k in range(len(names))]
        res = stats.bootstrap((np.arange(len(names)),), lambda idx: statistic(np.concatenate([members[int(i)] for i in idx])),
                              n_resamples=n_resamples, confidence_level=level, method="percentile",
                              random_state=rng, vectorized=False)
        return float(res.confidence_interval.low), float(res.confidence_interval.high)
    lo, hi = np.percentile(boot, [alpha, 100 - alpha])
    return float(lo), float(hi)


def summarise(values: Sequence[float], groups: Sequence[Any] | None = None, seed: int = 0) -> dict[str, Any]:
    """``n``, median and mean of ``values`` (NaNs dropped), each with its 95 % bootstrap interval."""
    v = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(v)
    out: dict[str, Any] = {"n": int(finite.sum())}
    for name, fn in (("median", np.median), ("mean", np.mean)):
        out[name] = float(fn(v[finite])) if finite.any() else None
        out[f"{name}_ci"] = list(bootstrap_ci(v, fn, groups, seed=seed)) if finite.any() else [None, None]
    return out
