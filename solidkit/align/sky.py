"""The relative yaw of two level panoramas from their skies: a cue where features fail.

The sky is at infinity: two level captures of one scene, taken minutes apart, see its radiance
pattern (the sun-sky gradient in azimuth even where the sun's disk is hidden; clouds on real
captures) related by a pure rotation about gravity, whatever the baseline. In an equirectangular
level panorama that rotation is a column shift, so the relative yaw ``psi`` (``yaw_b - yaw_a`` in
the heading convention of :mod:`solidkit.align.schema`: azimuth ``x`` in ``a`` is azimuth
``x - psi`` in ``b``) minimises the masked, exposure-normalised squared difference of the two
skies' log radiance::

    E(psi) = sum_{p in S_a & S_b(psi)} w_p (log L_a(p) - log L_b(p shifted by psi) - c)^2 / sum w_p

with ``c`` the weighted mean difference (the exposures' ratio) and ``w`` the pixels' solid angle.
Every shift at once by FFT along the azimuth (masked correlation, Padfield, "Masked object
registration in the Fourier domain", IEEE TIP 2012), the minimum refined by a parabola.

Sky mask (:func:`sky_layer`): above the horizon, bluish (``B >= R``), smooth (small local
log-gradient: building texture and render or sensor noise are not), not the sun's core, in
connected pieces of at least ``min_piece`` of the sphere (small sky-coloured patches are
reflections in windows, which move with the viewpoint).

Uncertainty (:func:`relative_sky_yaw`): least squares on the cost's curvature,
``sigma^2 = 2 E_min / (n_eff E'')``, with ``n_eff`` the overlap in units of
``correlation_px`` pixels squared (neighbouring sky pixels are not independent). The estimate is
refused when the overlap is small, the curvature flat (a sky too uniform in azimuth: no sun
gradient, only the elevation gradient) or another shift fits almost as well
(``min_delta_chi2`` between the best and the best outside its peak).

The sky's pattern is fixed to the sun, which moves (up to ~0.25° of azimuth a minute): between
captures minutes apart the shift includes the sun's azimuth drift (:func:`without_sun_drift`).
Clouds drift with the wind and change shape: on real captures minutes apart they are no
fixed pattern either (not measured here: no such real set).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from solidkit.align.schema import wrap_deg
from solidkit.envmap.coords import angles_grid, solid_angle
from solidkit.envmap.sun import luminance

__all__ = ["SkyLayer", "SkyYaw", "sky_layer", "relative_sky_yaw", "without_sun_drift"]


@dataclass(frozen=True)
class SkyLayer:
    """A level panorama's sky: log luminance ``(H, 2H)``, mask ``(H, 2H)`` bool, pixel weights ``(H, 2H)``."""

    log_lum: np.ndarray
    mask: np.ndarray
    weight: np.ndarray

    @property
    def fraction(self) -> float:
        """Solid-angle fraction of the sphere that is sky."""
        return float(self.weight[self.mask].sum() / self.weight.sum())


@dataclass(frozen=True)
class SkyYaw:
    """Relative yaw ``yaw_deg`` (``yaw_b - yaw_a``), its 1-sigma ``sigma_deg``, the overlap's solid-angle
    fraction of the sphere, the fit's RMS in log radiance, and ``delta_chi2`` of the best other shift."""

    yaw_deg: float
    sigma_deg: float
    overlap: float
    rms: float
    delta_chi2: float


