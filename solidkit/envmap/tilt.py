"""Residual tilt of a panorama: is it really level? Measured from its vertical scene edges.

In a level panorama (conventions §2: y down is gravity) every vertical scene edge (building
corners, poles, window frames) lies on a great circle through the zenith ``(0, -1, 0)``, i.e.
appears as a vertical line of constant azimuth. A panorama whose frame is tilted shows those
edges leaning by an angle that varies like a sinusoid with azimuth. :func:`residual_tilt`
finds the zenith the edges actually agree on (the vertical vanishing point on the sphere):

1. line segments are detected in the (tonemapped) image with OpenCV's LSD (von Gioi et al.,
   "LSD: a Line Segment Detector", IPOL 2012); near-vertical ones (leaning less than
   ``max_lean_deg`` in the image) within ``max_elevation_deg`` of the horizon are kept;
2. each segment's end points become unit directions ``d1, d2`` and its great circle the unit
   normal ``n = d1 x d2``: a vertical edge satisfies ``n . z = 0`` for the true zenith ``z``;
3. ``z`` is found by RANSAC over segment pairs (``z = n_i x n_j``), then refined by
   iteratively reweighted least squares: the smallest eigenvector of ``sum w n nᵀ``, ``w``
   the inverse variance of ``n . z`` (end-point noise over the segment's angular length, so a
   long edge counts much more than a short one) times Tukey's biweight of the normalised residual;
4. its 1-sigma uncertainty comes from the residuals' spread and the normal matrix of the
   two tilt components (Gauss-Newton linearisation about ``z``).

The result is the gravity ``g = -z`` in the panorama's frame, the tilt ``angle(g, (0, 1, 0))``
and the correction ``R(0, pitch, roll)`` (conventions §4) that maps ``g`` to ``(0, 1, 0)``:
``solidkit.envmap.resample.rotate(pano, correction)`` levels the panorama. The pitch/roll
algebra is that of ``g = R_z(roll)ᵀ R_x(pitch)ᵀ e_y = (sin r cos p, cos r cos p, -sin p)``
(the Ricoh gravity reading of :mod:`solidkit.camera.metadata`).

A panorama without enough vertical structure (open fields, sky) gives ``reliable = False``:
the estimate then says nothing. ``reliable`` needs ``min_segments`` inliers spread over at
least two azimuth directions 30°+ apart (one direction constrains only one tilt component)
and an uncertainty below ``max_uncertainty_deg``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from solidkit.envmap.coords import angles_from_direction, direction_from_coords, rotation_from_ypr
from solidkit.envmap.resample import rotate

__all__ = ["TiltEstimate", "residual_tilt", "correction_from_gravity", "TILT_FLAG_DEG"]

#: Residual tilts above this (degrees) are flagged by ingest and ``capture info``/``unwarp``.
TILT_FLAG_DEG = 0.5


@dataclass(frozen=True)
class TiltEstimate:
    """Residual tilt of a panorama (degrees; see the module docstring).

    ``tilt_deg``: angle between the edges' zenith and the frame's; ``pitch_deg``/``roll_deg``:
    the levelling correction ``R(0, pitch, roll)``; ``uncertainty_deg``: 1-sigma of the tilt
    (largest axis); ``segments``: inlier edges used; ``reliable``: enough edges in enough
    directions (else the numbers say nothing); ``gravity``: unit down vector in the frame.
    """

    tilt_deg: float
    pitch_deg: float
    roll_deg: float
    uncertainty_deg: float
    segments: int
    reliable: bool
    gravity: tuple[float, float, float]

    def to_json(self) -> dict[str, Any]:
        return {
            k: (round(v, 4) if isinstance(v, float) else list(v) if isinstance(v, tuple) else v)
            for k, v in asdict(self).items()
        }


def correction_from_gravity(g: np.ndarray) -> tuple[float, float]:
    """``(pitch, roll)`` in radians of ``R(0, pitch, roll)`` mapping the unit gravity ``g`` to ``(0, 1, 0)``.

    Examples
    --------
    >>> from solidkit.envmap.coords import rotation_from_ypr
    >>> g = rotation_from_ypr(0.0, math.radians(3.0), 0.0).T @ [0.0, 1.0, 0.0]  # gravity seen by a camera pitched 3°
    >>> [round(math.degrees(a), 6) for a in correction_from_gravity(g)]
    [3.0, 0.0]
    """
    g = np.asarray(g, np.float64) / np.linalg.norm(g)
    return math.asin(max(-1.0, min(1.0, -g[2]))), math.atan2(g[0], g[1])


def _gray8(pano: np.ndarray) -> np.ndarray:
    """8-bit gray image for line detection: uint8 as stored (channel mean), float tonemapped (99th percentile ->
    white, sRGB-like)."""
    img = np.asarray(pano)
    if img.dtype == np.uint8:
        if img.ndim == 3 and img.shape[-1] >= 3:
            return cv2.transform(img[..., :3], np.full((1, 3), 1.0 / 3.0))  # channel order does not matter
        return img if img.ndim == 2 else img[..., 0]
    if img.ndim == 3:
        img = img[..., :3].mean(axis=-1) if img.shape[-1] >= 3 else img[..., 0]
    x = np.nan_to_num(img.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    scale = np.percentile(x, 99) or x.max() or 1.0
    return (np.clip(x / scale, 0.0, 1.0) ** (1 / 2.2) * 255.0 + 0.5).astype(np.uint8)


_LSD_SCALE = 0.8  # OpenCV's default: LSD works on a Gaussian-subsampled copy


def _segments(
    gray: np.ndarray, max_lean_deg: float, max_elevation_deg: float, min_length_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Great-circle normals ``(N, 3)`` and angular lengths ``(N,)`` of near-vertical segments."""
    h = gray.shape[0]
    lim = h / 2 * (1 - max_elevation_deg / 90.0)  # rows above/below this are too close to a pole
    top = max(0, int(lim) - 2)
    lines = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, _LSD_SCALE).detect(gray[top : h - top])[0]
    if lines is None:
        return np.zeros((0, 3)), np.zeros(0)
    # LSD's coordinates put pixel centres at integers and map its subsampled copy back by 1/scale
    # (an edge between columns 99 and 100 comes back at 99.375): continuous coords (centres at +0.5)
    x1, y1, x2, y2 = (lines.reshape(-1, 4).astype(np.float64) + 0.5 / _LSD_SCALE + np.array([0, top, 0, top])).T
    dx, dy = x2 - x1, y2 - y1
    length = np.hypot(dx, dy)
    vertical = np.abs(dx) <= math.tan(math.radians(max_lean_deg)) * np.abs(dy)
    inside = (np.minimum(y1, y2) >= lim) & (np.maximum(y1, y2) <= h - lim)
    keep = vertical & inside & (length >= min_length_px)
    d1 = np.asarray(direction_from_coords(x1[keep], y1[keep], h), np.float64)
    d2 = np.asarray(direction_from_coords(x2[keep], y2[keep], h), np.float64)
    n = np.cross(d1, d2)
    norm = np.linalg.norm(n, axis=-1)
    ok = norm > 1e-9
    ang = np.arcsin(np.clip(norm[ok], 0.0, 1.0))
    return n[ok] / norm[ok, None], ang


