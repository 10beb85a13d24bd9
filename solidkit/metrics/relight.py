"""The re-rendering error: how differently two light probes light the same virtual object.

A probe that scores well as an image can still light an object from the wrong side, so
``solidkit eval --relight`` renders objects under the predicted and the true probe
(:mod:`solidkit.synth.relight`) and compares them three ways:

Scale-invariant RMSE (:func:`si_rmse`)
    The prediction's render ``P`` is first multiplied by the scale that fits the truth's render ``T``
    best in the least-squares sense, ``a = <P, T> / <P, P>`` (over the compared pixels and the three
    channels), so that the probes' units (which a real capture does not share with a model) do not
    count; the RMSE is then divided by the truth's RMS: ``||a P - T|| / ||T||``. 0 is a perfect
    render, 1 no better than black (``a = 0``); unitless, comparable across scenes of any exposure.

SSIM of the renders (:func:`render_ssim`)
    ``a P`` and ``T`` are exposed alike (the truth's mean luminance over the compared pixels to 0.18),
    clipped and sRGB-encoded (:func:`~solidkit.metrics.maps.ldr_from_hdr`), the prediction is set equal
    to the truth outside the compared pixels (so the background adds no difference to any window), and
    kornia's SSIM map (:func:`~solidkit.metrics.maps.masked_ssim`) is averaged over the compared pixels.

Shading direction (:func:`shading_direction`, :func:`shading_angle_deg`)
    Where the light comes from, as the object sees it: the irradiance-weighted mean direction of the
    probe over the hemisphere above the ground plane (the plane the object stands on hides the rest),

        s = normalise( sum_{d . up > 0} Y(d) d Omega(d) ),

    with ``Y`` the Rec. 709 luminance and ``Omega`` the pixel solid angle. This is the direction of the
    probe's first-order spherical harmonics (band l = 1) over that hemisphere, hence the normal at which
    the linear part of a diffuse object's irradiance peaks: the side a Lambertian sphere is lit from.
    Under a sun it points close to the sun (pulled up by the sky); under a uniform overcast sky it
    points up. The error is the angle between the two probes' ``s``, in degrees (0..180).
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np

from solidkit.envmap.coords import direction_grid, solid_angle
from solidkit.envmap.sun import luminance
from solidkit.metrics.maps import ldr_from_hdr, masked_ssim

__all__ = ["UP", "si_scale", "si_rmse", "render_ssim", "shading_direction", "shading_angle_deg"]

UP = (0.0, -1.0, 0.0)
"""Up in the panorama frame (docs/conventions.md §2: y down)."""


def _pair(predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(predicted, dtype=np.float64)[..., :3]
    t = np.asarray(truth, dtype=np.float64)[..., :3]
    if mask is None:
        return p.reshape(-1, 3), t.reshape(-1, 3)
    m = np.asarray(mask, dtype=bool)
    return p[m], t[m]


def si_scale(predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """The least-squares scale ``a = <P, T> / <P, P>`` of ``predicted`` onto ``truth`` (``(H, W, 3)``, linear)
    over ``mask (H, W)`` (default: every pixel); 0 for a black prediction."""
    p, t = _pair(predicted, truth, mask)
    pp = float(np.sum(p * p))
    return float(np.sum(p * t)) / pp if pp > 0 else 0.0


def si_rmse(predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Scale-invariant relative RMSE ``||a P - T|| / ||T||`` of two renders ``(H, W, 3)`` (linear) over
    ``mask (H, W)``, with ``a`` = :func:`si_scale`. In [0, 1]; NaN for a black truth or an empty mask."""
    p, t = _pair(predicted, truth, mask)
    tt = float(np.sum(t * t))
    if p.size == 0 or tt <= 0:
        return math.nan
    a = si_scale(predicted, truth, mask)
    return math.sqrt(float(np.sum((a * p - t) ** 2)) / tt)


def render_ssim(predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None, key: float = 0.18) -> float:
    """SSIM of two renders ``(H, W, 3)`` (linear) over ``mask (H, W)``: the prediction scaled by :func:`si_scale`,
    both exposed so that the truth's mean luminance over the mask is ``key``, sRGB-encoded; 1 when equal."""
    m = np.ones(np.shape(truth)[:2], dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    t = np.asarray(truth, dtype=np.float32)[..., :3]
    y = float(luminance(t)[m].mean()) if m.any() else 0.0
    if y <= 0:
        return math.nan
    a = si_scale(predicted, truth, m)
    k = key / y
    pt = ldr_from_hdr(np.asarray(predicted, dtype=np.float32)[..., :3], a * k)
    tt = ldr_from_hdr(t, k)
    pt = np.where(m[..., None], pt, tt)
    return masked_ssim(pt, tt, m)


def shading_direction(probe: np.ndarray, up: tuple[float, float, float] = UP) -> np.ndarray:
    """The unit shading direction ``(3,)`` of a probe ``(H, 2H, 3)`` (linear, panorama frame): its
    luminance-weighted mean direction over the hemisphere around ``up`` (see the module docstring);
    NaNs when no light comes from there."""
    p = np.clip(np.asarray(probe, dtype=np.float64)[..., :3], 0.0, None)
    h = p.shape[0]
    d = np.asarray(direction_grid(h), dtype=np.float64)
    w = luminance(p, np.float64) * np.asarray(solid_angle(h), dtype=np.float64) * (d @ np.asarray(up) > 0)
    v = np.einsum("hw,hwc->c", w, d)
    n = float(np.linalg.norm(v))
    return cast(np.ndarray, v / n) if n > 0 else np.full(3, np.nan)


def shading_angle_deg(predicted: np.ndarray, truth: np.ndarray, up: tuple[float, float, float] = UP) -> float:
    """Angle (degrees) between the :func:`shading_direction` of two probes; NaN if either has none."""
    a, b = shading_direction(predicted, up), shading_direction(truth, up)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return math.nan
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))
