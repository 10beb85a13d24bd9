"""Vignetting (radial light falloff) of each fisheye lens, from a flat field or the lenses' overlap.

Model, per lens: ``V(ρ) = 1 + a1 ρ² + a2 ρ⁴ + a3 ρ⁶`` (``V(0) = 1``), with ``ρ = r / r_norm`` the
distance from the lens' optical centre over its image-circle radius ``r(max_angle)`` (so the
profile is size-independent, like the lens profile). Correction divides linear pixels by ``V``
and happens on each lens image *before* unwarping/merging (:func:`correct_vignetting`).

Estimation:

- **flat field** (:func:`fit_flat_field`): a uniformly lit target filling each lens (e.g. an
  overcast sky through a diffuser). Pixels are binned by ``ρ`` (median per bin, robust to dust and
  seams) and ``s·V(ρ)`` is fitted by linear least squares; the unknown exposure ``s`` is divided out.
- **overlap** (:func:`fit_overlap`): directions seen by two lenses (a dual fisheye's ±10° band around
  90° incidence) are imaged at different radii. With one scene radiance ``L(d)`` per direction,
  ``log I_i(d) − log I_j(d) = log V(ρ_i) − log V(ρ_j) + c_ij`` (``c_ij``: a per-channel gain ratio);
  the lenses share one falloff (same design), fitted by robust non-linear least squares. The band
  only measures the falloff's *slope* there, so the default degree is 1 (``a1``); the reported
  parameter standard errors say how well it is determined.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, Field
from scipy.optimize import least_squares

from solidkit.calibration.profile import Profile, make_provenance
from solidkit.camera.lens import project
from solidkit.envmap.perspective import scale_pixel_coordinates
from solidkit.envmap.resample import sample_image
from solidkit.envmap.sun import luminance
from solidkit.errors import InputError, SolidkitError

__all__ = [
    "VignettingError",
    "LensVignetting",
    "VignettingProfile",
    "falloff",
    "vignetting_map",
    "correct_vignetting",
    "fit_flat_field",
    "fit_overlap",
    "lenses_from_profile",
    "make_profile",
]


class VignettingError(SolidkitError):
    """Too few usable pixels/samples to fit a falloff, or a profile that does not fit the image."""


class LensVignetting(BaseModel):
    """One lens' falloff at the profile's reference size."""

    name: str
    center: tuple[float, float] = Field(description="optical centre (px) at reference_size, OpenCV convention")
    r_norm_px: float = Field(gt=0, description="radius where rho = 1 (the image circle, px at reference_size)")
    coeffs: list[float] = Field(description="a1, a2, ... of V = 1 + a1 rho^2 + a2 rho^4 + ...")


class VignettingProfile(Profile):
    """Radial falloff per lens of a (dual-)fisheye camera."""

    KIND = "vignetting"
    method: str = Field(description="flat-field | overlap")
    reference_size: tuple[int, int]
    lenses: list[LensVignetting]
    lens_profile: str | None = Field(default=None, description="lens profile model/key the geometry came from")

    def scaled(self, width: int, height: int) -> list[LensVignetting]:
        """The lenses at another image size of the same aspect (centres ``(c + 0.5)s − 0.5``)."""
        W, H = self.reference_size
        s = width / W
        if abs(height - H * s) > 1.0:
            raise VignettingError(f"vignetting profile is for {W}x{H} images; got {width}x{height}")
        return [
            l.model_copy(
                update={"center": tuple(scale_pixel_coordinates(c, s) for c in l.center), "r_norm_px": l.r_norm_px * s}
            )
            for l in self.lenses
        ]


def falloff(coeffs: Sequence[float], rho: Any) -> np.ndarray:
    """``V(ρ) = 1 + Σ a_k ρ^(2k)`` (k = 1..len(coeffs))."""
    rho = np.asarray(rho, dtype=np.float64)
    r2 = rho * rho
    out = np.zeros_like(r2)
    for a in reversed(list(coeffs)):
        out = (out + a) * r2
    return 1.0 + out


def _lens_rho(lenses: Sequence[LensVignetting], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel: index of the lens whose circle contains it (nearest centre; -1 outside) and its ρ."""
    W, H = size
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    idx = np.full((H, W), -1, np.int32)
    rho = np.full((H, W), np.inf)
    for i, l in enumerate(lenses):
        r = np.hypot(xx - l.center[0], yy - l.center[1]) / l.r_norm_px
        take = (r <= 1.0) & (r < rho)
        idx[take] = i
        rho[take] = r[take]
    return idx, rho


def vignetting_map(profile: VignettingProfile, size: tuple[int, int]) -> np.ndarray:
    """``V`` for every pixel of a ``size = (W, H)`` image (1 outside every image circle), float32 (H, W)."""
    lenses = profile.scaled(*size)
    idx, rho = _lens_rho(lenses, size)
    V = np.ones(idx.shape)
    for i, l in enumerate(lenses):
        sel = idx == i
        V[sel] = falloff(l.coeffs, rho[sel])
    return V.astype(np.float32)