def _refine(n: np.ndarray, sigma: np.ndarray, z: np.ndarray, iters: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """IRLS with Tukey weights on ``(n . z) / sigma`` (c = 4.685): the zenith and the final weights."""
    w = np.zeros(len(n))
    for _ in range(iters):
        u = (n @ z) / (4.685 * sigma)
        w = np.where(np.abs(u) < 1.0, (1.0 - u**2) ** 2, 0.0) / sigma**2
        if w.sum() <= 0:
            break
        vals, vecs = np.linalg.eigh((n * w[:, None]).T @ n)
        z_new = vecs[:, 0] * np.sign(vecs[:, 0] @ z)
        done = np.linalg.norm(z_new - z) < 1e-12
        z = z_new
        if done:
            break
    return z, w


def _zenith(
    gray: np.ndarray,
    max_lean_deg: float,
    max_elevation_deg: float,
    ransac_iters: int,
    edge_px: float,
    model_deg: float,
    seed: int,
) -> tuple[np.ndarray, float, int, bool]:
    """One pass on an 8-bit panorama: (zenith, uncertainty in degrees, inlier count, azimuth spread ok)."""
    h = gray.shape[0]
    n, ang = _segments(gray, max_lean_deg, max_elevation_deg, max(8.0, h / 64))
    up = np.array([0.0, -1.0, 0.0])
    if len(n) < 2:
        return up, math.inf, int(len(n)), False
    # 1-sigma distance of the zenith from a segment's great circle: the lean of a line fitted to L px
    # of an edge with per-pixel noise e (std of a least-squares slope: e sqrt(12) / L^1.5), plus a
    # floor for imperfect scene edges
    px = math.pi / h
    sigma = np.hypot(edge_px * math.sqrt(12.0) / (ang / px) ** 1.5, math.radians(model_deg))
    # RANSAC: the zenith near up that most great circles (weighted by 1/sigma^2) pass through
    rng = np.random.default_rng(seed)
    info = 1.0 / sigma**2
    best_z, best_score = up, (np.abs(n @ up) < 3.0 * sigma) @ info
    cos_max = math.cos(math.radians(max_lean_deg))
    # all hypotheses at once: pairs drawn by precision, z = n_i x n_j turned toward up
    i = rng.choice(len(n), ransac_iters, p=info / info.sum())
    j = rng.choice(len(n), ransac_iters, p=info / info.sum())
    z = np.cross(n[i], n[j])
    nz = np.linalg.norm(z, axis=1)
    ok = (i != j) & (nz >= 1e-6)
    z = z[ok] / nz[ok, None]
    z *= np.where(z @ up >= 0, 1.0, -1.0)[:, None]
    z = z[z @ up >= cos_max]
    if len(z):
        scores = (np.abs(z @ n.T) < 3.0 * sigma) @ info
        k = int(np.argmax(scores))
        if scores[k] > best_score:
            best_z, best_score = z[k], scores[k]
    z, W = _refine(n, sigma, best_z)
    inl = W > 0
    m = int(inl.sum())
    # uncertainty: linearise n.z about z in two tangent directions; scale by the reduced chi-square
    e1 = np.cross(z, [1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.cross(z, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(z, e1)
    A = np.stack([n[inl] @ e1, n[inl] @ e2], axis=1)
    r = n[inl] @ z
    unc = math.inf
    if m > 2:
        chi2 = float((W[inl] * r**2).sum()) / (m - 2)
        try:
            cov = max(chi2, 1e-12) * np.linalg.inv((A * W[inl, None]).T @ A)
            unc = math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)))
        except np.linalg.LinAlgError:
            pass
    # two azimuth directions at least 30° apart (mod 180°: an edge constrains the tilt across it)
    d_mid = np.cross(n[inl], z)  # a direction on each great circle, on the horizon of z
    az = np.asarray(angles_from_direction(d_mid)[0], np.float64) % math.pi if m else np.zeros(0)
    spread = bool(m) and float(np.max(np.abs(np.sin(az[:, None] - az[None, :])))) >= math.sin(math.radians(30.0))
    return z, unc, m, spread


def residual_tilt(
    pano: np.ndarray,
    *,
    max_lean_deg: float = 12.0,
    max_elevation_deg: float = 60.0,
    min_segments: int = 8,
    max_uncertainty_deg: float = 0.3,
    ransac_iters: int = 500,
    edge_px: float = 1.0,
    model_deg: float = 0.03,
    seed: int = 0,
    max_height: int = 1024,
) -> TiltEstimate:
    """Estimate how far a panorama is from level (module docstring).

    Parameters
    ----------
    pano : ndarray (H, 2H[, C])
        Equirectangular panorama in the frame to check: uint8 (sRGB) or float (linear HDR).
    max_lean_deg : float
        Largest image-space lean of a segment still taken as a candidate vertical (the tilts this
        can measure are a little below it).
    max_elevation_deg : float
        Segments must lie within this elevation of the horizon (equirect distortion near the poles).
    min_segments, max_uncertainty_deg : int, float
        What ``reliable`` needs.
    ransac_iters, seed
        RANSAC of the zenith: pairs tried (drawn by precision), random seed.
    edge_px, model_deg
        Noise model: 1-sigma position noise of the edge pixels a segment is fitted to (pixels; its
        lean then has a std of ``edge_px sqrt(12) / L^1.5`` for ``L`` pixels, the slope of a line
        fit) and of a scene edge's verticality (degrees); a segment's weight is the inverse variance
        of its great circle's distance from the zenith. (An end-point model, ``∝ 1 / L``, gave short
        segments 10x more weight than their measured leans earn: on 3 rendered level streets at
        1024 px high, 0.17° off while the longest edges were vertical to 0.01°.)
    max_height : int
        Larger panoramas are first reduced to this height (area averaging): time drops, but so does
        precision (benchmarks/results/tilt.md, rendered streets level and tilted up to 4°: at 1024 px
        high median 0.04°, max 0.18° over 36 cases; the same reduced to 512, median 0.08°, max 0.29°).

    Returns
    -------
    TiltEstimate

    Examples
    --------
    >>> from solidkit.envmap.coords import direction_grid, rotation_from_ypr
    >>> from solidkit.envmap.resample import rotate
    >>> d = direction_grid(256)
    >>> stripes = np.floor(np.arctan2(d[..., 0], d[..., 2]) / (np.pi / 12)) % 2 == 0  # vertical edges every 15°
    >>> pano = np.repeat(np.where(stripes, 0.9, 0.3)[..., None], 3, axis=2).astype(np.float32)
    >>> round(residual_tilt(pano).tilt_deg, 1)
    0.0
    >>> t = residual_tilt(rotate(pano, rotation_from_ypr(0.0, math.radians(3.0), 0.0)))  # content pitched 3°
    >>> round(t.tilt_deg), round(t.pitch_deg)  # R(0, pitch, roll) levels it again
    (3, -3)
    """
    img = np.asarray(pano)
    h = img.shape[0]
    if img.ndim < 2 or img.shape[1] != 2 * h:
        raise ValueError(f"not an equirectangular panorama: shape {img.shape}")
    if img.dtype == np.uint8:
        gray = _gray8(img)  # full size: 8-bit gray is cheaper to reduce than colour
    elif h > max_height:  # reduce first: the tonemap then touches max_height² pixels, not H²
        img = cv2.resize(img.astype(np.float32, copy=False), (2 * max_height, max_height), interpolation=cv2.INTER_AREA)
    if img.dtype != np.uint8:
        gray = _gray8(img)
    if h > max_height:
        gray = (
            cv2.resize(gray, (2 * max_height, max_height), interpolation=cv2.INTER_AREA)
            if gray.shape[0] > max_height
            else gray
        )
        h = max_height
    params = (max_lean_deg, max_elevation_deg, ransac_iters, edge_px, model_deg, seed)
    z, unc, m, spread = _zenith(gray, *params)
    if m >= 2 and math.degrees(math.acos(min(1.0, float(-z[1])))) > 0.05:
        # a tilted frame bends vertical edges into curves that straight segments fit with a bias:
        # level the image with the first estimate and measure what is left (composed back)
        p1, r1 = correction_from_gravity(-z)
        R1 = np.asarray(rotation_from_ypr(0.0, p1, r1))
        levelled = np.clip(rotate(gray.astype(np.float32), R1, "cubic"), 0, 255).astype(np.uint8)
        z2, unc2, m2, spread2 = _zenith(levelled, *params)
        if m2 >= 2:
            z, unc, m, spread = R1.T @ z2, unc2, m2, spread2
    g = -z
    pitch, roll = correction_from_gravity(g)
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(g[1])))))
    reliable = m >= min_segments and spread and unc <= max_uncertainty_deg
    return TiltEstimate(
        tilt, math.degrees(pitch), math.degrees(roll), unc, m, reliable, (float(g[0]), float(g[1]), float(g[2]))
    )
