"""Sun detection in equirectangular panoramas: where the sun is, or that there is none.

Two named methods (docs/conventions.md §6; angles in radians here, degrees at the CLI/JSON edge):

- ``"core"`` (default): the centroid of the sun's bright core (the component of pixels above
  half the lightly blurred peak that contains the peak or, in a display-referred LDR panorama,
  the saturated blob), taken over the core and its skirt. A candidate is accepted as the sun only
  if it stands far above the bright sky around it and is compact. It lands on the sun, not on a
  bright sky region.
- ``"paper"``: the SOLID-Net paper's recipe for its sun-position metric (brightest 2 % of the
  map, largest connected component, its centroid), kept to reproduce the paper's evaluation.

Both label connected components across the ±180° azimuth seam and across each pole, compute the
centroid on the sphere (solid-angle-weighted mean of unit direction vectors, luminance-weighted
too for "core", then normalised; never in pixel space), return sub-pixel coordinates and a
confidence, and return ``found=False`` for overcast or occluded panoramas.

Measured on the real Poly Haven panoramas in ``../shared/data/real/hdr_panoramas`` (1024 x 512;
see ``tests/envmap/test_sun.py``): "core" is 0.007° (sunrise.exr) and 0.029° (city.exr) from the
saturated-core centroid; "paper" is 5.73° and 4.24° off, because its largest top-2 % component
is the sun together with the bright sky around it. courtyard.exr: the sun is occluded by the
carport roof; both methods return ``found=False``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, cast

import cv2
import numpy as np

from solidkit.envmap.coords import (
    angles_from_coords,
    angles_from_direction,
    angular_distance,
    coords_from_direction,
    direction_from_coords,
    solid_angle,
)
from solidkit.envmap.io import validate_panorama
from solidkit.errors import InputError

__all__ = [
    "SUN_ANGULAR_DIAMETER",
    "REC709_LUMINANCE",
    "LUMINANCE_WEIGHTS",
    "SunDetection",
    "detect_sun",
    "sun_core",
    "sun_paper",
    "label_spherical",
    "spherical_centroid",
    "luminance",
]

SUN_ANGULAR_DIAMETER = math.radians(0.53)
"""Mean angular diameter of the sun's disk seen from the Earth, radians."""

REC709_LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 / sRGB luminance weights of linear R, G, B (conventions §5): the one place these numbers are written."""

LUMINANCE_WEIGHTS = np.array(REC709_LUMINANCE, dtype=np.float32)
""":data:`REC709_LUMINANCE` as float32, for ``image @ LUMINANCE_WEIGHTS``."""

Method = Literal["core", "paper"]


@dataclass(frozen=True)
class SunDetection:
    """Result of :func:`detect_sun`.

    Attributes
    ----------
    found : bool
        Whether a sun was found. When ``False`` the angular fields are ``None``.
    direction : ndarray (3,) float64 or None
        Unit sun direction in the panorama frame (x right, y down, z forward).
    azimuth, elevation : float or None
        Radians (conventions §3): azimuth in ``[-pi, pi)``, 0 = forward, positive to the right;
        elevation positive up.
    x, y : float or None
        Sub-pixel continuous equirect coordinates of ``direction`` (pixel ``(u, v)`` has its centre
        at ``(u + 0.5, v + 0.5)``).
    confidence : float
        In ``[0, 1]``; see :func:`sun_core` and :func:`sun_paper` for its definition per method.
    method : str
        ``"core"`` or ``"paper"``.
    contrast : float
        Peak luminance of the candidate over the bright-sky background level (see :func:`sun_core`).
    size : float
        Equivalent angular diameter ``2 sqrt(Omega / pi)`` of the region the centroid was taken
        over, radians.
    n_pixels : int
        Number of pixels in that region.
    reason : str
        One line saying why the sun was (not) found.
    """

    found: bool
    direction: np.ndarray | None
    azimuth: float | None
    elevation: float | None
    x: float | None
    y: float | None
    confidence: float
    method: str
    contrast: float = 0.0
    size: float = 0.0
    n_pixels: int = 0
    reason: str = ""

    @property
    def azimuth_deg(self) -> float | None:
        """Azimuth in degrees (``None`` when not found)."""
        return None if self.azimuth is None else math.degrees(self.azimuth)

    @property
    def elevation_deg(self) -> float | None:
        """Elevation in degrees (``None`` when not found)."""
        return None if self.elevation is None else math.degrees(self.elevation)

    def to_json(self) -> dict[str, Any]:
        """The CLI's JSON: exactly ``{"found", "azimuth_deg", "elevation_deg", "confidence"}``."""
        return {
            "found": bool(self.found),
            "azimuth_deg": self.azimuth_deg,
            "elevation_deg": self.elevation_deg,
            "confidence": float(self.confidence),
        }