def sky_layer(
    pano: np.ndarray,
    *,
    height: int = 256,
    min_elevation_deg: float = 2.0,
    max_gradient: float = 0.03,
    min_piece: float = 0.002,
    blue_ratio: float = 1.0,
    saturation: float | None = None,
) -> SkyLayer:
    """The sky of a level panorama (module doc).

    Parameters
    ----------
    pano : ndarray (H0, 2 H0, 3)
        Linear RGB (HDR product or decoded LDR), in the capture's level frame.
    height : int
        Working height (area-averaged copy); ``max_gradient`` is the largest log-luminance step
        between neighbouring pixels at 256 rows, scaled with the pixel size.
    saturation : float, optional
        For a decoded LDR panorama: pixels with a channel at or above this value (clipped sky
        carries no pattern) are left out.
    """
    img: np.ndarray = np.asarray(pano, np.float32)
    if img.ndim != 3 or img.shape[2] < 3 or img.shape[1] != 2 * img.shape[0]:
        raise ValueError(f"sky_layer: expected an (H, 2H, 3) panorama, got {img.shape}")
    img = np.ascontiguousarray(img[..., :3])
    if img.shape[0] != height:
        img = cv2.resize(img, (2 * height, height), interpolation=cv2.INTER_AREA)
    lum = luminance(img)
    log_lum = np.log(np.maximum(lum, 1e-8)).astype(np.float64)
    _, el = angles_grid(height)
    gx = np.abs(np.roll(log_lum, -1, axis=1) - log_lum)
    gy = np.abs(np.diff(log_lum, axis=0, append=log_lum[-1:]))
    grad = cv2.blur(np.maximum(gx, gy).astype(np.float32), (3, 3))
    cand = (el > math.radians(min_elevation_deg)) & (img[..., 2] >= blue_ratio * img[..., 0]) & (lum > 0)
    if saturation is not None:
        cand &= img.max(axis=-1) < saturation
    cand &= grad < max_gradient * 256.0 / height
    if cand.any():  # the sun's core and its glare are no sky pattern
        cand &= log_lum < np.median(log_lum[cand]) + math.log(8.0)
    m = cv2.erode(cand.astype(np.uint8), np.ones((3, 3), np.uint8))
    w = np.broadcast_to(solid_angle(height), m.shape)
    # connected pieces, wrapping in azimuth (two copies side by side)
    n, lab = cv2.connectedComponents(np.concatenate([m, m], axis=1), connectivity=4)
    lab = np.where(lab[:, : 2 * height] > 0, lab[:, : 2 * height], lab[:, 2 * height :])
    area = np.bincount(lab.ravel(), weights=w.ravel(), minlength=n) / (4.0 * math.pi)
    keep = (area >= min_piece) & (np.arange(n) > 0)
    mask = keep[lab] & (m > 0)
    return SkyLayer(log_lum, mask, np.ascontiguousarray(w))