def correct_vignetting(image: np.ndarray, profile: VignettingProfile) -> np.ndarray:
    """Divide a *linear* (dual-)fisheye image (H, W[, C]) by its falloff; returns float32."""
    img = np.asarray(image, dtype=np.float32)
    V = vignetting_map(profile, (img.shape[1], img.shape[0]))
    if np.any(V <= 0.05):
        raise VignettingError("the falloff drops below 5 % inside an image circle: the profile is unusable")
    return img / (V[..., None] if img.ndim == 3 else V)


def fit_flat_field(
    image: np.ndarray,
    lenses: Sequence[LensVignetting],
    degree: int = 3,
    bins: int = 64,
    saturation: float = 0.98,
    rho_max: float = 0.98,
) -> tuple[list[LensVignetting], dict[str, Any]]:
    """Fit each lens' falloff to a linear flat-field image.

    ``lenses`` give the geometry (centre, ``r_norm_px``; their ``coeffs`` are ignored). Pixels
    above ``saturation`` or at zero are ignored; ``rho_max`` drops the circle's soft edge.
    Returns the fitted lenses and residuals (RMS relative deviation of the binned profile from
    the fit, per lens).
    """
    _check_size(np.asarray(image))
    lum = luminance(image, np.float64)
    size = (lum.shape[1], lum.shape[0])
    idx, rho = _lens_rho(lenses, size)
    out, res = [], {}
    for i, l in enumerate(lenses):
        sel = (idx == i) & (rho <= rho_max) & (lum > 0) & (lum < saturation)
        if sel.sum() < 50 * (degree + 1):
            raise VignettingError(f"lens {l.name}: only {int(sel.sum())} usable flat-field pixels")
        r, v = rho[sel], lum[sel]
        edges = np.linspace(0, rho_max, bins + 1)
        which = np.clip(np.digitize(r, edges) - 1, 0, bins - 1)
        centres, medians, counts = [], [], []
        for b in range(bins):
            m = which == b
            if m.sum() >= 10:
                centres.append(np.sqrt(np.mean(r[m] ** 2)))
                medians.append(np.median(v[m]))
                counts.append(m.sum())
        c, y, n = np.array(centres), np.array(medians), np.array(counts, np.float64)
        A = np.stack([c ** (2 * k) for k in range(degree + 1)], 1)  # s, s a1, s a2, ...
        wts = np.sqrt(n)
        sol, *_ = np.linalg.lstsq(A * wts[:, None], y * wts, rcond=None)
        s = sol[0]
        if s <= 0:
            raise VignettingError(f"lens {l.name}: the flat field is not positive at the centre")
        coeffs = (sol[1:] / s).tolist()
        rel = y / (s * falloff(coeffs, c)) - 1
        out.append(l.model_copy(update={"coeffs": coeffs}))
        res[l.name] = {
            "rms_rel": float(np.sqrt(np.average(rel**2, weights=n))),
            "pixels": int(sel.sum()),
            "falloff_at_rho_0.9": float(falloff(coeffs, 0.9)),
        }
    return out, res


