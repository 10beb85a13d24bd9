"""How well a lens profile fits a dual-fisheye frame: the seam error on the lenses' overlap ring.

Two fisheyes of more than 180° both see a ring of directions around the camera. Under the right
profile each ring direction ``d`` lands on pixels of the same scene point in both lenses; under a
wrong one (another camera, a rotated layout, a diverged refinement) on different points. The
seam error compares the lenses' log luminance there with what unrelated-but-nearby points give:

    e = median_k |a_k - b_k - o| / median_k |a_k - b'_k - o'|

with ``a_k``, ``b_k`` lens 0's and lens 1's log luminance at ring direction ``d_k`` (both lenses'
projections, :func:`solidkit.camera.lens.project`), ``o`` the median of ``a - b`` (the lenses'
gain ratio), and ``b'_k`` lens 1 at ``d_k`` turned by :data:`NULL_SHIFT_DEG` about a random axis:
the *null*, the disagreement of points a few degrees apart in this very scene. ``e`` is scale
free (the same for the scene at any brightness or contrast): about 0 for a perfect fit of a static
scene, rising with the misalignment -- on the real outdoor panorama city.exr seen through 194°
lenses (tests/calibration/test_selfcal.py): 0.06 for the true profile (8-bit noise), 0.21 / 0.35 /
0.59 / 0.84 with the back lens 1 / 2 / 4 / 8° off -- and about 1 for unrelated views. Parallax
(objects close to the camera), moving people and sensor noise keep it above 0 for a correct profile.

Images are compared at a working resolution where the image circles are about
:data:`WORK_RADIUS_PX` px in radius (area reduced, then a 1-px Gaussian blur), in log(luminance +
1 % of its median); saturated pixels, for 8-bit frames pixels darker than code 10
(:data:`LDR_FLOOR`), and directions within ``edge_px`` of an image circle are left out. With less
than :data:`MIN_USABLE` of the ring (or 200 samples) usable the seam error is NaN (unmeasured).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from solidkit.camera.lens import LensProfile, project
from solidkit.envmap.resample import sample_image
from solidkit.envmap.sun import luminance

__all__ = [
    "NULL_SHIFT_DEG",
    "WORK_RADIUS_PX",
    "LDR_FLOOR",
    "SeamImage",
    "prepare_seam_image",
    "ring_directions",
    "seam_error",
    "sample_lens_view",
]

#: Angle (degrees) between the directions compared for the null disagreement.
NULL_SHIFT_DEG = 4.0
#: Image circles are compared at about this radius (px).
WORK_RADIUS_PX = 256.0


@dataclass
class SeamImage:
    """A frame prepared for seam comparisons: ``log_lum`` (h, w) float32 (NaN where saturated)
    at ``size`` = (w, h), reduced from the frame's ``full_size`` = (W, H); ``log_lum_all`` the same
    with clipped pixels kept (as bright as they were recorded: for looking at the scene)."""

    log_lum: np.ndarray
    log_lum_all: np.ndarray
    size: tuple[int, int]
    full_size: tuple[int, int]


def ring_directions(n: int, lo_deg: float, hi_deg: float) -> np.ndarray:
    """``(m, 3)`` quasi-uniform directions (Fibonacci lattice) whose angle to +z is in [lo, hi] degrees."""
    return _ring(int(n), float(lo_deg), float(hi_deg)).copy()


@lru_cache(maxsize=256)
def _ring(n: int, lo_deg: float, hi_deg: float) -> np.ndarray:
    lo, hi = math.cos(math.radians(hi_deg)), math.cos(math.radians(lo_deg))
    i = np.arange(n) + 0.5
    z = lo + (hi - lo) * i / n
    phi = i * math.pi * (3 - math.sqrt(5))
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


#: The seam error needs this fraction of the overlap ring usable (neither clipped nor black).
MIN_USABLE = 0.2
#: 8-bit frames: pixels darker than code 10 (linear, sRGB) are noise and quantisation, left out.
LDR_FLOOR = 0.003


def prepare_seam_image(
    image: np.ndarray, radius_px: float, saturation: float | None = None, floor: float | None = None
) -> SeamImage:
    """Reduce a linear frame ``(H, W[, C])`` so that a circle of ``radius_px`` becomes ~:data:`WORK_RADIUS_PX`.

    ``saturation``: linear level at/above which a pixel (any channel) is clipped (``None``: HDR);
    ``floor``: luminance below which a pixel is left out too (default :data:`LDR_FLOOR` when a
    ``saturation`` is given, i.e. for 8-bit frames, else none): the seam of a dark frame (a 1/25000 s
    sun frame) is then unmeasured (NaN) instead of a comparison of noise.
    """
    img = np.asarray(image, np.float32)
    H, W = img.shape[:2]
    lum = luminance(img) if img.ndim == 3 else img
    valid = np.isfinite(lum)
    if saturation is not None:
        valid &= ~(np.any(img >= saturation, axis=-1) if img.ndim == 3 else img >= saturation)
        floor = LDR_FLOOR if floor is None else floor
    if floor is not None:
        valid &= lum >= floor
    s = min(1.0, WORK_RADIUS_PX / max(radius_px, 1.0))
    w, h = max(8, round(W * s)), max(8, round(H * s))
    x: np.ndarray = np.where(valid, lum, 0.0).astype(np.float32)
    a = np.nan_to_num(lum, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)
    v = valid.astype(np.float32)
    if (w, h) != (W, H):
        x = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA)
        a = cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA)
        v = cv2.resize(v, (w, h), interpolation=cv2.INTER_AREA)
    x = cv2.GaussianBlur(x, (0, 0), 1.0)
    v = cv2.GaussianBlur(v, (0, 0), 1.0)
    pos = x[v > 0.999]
    eps = max(0.01 * float(np.median(pos[pos > 0])) if np.any(pos > 0) else 1e-4, 1e-6)
    log_lum = np.where(v > 0.999, np.log(np.maximum(x, 0.0) + eps), np.nan).astype(np.float32)
    return SeamImage(log_lum, np.log(np.maximum(a, 0.0) + eps).astype(np.float32), (w, h), (W, H))


def _in_both(prof: LensProfile, d: np.ndarray, edge_px: float) -> tuple[np.ndarray, list]:
    ok = np.ones(len(d), bool)
    xy = []
    for lens in prof.lenses[:2]:
        x, y, th = project(lens, d)
        ok &= th <= lens.angle(max(lens.max_radius() - edge_px, 1.0))
        xy.append((x, y))
    return ok, xy


def sample_lens_view(seam: SeamImage, profile: LensProfile, directions: np.ndarray, lens: int) -> np.ndarray:
    """Log luminance that lens ``lens`` of ``profile`` sees in ``directions (N, 3)`` (NaN outside its field)."""
    prof = profile.scaled(*seam.size)
    L = prof.lenses[lens]
    x, y, th = project(L, directions)
    v = sample_image(seam.log_lum, x, y, border_value=np.nan)
    return np.where(th <= math.radians(L.max_angle_deg), v, np.nan)


def seam_error(
    seam: SeamImage,
    profile: LensProfile,
    *,
    n: int = 20000,
    edge_px: float = 2.0,
    ring_deg: tuple[float, float] | None = None,
    seed: int = 0,
) -> dict[str, float]:
    """Seam error of ``profile`` on a prepared frame (module docstring).

    Parameters
    ----------
    seam : SeamImage
    profile : LensProfile with two lenses (any reference size of the frame's aspect).
    n : ring directions drawn.
    edge_px : directions closer than this (working px) to either circle's edge are left out.
    ring_deg : incidence-angle band about the front lens axis; default ``[180 - m1, m0]``.

    Returns
    -------
    dict
        ``seam_error`` (ratio, see above), ``seam_log_mad`` (median |log ratio| after the gain,
        natural-log units), ``null_log_mad``, ``gain_log`` (``o``), ``samples`` (ring directions
        seen by both lenses and not clipped), ``coverage`` (fraction of 10° azimuth sectors about
        the front axis where the two lenses' fields overlap: a profile whose lenses overlap on part
        of the ring only has a low one). NaNs (coverage 0) when fewer than 200 samples remain.
    """
    prof = profile.scaled(*seam.size)
    m0, m1 = prof.lenses[0].max_angle_deg, prof.lenses[1].max_angle_deg
    lo, hi = ring_deg if ring_deg is not None else (180.0 - m1, m0)
    out = {
        "seam_error": math.nan,
        "seam_log_mad": math.nan,
        "null_log_mad": math.nan,
        "gain_log": math.nan,
        "samples": 0,
        "coverage": 0.0,
    }
    if hi <= lo:
        return out
    R0 = prof.lenses[0].rotation
    d = ring_directions(n, lo, hi) @ R0.T  # about the front lens' axis
    rng = np.random.default_rng(seed)
    u = np.cross(d, rng.normal(size=d.shape))
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    t = math.radians(NULL_SHIFT_DEG)
    d_null = math.cos(t) * d + math.sin(t) * u
    ok, xy = _in_both(prof, d, edge_px)
    ok_n, xy_n = _in_both(prof, d_null, edge_px)
    a = sample_image(seam.log_lum, xy[0][0], xy[0][1], border_value=np.nan)
    b = sample_image(seam.log_lum, xy[1][0], xy[1][1], border_value=np.nan)
    bn = sample_image(seam.log_lum, xy_n[1][0], xy_n[1][1], border_value=np.nan)
    good = ok & np.isfinite(a) & np.isfinite(b)
    good_n = good & ok_n & np.isfinite(bn)
    if good.sum() < max(200, MIN_USABLE * ok.sum()) or good_n.sum() < 200:
        out["samples"] = int(good.sum())
        return out
    diff = a[good] - b[good]
    o = float(np.median(diff))
    mad = float(np.median(np.abs(diff - o)))
    dn = a[good_n] - bn[good_n]
    null = float(np.median(np.abs(dn - np.median(dn))))
    dl = d[ok] @ R0  # front-lens frame; geometry only (clipped sky is no gap in the overlap)
    az = np.arctan2(dl[:, 1], dl[:, 0])
    coverage = np.count_nonzero(np.bincount(((az + math.pi) / (2 * math.pi) * 36).astype(int) % 36, minlength=36)) / 36
    return {
        "seam_error": mad / max(null, 1e-9),
        "seam_log_mad": mad,
        "null_log_mad": null,
        "gain_log": o,
        "samples": int(good.sum()),
        "coverage": float(coverage),
    }