def _xcorr(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``h[k] = sum_rows sum_x f[., x] g[., x - k]`` (circular in x), every ``k`` at once."""
    F = np.fft.rfft(f, axis=1)
    G = np.fft.rfft(g, axis=1)
    return np.fft.irfft(np.sum(F * np.conj(G), axis=0), n=f.shape[1])


def relative_sky_yaw(
    a: SkyLayer,
    b: SkyLayer,
    *,
    min_overlap: float = 0.005,
    correlation_px: float = 18.0,
    min_delta_chi2: float = 9.0,
    max_sigma_deg: float = 3.0,
) -> tuple[SkyYaw | None, str]:
    """Relative yaw ``yaw_b - yaw_a`` (degrees) of two level panoramas from their skies; ``(None, why)`` when refused.

    ``correlation_px``: the sky's correlation length in working pixels (``n_eff`` = overlap in
    pixels / ``correlation_px``^2; 18 at 256 rows makes the sigmas match the errors of 37 capture
    pairs of a virtual campaign, seed 11: |error / sigma| median 0.66); ``min_delta_chi2``: how much worse (in
    chi-square units) the best shift outside the peak must fit; ``max_sigma_deg``: a larger sigma is refused (the
    sky is too uniform in azimuth to tell).
    """
    if a.log_lum.shape != b.log_lum.shape:
        raise ValueError("relative_sky_yaw: the two sky layers differ in size")
    h, width = a.log_lum.shape
    step = 360.0 / width
    wa = a.weight * a.mask
    mb = b.mask.astype(np.float64)
    A = np.where(a.mask, a.log_lum, 0.0)
    B = np.where(b.mask, b.log_lum, 0.0)
    n = _xcorr(wa, mb)
    if n.max() < min_overlap * 4.0 * math.pi:
        return None, (
            f"sky overlap {n.max() / (4 * math.pi):.3f} of the sphere (< {min_overlap:g}): "
            f"sky {a.fraction:.3f} and {b.fraction:.3f}"
        )
    s_a = _xcorr(wa * A, mb)
    s_b = _xcorr(wa, mb * B)
    q = _xcorr(wa * A * A, mb) + _xcorr(wa, mb * B * B) - 2.0 * _xcorr(wa * A, mb * B)
    valid = n >= min_overlap * 4.0 * math.pi
    nn = np.where(valid, n, 1.0)
    c = (s_a - s_b) / nn
    cost = np.where(valid, np.maximum(q / nn - c * c, 0.0), np.inf)
    k = int(np.argmin(cost))
    c0, cm, cp = cost[k], cost[(k - 1) % width], cost[(k + 1) % width]
    den = cm - 2.0 * c0 + cp
    if not (np.isfinite(den) and den > 0):
        return None, "the sky's cost has no curvature at its minimum"
    off = float(np.clip(0.5 * (cm - cp) / den, -0.5, 0.5))
    e_min = max(float(c0 - 0.125 * (cm - cp) ** 2 / den), 1e-12)
    curv = den / step**2  # per deg^2
    px_area = float(a.weight[h // 2, 0])  # solid angle of a pixel at the horizon
    n_eff = float(n[k]) / px_area / correlation_px**2
    sigma = math.sqrt(2.0 * e_min / (n_eff * curv))
    # the best other local minimum outside the peak (3 sigma or 3 pixels from it): a second basin
    dist = np.abs(((np.arange(width) - k + width // 2) % width) - width // 2) * step
    local = (
        (cost <= np.roll(cost, 1))
        & (cost <= np.roll(cost, -1))
        & (cost <= np.roll(cost, 2))
        & (cost <= np.roll(cost, -2))
    )
    far = local & (dist > max(3.0 * sigma, 3.0 * step)) & np.isfinite(cost)
    delta = float((cost[far].min() - c0) * n_eff / (2.0 * e_min)) if far.any() else math.inf
    yaw = wrap_deg((k + off) * step)
    res = SkyYaw(yaw, sigma, float(n[k]) / (4.0 * math.pi), math.sqrt(e_min), delta)
    if delta < min_delta_chi2:
        return None, (
            f"sky ambiguous: another yaw {delta:.0f} chi2 from the best ({yaw:+.2f} deg, sigma {sigma:.2f} deg); "
            "too little azimuthal structure"
        )
    if sigma > max_sigma_deg:
        return None, f"sky too uniform in azimuth: sigma {sigma:.1f} deg (> {max_sigma_deg:g})"
    return res, (
        f"sky relative yaw {yaw:+.2f} deg (sigma {sigma:.2f}; overlap {res.overlap:.3f} of the sphere, "
        f"RMS {res.rms:.3f} in log radiance, next best {delta:.0f} chi2 worse)"
    )


def without_sun_drift(yaw_deg: float, sun_azimuth_a_deg: float, sun_azimuth_b_deg: float) -> float:
    """The relative yaw ``yaw_b - yaw_a`` from a sky shift measured while the sun moved.

    The sky's pattern turns with the sun: with world (solar) azimuths ``A_a``, ``A_b`` of the sun
    at the two captures' times, the measured shift is ``(yaw_b - yaw_a) + (A_a - A_b)``.
    """
    return wrap_deg(yaw_deg + wrap_deg(sun_azimuth_b_deg - sun_azimuth_a_deg))