# ---------------------------------------------------------------------------------------------
# small pieces


def luminance(image: Any, dtype: Any = np.float32) -> np.ndarray:
    """Luminance ``(H, W)`` of linear RGB ``(H, W, 3)`` with the Rec. 709 weights (:data:`REC709_LUMINANCE`).

    Computed in ``dtype`` (float32 by default; ``np.float64`` for double precision); a 2-D image or
    a single channel passes through (cast to ``dtype``); channels after the third (alpha) are ignored.

    Examples
    --------
    >>> luminance(np.array([[[1.0, 1.0, 1.0], [0.0, 1.0, 0.0]]]))  # white, pure green
    array([[1.    , 0.7152]], dtype=float32)
    """
    image = np.asarray(image)
    if image.ndim == 2:
        return cast(np.ndarray, image.astype(dtype, copy=False))
    if image.shape[2] == 1:
        return cast(np.ndarray, image[..., 0].astype(dtype, copy=False))
    return cast(np.ndarray, image[..., :3].astype(dtype, copy=False) @ np.asarray(REC709_LUMINANCE, dtype=dtype))


def label_spherical(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected components of an equirect mask ``(H, 2H)`` on the sphere.

    8-connected labelling (``scipy.ndimage.label``), then labels are merged (with
    ``scipy.sparse.csgraph.connected_components``) where the sphere joins what the image splits:
    column 0 touches column ``W - 1`` (the ±180° seam; rows ``v - 1 .. v + 1``), and all pixels of
    the top row touch each other at the zenith (likewise the bottom row at the nadir).

    Returns
    -------
    labels : ndarray (H, W) int32
        0 for background, ``1 .. n`` for the components, numbered in raster order of first pixel.
    n : int
        Number of components.

    Examples
    --------
    >>> mask = np.zeros((8, 16), bool)
    >>> mask[3, [0, 15]] = True  # two pixels either side of the seam
    >>> labels, n = label_spherical(mask)
    >>> n, bool(labels[3, 0] == labels[3, 15])  # one component across the seam
    (1, True)
    """
    from scipy import ndimage  # SciPy on use: commands that only need the weights/constants start faster
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    mask = np.asarray(mask, dtype=bool)
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return labels.astype(np.int32), 0
    pairs = []
    left, right = labels[:, 0], labels[:, -1]
    for shift in (-1, 0, 1):  # 8-connectivity across the seam
        r = np.roll(right, shift)
        if shift == -1:
            r[-1] = 0
        elif shift == 1:
            r[0] = 0
        ok = (left > 0) & (r > 0)
        pairs.append(np.stack([left[ok], r[ok]], axis=1))
    for row in (labels[0], labels[-1]):  # all pixels of a polar row meet at the pole
        present = np.unique(row[row > 0])
        if present.size > 1:
            pairs.append(np.stack([np.full(present.size - 1, present[0]), present[1:]], axis=1))
    edges = np.concatenate(pairs, axis=0) if pairs else np.zeros((0, 2), dtype=labels.dtype)
    if edges.size == 0:
        return labels.astype(np.int32), int(n)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n + 1, n + 1))
    _, comp = connected_components(graph, directed=False)
    # renumber so that background stays 0 and components are 1..m in order of first appearance
    comp_of_label = comp[1:]
    _, first, inverse = np.unique(comp_of_label, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    lut = np.concatenate([[0], order[inverse] + 1]).astype(np.int32)
    merged = lut[labels]
    return merged, int(first.size)


def spherical_centroid(weights: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray | None:
    """Weighted centroid on the sphere of an equirect weight map ``(H, 2H)``.

    ``d = normalise(sum_p w_p Omega_p n_p)`` over the pixels in ``mask`` (all when ``None``), with
    ``n_p`` the unit direction and ``Omega_p`` the solid angle of pixel ``p``
    (:func:`~solidkit.envmap.coords.direction_from_coords`, :func:`~solidkit.envmap.coords.solid_angle`).
    Returns the unit vector ``(3,)`` float64, or ``None`` when the weighted sum vanishes.

    Examples
    --------
    >>> w = np.zeros((8, 16))
    >>> w[3, [7, 8]] = 1.0  # two pixels either side of forward
    >>> np.round(spherical_centroid(w), 6) + 0.0
    array([ 0.      , -0.198763,  0.980048])
    """
    weights = np.asarray(weights)
    h = weights.shape[0]
    if mask is None:
        mask = weights != 0
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return None
    w = weights[rows, cols].astype(np.float64) * solid_angle(h)[rows, cols]
    dirs = _pixel_directions(rows, cols, h)
    s = (w[:, None] * dirs).sum(axis=0)
    norm = float(np.linalg.norm(s))
    if not np.isfinite(norm) or norm <= 1e-300 * max(float(np.abs(w).sum()), 1e-300):
        return None
    return cast(np.ndarray, s / norm)


def _pixel_directions(rows: np.ndarray, cols: np.ndarray, h: int) -> np.ndarray:
    """Unit directions ``(n, 3)`` float64 of the centres of pixels ``(rows, cols)``."""
    return cast(np.ndarray, direction_from_coords(cols + 0.5, rows + 0.5, h))


def _cos_to(h: int, centre: np.ndarray) -> np.ndarray:
    """``cos`` of the angle between every pixel centre and ``centre`` (``(H, 2H)`` float32), built
    from per-row and per-column factors instead of a full direction grid (large panoramas)."""
    phi, theta = angles_from_coords(np.arange(2 * h) + 0.5, np.arange(h) + 0.5, h)
    cols = (np.sin(phi) * centre[0] + np.cos(phi) * centre[2]).astype(np.float32)
    rows_sin = (np.sin(theta) * centre[1]).astype(np.float32)[:, None]
    return cast(np.ndarray, np.cos(theta).astype(np.float32)[:, None] * cols[None, :] - rows_sin)


def _weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The ``q``-quantile of ``values`` under ``weights`` (solid angle): lower step of the weighted CDF."""
    if values.size == 0:
        return 0.0
    order = np.argsort(values, kind="stable")
    cdf = np.cumsum(weights[order], dtype=np.float64)
    i = int(np.searchsorted(cdf, q * cdf[-1], side="left"))
    return float(values[order[min(i, values.size - 1)]])


def _blur(lum: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur that wraps across the azimuth seam (rows clamp at the poles)."""
    if sigma_px < 0.3:
        return lum
    from scipy import ndimage

    return cast(np.ndarray, ndimage.gaussian_filter(lum, sigma_px, mode=("nearest", "wrap"), truncate=3.0))


def _background(lum: np.ndarray, centre: np.ndarray, exclude: float, q: float, max_height: int = 512) -> float:
    """Solid-angle-weighted ``q``-quantile of luminance outside a cap of radius ``exclude`` about
    ``centre``: the bright-sky level. A smooth statistic, so it is taken on an area-averaged copy
    at most ``max_height`` rows high (``cv2.INTER_AREA``), which keeps large panoramas fast."""
    h = lum.shape[0]
    if h > max_height:
        small = max_height
        lum = cv2.resize(lum, (2 * small, small), interpolation=cv2.INTER_AREA)
        h = small
    outside = _cos_to(h, centre) < math.cos(exclude)
    return _weighted_quantile(lum[outside], solid_angle(h)[outside], q)


def _component_stats(
    labels: np.ndarray, n: int, values: np.ndarray, omega: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-component peak of ``values`` and solid angle, for labels ``1 .. n`` (only labelled pixels are read)."""
    sel = labels > 0
    lab = labels[sel]
    peaks = np.full(n + 1, -np.inf)
    np.maximum.at(peaks, lab, values[sel].astype(np.float64))
    areas = np.bincount(lab, weights=np.broadcast_to(omega, labels.shape)[sel], minlength=n + 1)
    return peaks[1:], areas[1:]


def _prepare(pano: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(H, 2H, C)`` float panorama (C in 1, 3; negatives clipped) and its luminance."""
    pano = np.asarray(pano)
    if not np.issubdtype(pano.dtype, np.floating):
        raise InputError(
            f"expected a float (linear) panorama, got dtype {pano.dtype}; decode LDR with read_ldr(linear=True)"
        )
    if pano.ndim == 2:
        pano = pano[..., None]
    if pano.ndim == 3 and pano.shape[2] not in (1, 3):
        pano = pano[..., :3]  # RGBA: alpha is not light
    validate_panorama(pano, "panorama")
    if pano.shape[2] not in (1, 3):
        raise InputError(f"panorama has {pano.shape[2]} channels; expected 1 or 3 (RGB)")
    if pano.shape[0] < 2:
        raise InputError(f"panorama of shape {pano.shape} is too small to look for the sun in")
    if np.any(pano < 0):
        pano = np.clip(pano, 0.0, None)
    return pano, luminance(pano)


def _result(method: str, direction: np.ndarray | None, h: int, **kw: Any) -> SunDetection:
    if direction is None:
        return SunDetection(False, None, None, None, None, None, method=method, **kw)
    phi, theta = angles_from_direction(direction)
    phi = float(phi) - 2.0 * math.pi if float(phi) >= math.pi else float(phi)  # [-pi, pi) (conventions §3)
    x, y = coords_from_direction(direction, h)
    return SunDetection(True, direction, float(phi), float(theta), float(x), float(y), method=method, **kw)


def _size(omega_sum: float) -> float:
    return 2.0 * math.sqrt(max(omega_sum, 0.0) / math.pi)


# ---------------------------------------------------------------------------------------------
# the two methods


def sun_core(
    pano: np.ndarray,
    *,
    rel_threshold: float = 0.5,
    rel_centroid: float = 0.01,
    blur: float = math.radians(0.1),
    saturation: float | None = None,
    min_contrast: float = 20.0,
    max_size: float = math.radians(4.0),
    background_quantile: float = 0.99,
    exclude: float = math.radians(5.0),
) -> SunDetection:
    """Find the sun as the centroid of its bright (or saturated) core.

    Steps (all on the sphere):

    1. Luminance ``L`` (Rec. 709) and a light Gaussian blur ``Lb`` of ``blur`` radians that wraps
       the seam (skylibs' ``findBrightestSpot`` blurs too; here the blur only locates the peak and
       shapes the masks, the centroid uses the unblurred ``L``).
    2. Core: HDR: the pixels with ``Lb >= rel_threshold * max(Lb)`` (the half-maximum core of the
       sun; a sensor-clipped plateau lies inside it). Display-referred LDR (``max <= 1``, e.g. the
       1/25000 s Theta frames in which only the sun clips), or when ``saturation`` is given: the
       pixels whose channels are all ``>= saturation`` (0.98 for LDR), the saturated blob; an LDR
       panorama without any saturated pixel falls back to the half-maximum core.
    3. Components of the core mask across the ±180° seam and the poles (:func:`label_spherical`);
       the candidate is the component with the highest blurred peak (ties, as among saturated
       blobs: the largest solid angle).
    4. Background: the ``background_quantile`` (solid-angle weighted) of ``L`` outside a cap of
       radius ``exclude`` about the candidate, i.e. the bright sky, not the median of a dark ground.
    5. Direction: the centroid (:func:`spherical_centroid`, luminance- and solid-angle-weighted
       unit vectors) of the candidate grown to its skirt, the component of
       ``Lb >= t = max(rel_centroid * peak, 2 * background)`` that contains it, with weights
       ``L - t`` (continuous at the mask's edge, so pixels entering or leaving it do not make the
       result jump). This captures the sun's whole point-spread function (for a saturated blob:
       its partially covered rim), which makes the centroid unbiased and sub-pixel. If that
       centroid strays from the core's own centroid by more than the core's radius (a lopsided
       skirt: lens flare, an adjacent cloud), the core's centroid is kept.
    6. Decision. ``contrast = peak / background``; ``size = 2 sqrt(Omega / pi)`` of the core, its
       equivalent angular diameter, allowed up to ``max(max_size, 4 pixels)`` for a blurred or
       saturated core (the disk itself is 0.53°). The sun is found iff ``contrast >= min_contrast``
       and ``size <= max_size``; otherwise (overcast sky, a bright cloud, a sunlit wall while the
       sun is occluded) ``found=False`` with no angles.

    ``confidence = (1 - min_contrast / contrast) * (1 - ((size - s0) / (max_size - s0))^2)``,
    each factor clipped to ``[0, 1]``, with ``s0 = max(0.53°, 2.5 pixels)`` the smallest core a sun
    can show at this resolution: 0 exactly when not found, near 1 for a sharp sun far above the sky.

    Accuracy (``tests/envmap/test_sun.py``): a 0.53° disk rendered at 1024 x 512 (box-filtered, 1.5 px
    wide) is found within 0.02°; one blurred by a 1-pixel PSF at 256 x 128 within 0.01°, at the
    seam and at 85°+ elevation too. A disk smaller than a pixel without any blur (256 x 128,
    0.37 px) has no recoverable sub-pixel position: up to half a pixel (0.35°) off.

    Parameters
    ----------
    pano : ndarray (H, 2H, 3) or (H, 2H)
        Linear RGB (or luminance) equirectangular panorama, float; finite.
    rel_threshold : float
        Core threshold relative to the blurred peak (HDR).
    rel_centroid : float
        Skirt threshold relative to the peak for the centroid (HDR).
    blur : float
        Gaussian sigma in radians (skipped below 0.3 px).
    saturation : float or None
        Saturation level per channel; ``None``: 0.98 when ``max <= 1`` (LDR), otherwise unused.
    min_contrast, max_size, background_quantile, exclude : float
        Decision parameters (sizes and angles in radians).

    Returns
    -------
    SunDetection

    Examples
    --------
    >>> pano = np.full((64, 128, 3), 0.5, np.float32)
    >>> pano[20:22, 80:82] = 5e4
    >>> sun = sun_core(pano)
    >>> sun.found, sun.method, round(sun.x, 3), round(sun.y, 3)
    (True, 'core', 81.0, 21.005)
    """
    pano, lum = _prepare(pano)
    h, w = lum.shape
    omega = solid_angle(h)
    px = 2.0 * math.pi / w
    limit = max(max_size, 4.0 * px)
    lum_b = _blur(lum, blur / px)
    if float(lum_b.max()) <= 0.0:
        return _result("core", None, h, confidence=0.0, reason="the panorama is black")

    if saturation is None and float(pano.max()) <= 1.0 + 1e-6:
        saturation = 0.98
    mask = pano.min(axis=2) >= saturation if saturation is not None else None
    saturated = mask is not None and bool(mask.any())
    if not saturated:
        mask = lum_b >= rel_threshold * float(lum_b.max())
    labels, n = label_spherical(cast(np.ndarray, mask))
    peaks, areas = _component_stats(labels, n, lum_b, omega)
    best = int(np.lexsort((areas, peaks))[-1]) + 1
    core = labels == best
    direction = spherical_centroid(lum, core)
    if direction is None:
        return _result("core", None, h, confidence=0.0, reason="the candidate has no energy")
    peak = float(peaks[best - 1])
    size = _size(float(areas[best - 1]))
    bg = _background(lum, direction, exclude, background_quantile)
    t = max(rel_centroid * peak, 2.0 * bg)
    skirt_labels, _ = label_spherical(lum_b >= t)
    skirt = np.isin(skirt_labels, np.unique(skirt_labels[core & (skirt_labels > 0)]))
    refined = spherical_centroid(np.clip(lum - t, 0.0, None), skirt | core)
    if refined is not None and float(angular_distance(refined, direction)) <= max(size / 2, px):
        direction = refined  # else the skirt is lopsided (flare, a cloud): keep the core's centroid
    contrast = peak / bg if bg > 0 else math.inf
    c_contrast = 1.0 - min_contrast / contrast if contrast > 0 else 0.0
    nominal = max(SUN_ANGULAR_DIAMETER, 2.5 * px)  # the smallest core a sun can show at this resolution
    c_size = 1.0 - (max(size - nominal, 0.0) / max(limit - nominal, 1e-12)) ** 2
    common = dict(contrast=contrast, size=size, n_pixels=int(core.sum()))
    if contrast < min_contrast:
        reason = f"brightest spot only {contrast:.3g}x the bright sky (< {min_contrast:g}x): overcast or occluded"
        return _result("core", None, h, confidence=0.0, reason=reason, **common)
    if size > limit:
        reason = f"bright core {math.degrees(size):.2f} deg wide (> {math.degrees(limit):.2f}): not a sun disk"
        return _result("core", None, h, confidence=0.0, reason=reason, **common)
    confidence = float(np.clip(c_contrast, 0.0, 1.0) * np.clip(c_size, 0.0, 1.0))
    kind = "saturated blob" if saturated else "core"
    reason = f"sun {kind} of {int(core.sum())} px, {contrast:.3g}x the bright sky"
    return _result("core", direction, h, confidence=confidence, reason=reason, **common)


def sun_paper(
    pano: np.ndarray,
    *,
    percentile: float = 98.0,
    weighting: Literal["geometric", "luminance"] = "geometric",
    min_contrast: float = 20.0,
    background_quantile: float = 0.99,
    exclude: float = math.radians(5.0),
    concentration_radius: float = math.radians(1.0),
) -> SunDetection:
    """The SOLID-Net paper's sun position: centroid of the largest bright component.

    Zhu et al., "Spatially-Varying Outdoor Lighting Estimation from Intrinsics", CVPR 2021, §5.1:
    "computing the sun position by finding the largest connected component of the sky above a
    threshold (98%) and computing its centroid". The recipe, literally: the threshold is the
    98th percentile of the map's pixel luminances (``numpy.percentile``), pixels strictly above
    it form components (8-connected, joined across the ±180° seam and the poles,
    :func:`label_spherical`), the largest component (by solid angle) is kept and its centroid is
    taken on the sphere (:func:`spherical_centroid`): ``weighting="geometric"`` (default, the
    paper's "its centroid": every pixel weighted by its solid angle only) or ``"luminance"``
    (additionally weighted by luminance, as ``scipy.ndimage.center_of_mass`` would).

    This reproduces the paper's metric; it does not reliably find the sun. On real HDR panoramas
    the largest top-2 % component is the sun together with the bright sky around it, and its
    centroid lies in that sky (measured, 1024 x 512: 5.73° off on sunrise.exr, 4.24° on city.exr
    geometric; 0.72° and 1.36° luminance-weighted). Use :func:`sun_core` to find the sun.

    "No sun": the component's peak must stand ``min_contrast`` times above the bright sky
    (``background_quantile`` of luminance outside a cap of radius ``exclude`` about that peak),
    as in :func:`sun_core`; an overcast map returns ``found=False``.
    ``confidence = (1 - min_contrast / contrast) * f``, with ``f`` the fraction of the
    component's luminance energy (``L Omega``) within ``concentration_radius`` of the returned
    direction: low when the centroid sits in the sky beside the sun.

    Examples
    --------
    On a clear sun both methods agree (the paper's metric differs where the sun is clipped or hazy):

    >>> sky = np.full((64, 128, 3), 0.5, np.float32)
    >>> sky[20:22, 80:82] = 5e4
    >>> paper, core = sun_paper(sky), sun_core(sky)
    >>> paper.method, round(math.degrees(float(angular_distance(paper.direction, core.direction))), 6)
    ('paper', 0.0)
    """
    pano, lum = _prepare(pano)
    h, _ = lum.shape
    omega = solid_angle(h)
    if weighting not in ("geometric", "luminance"):
        raise InputError(f"unknown centroid weighting {weighting!r} (expected 'geometric' or 'luminance')")
    if float(lum.max()) <= 0.0:
        return _result("paper", None, h, confidence=0.0, reason="the panorama is black")
    mask = lum > np.percentile(lum, percentile)
    if not mask.any():  # e.g. a constant map: nothing is above its own percentile
        return _result("paper", None, h, confidence=0.0, reason=f"no pixel above the {percentile:g}th percentile")
    labels, n = label_spherical(mask)
    _, areas = _component_stats(labels, n, lum, omega)
    best = int(np.argmax(areas)) + 1
    region = labels == best
    direction = spherical_centroid(lum if weighting == "luminance" else np.ones_like(lum), region)
    if direction is None:
        return _result("paper", None, h, confidence=0.0, reason="the component has no energy")
    flat = np.where(region, lum, -np.inf)
    peak_pos = np.unravel_index(int(np.argmax(flat)), flat.shape)
    peak = float(lum[peak_pos])
    peak_dir = _pixel_directions(np.array(peak_pos[0]), np.array(peak_pos[1]), h)
    bg = _background(lum, peak_dir, exclude, background_quantile)
    contrast = peak / bg if bg > 0 else math.inf
    common = dict(contrast=contrast, size=_size(float(areas[best - 1])), n_pixels=int(region.sum()))
    if contrast < min_contrast:
        reason = f"largest bright component peaks only {contrast:.3g}x the bright sky (< {min_contrast:g}x)"
        return _result("paper", None, h, confidence=0.0, reason=reason, **common)
    energy = (lum * omega)[region]
    rows, cols = np.nonzero(region)
    near = _pixel_directions(rows, cols, h) @ direction >= math.cos(concentration_radius)
    frac = float(energy[near].sum() / energy.sum())
    confidence = float(np.clip(1.0 - min_contrast / contrast, 0.0, 1.0) * frac)
    reason = f"largest component above the {percentile:g}th percentile: {int(region.sum())} px"
    return _result("paper", direction, h, confidence=confidence, reason=reason, **common)


def detect_sun(pano: np.ndarray, method: Method = "core", **kwargs: Any) -> SunDetection:
    """Detect the sun in an equirectangular panorama.

    Parameters
    ----------
    pano : ndarray (H, 2H, 3) or (H, 2H)
        Linear RGB (HDR, or LDR decoded to linear) panorama in the conventions' frame.
    method : {"core", "paper"}
        ``"core"`` (default, :func:`sun_core`) finds the sun; ``"paper"`` (:func:`sun_paper`)
        reproduces the SOLID-Net paper's metric.
    **kwargs
        Passed to the method.

    Returns
    -------
    SunDetection
        ``found``, unit ``direction``, ``azimuth``/``elevation`` (radians), sub-pixel ``x, y``,
        ``confidence`` in ``[0, 1]``; the angles are ``None`` when no sun was found.

    Examples
    --------
    >>> from solidkit.envmap.coords import coords_from_angles
    >>> pano = np.full((64, 128, 3), 0.5, np.float32)
    >>> x, y = coords_from_angles(math.radians(40.0), math.radians(30.0), 64)
    >>> pano[int(y), int(x)] = 5e4  # the pixel holding azimuth 40°, elevation 30°
    >>> sun = detect_sun(pano)
    >>> sun.found, round(sun.azimuth_deg, 1), round(sun.elevation_deg, 1)  # that pixel's centre
    (True, 40.8, 29.5)
    >>> detect_sun(np.full((64, 128, 3), 0.5, np.float32)).found  # overcast: no sun
    False
    """
    if method == "core":
        return sun_core(pano, **kwargs)
    if method == "paper":
        return sun_paper(pano, **kwargs)
    raise InputError(f"unknown sun detection method {method!r} (expected 'core' or 'paper')")
