"""Seam disparity: how far apart (degrees) the two lenses of a dual-fisheye profile put the same scene point.

Under the right profile every scene point the two lenses both see is mapped to one direction;
under a wrong one (another camera's lens, a back lens aimed wrong, a field of view off) the two
lenses' views of it land some degrees apart, and the stitched panorama shows it twice. This
measure looks for exactly that, across the whole overlap and beyond it:

1. Each lens' view is unrolled onto a **ring strip** about the front lens' axis: columns are the
   azimuth ``psi`` about that axis (0-360°, padded by wrapping), rows the angle ``alpha`` from it,
   both in steps of :data:`STEP_DEG`, over the overlap band ``[180 - t1, t0]`` widened by
   :data:`SEARCH_DEG` on each side (``t_i``: the angle the profile gives lens ``i``'s image-circle
   edge, found in the frame when possible: a profile claiming a narrower field does not shrink
   the band). Each strip shows what its lens sees under the profile and is masked where it does
   not (the widening lets content that the profile misplaces by up to :data:`SEARCH_DEG` still
   be found in the other lens).
2. SIFT keypoints (Lowe 2004) in each strip away from its mask's edge are matched by descriptor
   (mutual nearest neighbours, Lowe's ratio test at :data:`RATIO`) among candidates within
   :data:`SEARCH_DEG` on the sphere; a match's **disparity** is the angle between the two
   directions the profile gives the two keypoints.
3. The distribution over matches: ``median_deg``, ``p95_deg``, ``doubled_fraction`` (matches more
   than :data:`DOUBLED_DEG` apart), the signed median components across the ring (``across_deg``,
   toward the back lens) and along it (``along_deg``), ``matches``; and where the overlap has
   something to match: ``textured_fraction`` (the overlap band's pixels with a gradient above
   :data:`TEXTURE_LEVEL` grey levels per degree in the front lens' strip) and ``coverage`` (the
   fraction of 10° sectors of the ring holding at least one match).

Doubled content is what it measures: content shown twice ``x`` degrees apart gives matches ``x``
apart, wherever it lies in the band, whatever its contrast, brightness or the lenses' gains
(SIFT is invariant to them); a wide band does not dilute it. Degrees are what a person sees in
the panorama. What it does not see: doubling larger than :data:`SEARCH_DEG`, and a band without
texture (sky, a wall): ``matches`` below :data:`MIN_MATCHES` gives NaN figures (unmeasured).
Correct profiles keep a small disparity from parallax (near objects: the lenses are ~2-3 cm
apart, 1° at 1.3 m), moving things and the detector's precision (~0.05° at these steps).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from solidkit.camera.lens import LensProfile, project, unproject
from solidkit.envmap.coords import wrap_angle
from solidkit.envmap.perspective import scale_pixel_coordinates
from solidkit.envmap.sun import luminance

__all__ = [
    "STEP_DEG",
    "SEARCH_DEG",
    "DOUBLED_DEG",
    "DISPARITY_WARN_DEG",
    "DOUBLED_WARN_FRACTION",
    "SeamDisparity",
    "disparity_warning",
    "SeamMatches",
    "ring_strips",
    "seam_matches",
    "match_disparity",
    "summarize",
    "seam_disparity",
]

#: Ring strip resolution (degrees per pixel, both axes; SIFT's first octave doubles it).
STEP_DEG = 0.3
#: Largest disparity looked for (degrees); the strips reach this far beyond the overlap.
SEARCH_DEG = 15.0
#: Lowe's ratio test: best descriptor distance below this fraction of the second best.
RATIO = 0.8
#: A match farther apart than this (degrees) is doubled content a person can see.
DOUBLED_DEG = 1.0
#: Median disparity above which a profile does not fit the frame (degrees): 15 px of doubling in a 5376-px panorama.
#: Correct profiles measured 0.02-0.05° on rendered frames and 0.64° on the real indoor Theta S frame (parallax);
#: a field of view 1.5° off 1.38°, a back lens 2° off 1.93° (benchmarks/results/seam_disparity.md).
DISPARITY_WARN_DEG = 1.0
#: A profile does not fit either when more than this fraction of the matches are over :data:`DOUBLED_DEG` apart.
DOUBLED_WARN_FRACTION = 0.5
#: Fewer matches leave the disparity unmeasured.
MIN_MATCHES = 20
#: A strip pixel is textured above this gradient (grey levels of the 8-bit strip per degree).
TEXTURE_LEVEL = 20.0


@dataclass(frozen=True)
class SeamDisparity:
    """The disparity distribution of one profile on one frame (degrees; see the module docstring)."""

    median_deg: float
    p95_deg: float
    mean_deg: float
    doubled_fraction: float
    across_deg: float
    along_deg: float
    matches: int
    textured_fraction: float
    coverage: float
    band_deg: tuple[float, float]

    @property
    def measured(self) -> bool:
        return self.matches >= MIN_MATCHES

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in asdict(self).items():
            if isinstance(v, float):
                out[k] = round(v, 4) if math.isfinite(v) else None
            elif isinstance(v, tuple):
                out[k] = [round(x, 3) for x in v]
            else:
                out[k] = v
        return out


def disparity_warning(disparity: SeamDisparity) -> str | None:
    """The ``seam_disparity`` warning of a measured disparity that says the profile does not fit the frame (a median
    above :data:`DISPARITY_WARN_DEG` or more than :data:`DOUBLED_WARN_FRACTION` of the matches over
    :data:`DOUBLED_DEG` apart), else None: one rule and one text for ``calibrate fisheye`` and ``capture unwarp``."""
    if not disparity.measured:
        return None
    if disparity.median_deg <= DISPARITY_WARN_DEG and disparity.doubled_fraction <= DOUBLED_WARN_FRACTION:
        return None
    return (
        f"seam_disparity: the two lenses put the same scene points {disparity.median_deg:.2f}° apart (median; "
        f"95 % within {disparity.p95_deg:.1f}°, {100 * disparity.doubled_fraction:.0f} % more than 1°): the "
        f"panorama will show content twice at the seams (warns above {DISPARITY_WARN_DEG:g}°); the profile does "
        "not fit this frame"
    )


def _edge_angles(profile: LensProfile, circles: Any) -> list[float]:
    """Per lens, the angle (degrees) the profile gives its image-circle edge (the circle's radius when given)."""
    out = []
    for i, lens in enumerate(profile.lenses[:2]):
        r = lens.max_radius() if circles is None else float(circles[i].r)
        out.append(math.degrees(float(lens.angle(r * 0.99))))
    return out


def ring_strips(
    image: np.ndarray,
    profile: LensProfile,
    circles: Any = None,
    *,
    step_deg: float = STEP_DEG,
    search_deg: float = SEARCH_DEG,
) -> dict[str, Any]:
    """Both lenses' views of the widened overlap band as ring strips (module docstring, step 1).

    ``image``: the frame ``(H, W[, C])`` in linear light (any scale) or uint8 sRGB; ``profile`` at any
    reference size of its aspect; ``circles``: the frame's image circles (``cx, cy, r`` each, in
    ``image`` pixels) or None (the profile's fields). Returns ``strips`` (two ``(rows, cols)`` uint8,
    gamma-encoded luminance scaled alike), ``masks`` (two bool: the lens sees it), ``directions``
    ``(rows, cols, 3)`` in the camera frame, ``alpha_deg`` (rows), ``pad`` (columns of wrap at each
    side), ``band_deg`` (the overlap band) and ``step_deg``.
    """
    h, w = image.shape[:2]
    prof = profile.scaled(w, h) if tuple(profile.reference_size) != (w, h) else profile
    lum = luminance(np.asarray(image, np.float32)) if image.ndim == 3 else np.asarray(image, np.float32)
    if image.dtype == np.uint8:
        lum = lum / 255.0  # already gamma-encoded
    else:
        lum = np.maximum(lum, 0.0) ** (1 / 2.2)
    t0, t1 = _edge_angles(prof, circles)
    band = (180.0 - t1, t0)
    lo, hi = max(0.0, band[0] - search_deg), min(180.0, band[1] + search_deg)
    # lens pixels per strip pixel: reduce the frame first (area) so the strip samples it without aliasing
    px_per_deg = max(float(l.dradius(math.radians(90.0))) * math.pi / 180.0 for l in prof.lenses[:2])
    s = min(1.0, 1.5 / max(px_per_deg * step_deg, 1e-9))
    if s < 0.9:
        lum = cv2.resize(lum, (max(8, round(w * s)), max(8, round(h * s))), interpolation=cv2.INTER_AREA)
    s_x, s_y = lum.shape[1] / w, lum.shape[0] / h
    alpha = np.arange(lo, hi + 1e-9, step_deg)
    pad = int(math.ceil(search_deg / step_deg)) + 8
    n_psi = int(round(360.0 / step_deg))
    psi = (np.arange(-pad, n_psi + pad) + 0.5) * step_deg
    A, P = np.meshgrid(np.radians(alpha), np.radians(psi), indexing="ij")
    d_ring = np.stack([np.sin(A) * np.cos(P), np.sin(A) * np.sin(P), np.cos(A)], axis=-1)
    d = d_ring @ prof.lenses[0].rotation.T  # ring frame = the front lens' frame -> camera frame
    scale = float(np.percentile(lum[lum > 0], 99.5)) if np.any(lum > 0) else 1.0
    strips, masks = [], []
    for i, lens in enumerate(prof.lenses[:2]):
        x, y, th = project(lens, d)
        edge = math.radians(t0 if i == 0 else t1)
        xs = scale_pixel_coordinates(x, s_x).astype(np.float32)
        ys = scale_pixel_coordinates(y, s_y).astype(np.float32)
        v = cv2.remap(lum, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        m = (th <= edge) & (xs >= 0) & (ys >= 0) & (xs <= lum.shape[1] - 1) & (ys <= lum.shape[0] - 1)
        g = np.clip(v / max(scale, 1e-12), 0, 1) * 255.0
        # outside the lens: a smooth continuation (normalised convolution), so its edge makes no features
        k = (0, 0)
        num = cv2.GaussianBlur(np.where(m, g, 0).astype(np.float32), k, 8.0)
        den = cv2.GaussianBlur(m.astype(np.float32), k, 8.0)
        fill = np.where(den > 1e-3, num / np.maximum(den, 1e-3), float(g[m].mean()) if m.any() else 0.0)
        strips.append(np.where(m, g, fill).astype(np.uint8))
        masks.append(m)
    return {
        "strips": strips,
        "masks": masks,
        "directions": d,
        "alpha_deg": alpha,
        "pad": pad,
        "band_deg": band,
        "step_deg": step_deg,
    }


def _keypoints(strip: np.ndarray, mask: np.ndarray, sift: Any) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoint positions ``(n, 2)`` (x, y strip px) and descriptors ``(n, 128)`` well inside ``mask``."""
    rows = np.nonzero(mask.any(axis=1))[0]
    if not rows.size:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    r0, r1 = max(0, rows[0] - 8), min(mask.shape[0], rows[-1] + 9)  # only the rows the lens sees, and a margin
    kps, desc = sift.detectAndCompute(np.ascontiguousarray(strip[r0:r1]), None)
    if desc is None or not kps:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    xy = np.array([k.pt for k in kps], np.float64) + [0.0, r0]
    size = np.array([k.size for k in kps], np.float64)
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3)
    xi = np.clip(np.round(xy[:, 0]).astype(int), 0, mask.shape[1] - 1)
    yi = np.clip(np.round(xy[:, 1]).astype(int), 0, mask.shape[0] - 1)
    keep = dist[yi, xi] > np.maximum(3.0, 0.75 * size)  # the descriptor's support lies inside the lens' view
    return xy[keep], np.asarray(desc, np.float32)[keep]


def _directions_at(d: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Directions ``(n, 3)`` at strip positions (bilinear in the direction grid, renormalised)."""
    rows, cols = d.shape[:2]
    x = np.clip(xy[:, 0] - 0.5, 0, cols - 1.001)  # strip pixel centres at +0.5 (SIFT: at integers + 0.5)
    y = np.clip(xy[:, 1] - 0.5, 0, rows - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    v = (
        d[y0, x0] * (1 - fx) * (1 - fy)
        + d[y0, x0 + 1] * fx * (1 - fy)
        + d[y0 + 1, x0] * (1 - fx) * fy
        + d[y0 + 1, x0 + 1] * fx * fy
    )
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _match(
    dir0: np.ndarray, desc0: np.ndarray, dir1: np.ndarray, desc1: np.ndarray, search_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest descriptor neighbours passing the ratio test among candidates within ``search_deg``."""
    if not len(desc0) or not len(desc1):
        return np.zeros(0, int), np.zeros(0, int)
    cos_max = math.cos(math.radians(search_deg))
    n0 = np.sum(desc0**2, 1)
    n1 = np.sum(desc1**2, 1)
    best01 = np.full(len(desc0), -1)
    ok01 = np.zeros(len(desc0), bool)
    best10_d = np.full(len(desc1), np.inf)
    best10 = np.full(len(desc1), -1)
    for a in range(0, len(desc0), 1024):
        b = slice(a, a + 1024)
        dd = n0[b, None] + n1[None, :] - 2.0 * desc0[b] @ desc1.T
        dd = np.where(dir0[b] @ dir1.T >= cos_max, np.maximum(dd, 0.0), np.inf)
        order = np.argsort(dd, axis=1)[:, :2]
        first = np.take_along_axis(dd, order[:, :1], 1)[:, 0]
        second = np.take_along_axis(dd, order[:, 1:2], 1)[:, 0] if dd.shape[1] > 1 else np.full(len(first), np.inf)
        best01[b] = order[:, 0]
        ok01[b] = np.isfinite(first) & (np.sqrt(first) < RATIO * np.sqrt(second))
        col = np.argmin(dd, axis=0)
        val = dd[col, np.arange(dd.shape[1])]
        better = val < best10_d
        best10_d[better], best10[better] = val[better], col[better] + a
    i0 = np.nonzero(ok01)[0]
    i1 = best01[i0]
    mutual = best10[i1] == i0
    return i0[mutual], i1[mutual]


@dataclass(frozen=True)
class SeamMatches:
    """Scene points both lenses show: ``p0``, ``p1`` ``(n, 2)`` pixel positions (frame of ``size = (W, H)``) of
    each match in lens 0 and lens 1, found under some profile but a property of the frame: any profile can be
    judged (:func:`match_disparity`) or fitted on them. ``band_deg``, ``textured_fraction``: as in
    :class:`SeamDisparity`, of the profile they were found with."""

    p0: np.ndarray
    p1: np.ndarray
    size: tuple[int, int]
    band_deg: tuple[float, float]
    textured_fraction: float


def seam_matches(
    image: np.ndarray,
    profile: LensProfile,
    circles: Any = None,
    *,
    step_deg: float = STEP_DEG,
    search_deg: float = SEARCH_DEG,
) -> SeamMatches:
    """The SIFT matches of the two lenses' ring strips under ``profile`` (module docstring, steps 1-2)."""
    h, w = image.shape[:2]
    prof = profile.scaled(w, h) if tuple(profile.reference_size) != (w, h) else profile
    strips = ring_strips(image, prof, circles, step_deg=step_deg, search_deg=search_deg)
    s0, s1 = strips["strips"]
    m0, m1 = strips["masks"]
    d, pad, band = strips["directions"], strips["pad"], strips["band_deg"]
    alpha = strips["alpha_deg"]
    core = np.zeros_like(m0)
    core[:, pad:-pad] = True
    in_band = ((alpha >= band[0]) & (alpha <= band[1]))[:, None] & core
    common = m0 & m1 & in_band
    gy, gx = np.gradient(cv2.GaussianBlur(s0.astype(np.float32), (0, 0), 1.0))
    grad = np.hypot(gx, gy) / step_deg
    textured = float(np.mean(grad[common] > TEXTURE_LEVEL)) if common.any() else 0.0
    sift = cv2.SIFT_create(nfeatures=0, contrastThreshold=0.01)  # type: ignore[attr-defined]  # stubs lack it
    xy0, desc0 = _keypoints(s0, m0, sift)
    xy1, desc1 = _keypoints(s1, m1, sift)
    # the wrap pad holds copies of the ring's ends: lens 0's keypoints are taken in the core only
    keep0 = (xy0[:, 0] >= pad) & (xy0[:, 0] < s0.shape[1] - pad)
    xy0, desc0 = xy0[keep0], desc0[keep0]
    dir0, dir1 = _directions_at(d, xy0), _directions_at(d, xy1)
    i0, i1 = _match(dir0, desc0, dir1, desc1, search_deg)
    px = []
    for lens, dirs in zip(prof.lenses[:2], (dir0[i0], dir1[i1])):
        x, y, _ = project(lens, dirs)
        px.append(np.stack([x, y], axis=-1) if len(dirs) else np.zeros((0, 2)))
    return SeamMatches(px[0], px[1], (w, h), (float(band[0]), float(band[1])), textured)


def match_disparity(profile: LensProfile, matches: SeamMatches) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per match, the angle (degrees) between the directions ``profile`` gives its two pixels, and those directions
    ``(n, 3)`` (camera frame) from lens 0 and lens 1."""
    prof = profile.scaled(*matches.size) if tuple(profile.reference_size) != matches.size else profile
    a = unproject(prof.lenses[0], matches.p0[:, 0], matches.p0[:, 1])[0]
    b = unproject(prof.lenses[1], matches.p1[:, 0], matches.p1[:, 1])[0]
    disp = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1)))
    return disp, a, b


def _nan(band: tuple[float, float], matches: int, textured: float) -> SeamDisparity:
    nan = math.nan
    return SeamDisparity(nan, nan, nan, nan, nan, nan, matches, textured, 0.0, band)


def summarize(profile: LensProfile, matches: SeamMatches) -> SeamDisparity:
    """The disparity distribution of ``profile`` on ``matches`` (module docstring, step 3)."""
    band, n = matches.band_deg, len(matches.p0)
    if n < MIN_MATCHES:
        return _nan(band, n, matches.textured_fraction)
    disp, a, b = match_disparity(profile, matches)
    prof = profile.scaled(*matches.size) if tuple(profile.reference_size) != matches.size else profile
    R0 = prof.lenses[0].rotation
    al, bl = a @ R0, b @ R0  # front lens' frame: the ring's axis is +z
    ang_a = np.arccos(np.clip(al[:, 2], -1, 1))
    across = np.degrees(np.arccos(np.clip(bl[:, 2], -1, 1)) - ang_a)
    along = np.degrees(wrap_angle(np.arctan2(bl[:, 1], bl[:, 0]) - np.arctan2(al[:, 1], al[:, 0]))) * np.sin(ang_a)
    az = np.degrees(np.arctan2(al[:, 1], al[:, 0])) % 360.0
    ang = np.degrees(ang_a)
    sectors = np.unique((az[(ang >= band[0]) & (ang <= band[1])] // 10).astype(int))
    return SeamDisparity(
        median_deg=float(np.median(disp)),
        p95_deg=float(np.percentile(disp, 95)),
        mean_deg=float(np.mean(disp)),
        doubled_fraction=float(np.mean(disp > DOUBLED_DEG)),
        across_deg=float(np.median(across)),
        along_deg=float(np.median(along)),
        matches=n,
        textured_fraction=matches.textured_fraction,
        coverage=float(len(sectors) / 36.0),
        band_deg=band,
    )


def seam_disparity(
    image: np.ndarray,
    profile: LensProfile,
    circles: Any = None,
    *,
    step_deg: float = STEP_DEG,
    search_deg: float = SEARCH_DEG,
) -> SeamDisparity:
    """The seam disparity of ``profile`` on a dual-fisheye frame (module docstring).

    ``image``: ``(H, W[, C])`` linear float or uint8 sRGB; ``circles``: the frame's image circles
    (:func:`~solidkit.calibration.circles.find_image_circles`) or None (the profile's fields).
    """
    return summarize(profile, seam_matches(image, profile, circles, step_deg=step_deg, search_deg=search_deg))