def fit_overlap(
    image: np.ndarray,
    lens_profile,
    degree: int = 1,
    n_directions: int = 200_000,
    saturation: float = 0.98,
    floor: float = 1e-3,
    max_gradient: float = 0.05,
    seed: int = 0,
) -> tuple[list[LensVignetting], dict[str, Any]]:
    """Fit one shared falloff to the overlap of a linear dual-fisheye image.

    Parameters
    ----------
    image : (H, W, C) linear image (response-linearised), original layout of ``lens_profile``.
    lens_profile : :class:`solidkit.camera.lens.LensProfile` with 2 lenses (geometry).
    degree : number of coefficients (1 = ``a1`` only; see module doc on identifiability).
    n_directions : random directions drawn on the sphere (those seen by both lenses are used).
    saturation, floor : pixel values outside ``(floor, saturation)`` in any channel are ignored.
    max_gradient : samples whose log-intensity changes by more than this over one pixel (edges,
        where a small misregistration or parallax breaks the one-radiance assumption) are ignored.

    Returns the lenses (sharing the coefficients) and residuals: robust RMS of the log ratio
    before and after (stops), parameter standard errors, sample count.
    """
    img = np.asarray(image, dtype=np.float32)
    _check_size(img)
    if img.ndim == 2:
        img = img[..., None]
    H, W = img.shape[:2]
    prof = lens_profile.scaled(W, H)
    if len(prof.lenses) != 2:
        raise VignettingError(f"overlap vignetting needs a two-lens profile, {prof.model!r} has {len(prof.lenses)}")
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_directions, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    la, lb = prof.lenses
    xa, ya, ta = project(la, d)
    xb, yb, tb = project(lb, d)
    both = (ta <= math.radians(la.max_angle_deg)) & (tb <= math.radians(lb.max_angle_deg))
    inside = lambda x, y: (x >= 1) & (x <= W - 2) & (y >= 1) & (y <= H - 2)  # noqa: E731
    both &= inside(xa, ya) & inside(xb, yb)
    if both.sum() < 100:
        raise VignettingError(f"only {int(both.sum())} directions seen by both lenses: no usable overlap")
    xa, ya, xb, yb = xa[both], ya[both], xb[both], yb[both]
    Ia, Ib = sample_image(img, xa, ya), sample_image(img, xb, yb)
    ok = np.all((Ia > floor) & (Ia < saturation) & (Ib > floor) & (Ib < saturation), axis=1)
    # reject edges: log-gradient at each sample
    logimg = np.log(np.maximum(luminance(img, np.float64), floor)).astype(np.float32)
    gx = cv2.Sobel(logimg, cv2.CV_32F, 1, 0, ksize=3) / 8
    gy = cv2.Sobel(logimg, cv2.CV_32F, 0, 1, ksize=3) / 8
    grad = np.hypot(gx, gy)[..., None]
    ok &= (sample_image(grad, xa, ya)[:, 0] < max_gradient) & (sample_image(grad, xb, yb)[:, 0] < max_gradient)
    if ok.sum() < 50:
        raise VignettingError(f"only {int(ok.sum())} usable overlap samples (saturated, dark or textured)")
    ra = np.hypot(xa[ok] - la.center[0], ya[ok] - la.center[1]) / la.max_radius()
    rb = np.hypot(xb[ok] - lb.center[0], yb[ok] - lb.center[1]) / lb.max_radius()
    lr = np.log(Ia[ok]) - np.log(Ib[ok])  # (N, C)
    C = lr.shape[1]

    def resid(p):
        a, c = p[:degree], p[degree:]
        Va, Vb = falloff(a, ra), falloff(a, rb)
        if np.any(Va <= 0) or np.any(Vb <= 0):
            return np.full(lr.size, 10.0)
        return (lr - (np.log(Va) - np.log(Vb))[:, None] - c[None, :]).ravel()

    p0 = np.concatenate([np.zeros(degree), np.median(lr, axis=0)])
    before = resid(p0)
    sol = least_squares(resid, p0, loss="soft_l1", f_scale=0.02)
    J = sol.jac
    dof = max(sol.fun.size - len(sol.x), 1)
    sigma2 = float(np.median(np.abs(sol.fun)) / 0.6745) ** 2
    try:
        cov = np.linalg.inv(J.T @ J) * sigma2
        stderr = np.sqrt(np.clip(np.diag(cov), 0, None))[:degree].tolist()
    except np.linalg.LinAlgError:
        stderr = [float("inf")] * degree
    coeffs = sol.x[:degree].tolist()
    gains = np.exp(sol.x[degree:]).tolist()
    lenses = [
        LensVignetting(name=l.name, center=tuple(l.center), r_norm_px=l.max_radius(), coeffs=coeffs) for l in (la, lb)
    ]
    res = {
        "samples": int(ok.sum()),
        "dof": dof,
        "log_ratio_robust_rms_stops_before": float(1.4826 * np.median(np.abs(before)) / math.log(2)),
        "log_ratio_robust_rms_stops_after": float(1.4826 * np.median(np.abs(sol.fun)) / math.log(2)),
        "coeff_stderr": stderr,
        "gain_ratio_per_channel": gains,
        "rho_range": [float(min(ra.min(), rb.min())), float(max(ra.max(), rb.max()))],
        "channels": C,
    }
    return lenses, res


def lenses_from_profile(lens_profile) -> list[LensVignetting]:
    """Geometry-only :class:`LensVignetting` entries (zero falloff) from a lens profile."""
    return [
        LensVignetting(name=l.name, center=tuple(l.center), r_norm_px=l.max_radius(), coeffs=[])
        for l in lens_profile.lenses
    ]


def make_profile(
    method: str,
    lenses: Sequence[LensVignetting],
    reference_size: tuple[int, int],
    residuals: dict,
    inputs: Sequence[Any] = (),
    lens_profile=None,
    **params,
) -> VignettingProfile:
    """Wrap fitted lenses into a :class:`VignettingProfile` with provenance."""
    return VignettingProfile(
        provenance=make_provenance(list(inputs), tool=f"solidkit.calibration.vignetting.{method}", **params),
        residuals=residuals,
        method=method,
        reference_size=tuple(reference_size),
        lenses=list(lenses),
        lens_profile=None if lens_profile is None else f"{lens_profile.model}:{lens_profile.key()}",
    )


def _check_size(img: np.ndarray) -> None:
    if img.ndim not in (2, 3):
        raise InputError(f"expected an (H, W[, C]) image, got shape {img.shape}")
