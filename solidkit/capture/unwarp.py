"""Dual-fisheye -> equirectangular unwarping through a lens profile, and re-orienting stitched input.

For every output pixel (direction from :func:`solidkit.envmap.coords.direction_from_coords`,
i.e. the :func:`~solidkit.envmap.coords.direction_grid` formula, evaluated in row blocks to bound
memory) the direction is taken into the camera frame (``d_cam = R_levelᵀ d_pano``), projected
into each lens through the profile (:func:`solidkit.camera.lens.project`) and the lens images
are sampled with ``cv2.remap``. The lenses are blended by *feathering* across their overlap: with
``m_i = max_angle_i - theta_i`` the angular margin of lens ``i``, the weights are
``w_i = clip(0.5 + (m_i - max_{j != i} m_j) / (2 f), 0, 1)`` (normalised), a linear cross-fade
over a band of ``feather_deg`` of incidence angle centred where the margins are equal (90° for
two opposite lenses of equal field). Per-lens, per-channel gains are matched in *linear* light on
the overlap (median log ratio of unsaturated pixels, split symmetrically between the lenses)
before blending. An optional vignetting profile (:mod:`solidkit.calibration.vignetting`) divides
each lens' linear samples by that lens' radial falloff ``V(ρ)`` first (:func:`vignetting_gains`),
so gain matching and blending see falloff-free radiance: without it the two lenses disagree on
the overlap by ``V(ρ_0)/V(ρ_1)``, which a single gain cannot remove where the circles' radii vary.

Orientation (docs/conventions.md §2): the output panorama is gravity-aligned with forward = the
front lens' axis projected onto the horizontal plane. ``R_level = R(0, pitch, roll)`` comes from
the metadata (:func:`solidkit.camera.metadata.level_rotation`); Ricoh's camera axes (Z up, +Y
toward the front lens, X right) map to ours by ``RICOH_TO_OURS`` (x = X, y = -Z, z = Y).
Stitched equirectangular input (e.g. Theta SC2 stills) that the camera did not zenith-correct
is rotated by ``R_level`` (:func:`solidkit.envmap.resample.rotate`); when no rotation is needed
the pixels are passed through untouched (no resampling).

Remap tables are cached per (profile, input size, output size, orientation): in memory (LRU of
:data:`CACHE_SIZE` entries) and optionally on disk (``.npz`` named by a SHA-256 of the key), as
OpenCV fixed-point maps (1/32 px, what ``cv2.remap`` uses internally for bilinear sampling).

8-bit sRGB in and out (JPEG -> PNG/JPEG) takes :func:`unwarp_srgb8`: the same geometry, gains and
feathering, but only the feather band is decoded to linear light and blended; elsewhere the one
lens' sample gets its gain through an exact 8-bit table ``enc(g dec(v))``. It matches the float
path within one code value (``tests/test_unwarp.py``) at a fraction of the memory traffic.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from solidkit.camera.lens import LensProfile, project
from solidkit.envmap.coords import direction_from_coords
from solidkit.errors import InputError

__all__ = [
    "CACHE_SIZE",
    "UnwarpMaps",
    "build_maps",
    "get_maps",
    "feather_weights",
    "match_gains",
    "unwarp",
    "seam_disagreement",
    "clear_cache",
    "render_fisheye",
    "cut_columns",
    "seam_step",
    "unwarp_srgb8",
    "encode_srgb8",
    "vignetting_gains",
    "load_vignetting",
    "default_out_height",
]

CACHE_SIZE = 4
_ROWS = 256
_cache: "OrderedDict[str, UnwarpMaps]" = OrderedDict()


def default_out_height(in_width: int) -> int:
    """Default equirect height for a dual-fisheye input ``in_width`` px wide: the panorama is as wide
    as the input (``2 H = in_width``: 5792x2896 -> 5792x2896), keeping the lenses' centre resolution.

    Used by ``solidkit capture unwarp`` (no ``--size``) and by the campaign's products.
    """
    return max(2, int(in_width) // 2)


@dataclass
class UnwarpMaps:
    """Per-lens remap tables for one (profile, input size, output size, orientation).

    ``map1`` ``(L, H, 2H, 2)`` int16 and ``map2`` ``(L, H, 2H)`` uint16: OpenCV's fixed-point
    maps (``cv2.convertMaps(..., CV_16SC2)``; 1/32-px sub-pixel positions, the precision
    ``cv2.remap`` uses internally for bilinear interpolation anyway) of the fisheye pixel
    coordinates; ``weight``: ``(L, H, 2H)`` float32 feather weights summing to 1 where any lens
    sees (0 where a lens does not).
    """

    map1: np.ndarray
    map2: np.ndarray
    weight: np.ndarray
    _derived: dict = field(default_factory=dict, repr=False, compare=False)

    def band(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Two lenses: ``(lens0_dominant (H, 2H) bool, band flat indices, lens-0 weight there)``."""
        if "band" not in self._derived:
            w0 = self.weight[0]
            idx = np.flatnonzero((w0 > 0) & (self.weight[1] > 0))
            self._derived["band"] = (w0 >= 0.5, idx, w0.reshape(-1)[idx].astype(np.float32))
        return self._derived["band"]

    @property
    def coverage(self) -> np.ndarray:
        """``(H, 2H)`` bool: some lens sees this output pixel."""
        return self.weight.sum(axis=0) > 0

    @property
    def overlap(self) -> np.ndarray:
        """``(H, 2H)`` bool: blended pixels (at least two lenses with weight > 0)."""
        return (self.weight > 0).sum(axis=0) >= 2


def feather_weights(margin: np.ndarray, feather_deg: float) -> np.ndarray:
    """Cross-fade weights ``(L, ...)`` from angular margins ``(L, ...)`` (radians); see module doc."""
    L = margin.shape[0]
    f = max(math.radians(feather_deg), 1e-6)
    valid = margin > 0
    m = np.where(valid, margin, -np.inf)
    if L == 1:
        return valid.astype(np.float32)
    w = np.empty_like(margin, dtype=np.float32)
    for i in range(L):
        others = np.max(np.delete(m, i, axis=0), axis=0)
        with np.errstate(invalid="ignore"):  # -inf - -inf where no lens sees: masked below
            diff = np.where(np.isfinite(others), m[i] - others, np.inf)
        w[i] = np.where(valid[i], np.clip(0.5 + diff / (2 * f), 0.0, 1.0), 0.0)
    s = w.sum(axis=0)
    return np.where(s > 0, w / np.where(s > 0, s, 1), 0).astype(np.float32)


def build_maps(
    profile: LensProfile, in_size: tuple[int, int], out_height: int, R_level: Any = None, feather_deg: float = 10.0
) -> UnwarpMaps:
    """Remap tables for unwarping a ``in_size = (W, H)`` dual-fisheye image to a ``(out_height, 2 out_height)`` panorama."""
    prof = profile.scaled(*in_size)
    R = np.eye(3) if R_level is None else np.asarray(R_level, dtype=np.float64)
    H, W, L = out_height, 2 * out_height, len(prof.lenses)
    map1 = np.empty((L, H, W, 2), np.int16)
    map2 = np.empty((L, H, W), np.uint16)
    margin = np.empty((L, H, W), np.float32)
    xs = np.arange(W, dtype=np.float64) + 0.5
    w_in, h_in = in_size
    for r0 in range(0, H, _ROWS):
        r1 = min(H, r0 + _ROWS)
        yy, xx = np.meshgrid(np.arange(r0, r1, dtype=np.float64) + 0.5, xs, indexing="ij")
        d_cam = direction_from_coords(xx, yy, H) @ R  # row vectors: (R^T d)^T
        for i, lens in enumerate(prof.lenses):
            x, y, theta = project(lens, d_cam)
            m = math.radians(lens.max_angle_deg) - theta
            inside = (x >= -0.5) & (x <= w_in - 0.5) & (y >= -0.5) & (y <= h_in - 0.5)  # never sample outside the frame
            margin[i, r0:r1] = np.where(inside, m, np.minimum(m, -1e-6))
            x = np.clip(x, -2.0, w_in + 1.0).astype(np.float32)
            y = np.clip(y, -2.0, h_in + 1.0).astype(np.float32)
            map1[i, r0:r1], map2[i, r0:r1] = cv2.convertMaps(x, y, cv2.CV_16SC2)
    weight = feather_weights(margin, feather_deg)
    return UnwarpMaps(map1, map2, weight)


def _key(profile: LensProfile, in_size: tuple[int, int], out_height: int, R: np.ndarray, feather_deg: float) -> str:
    h = hashlib.sha256()
    h.update(profile.key().encode())
    h.update(repr((tuple(in_size), int(out_height), float(feather_deg))).encode())
    h.update(np.round(np.asarray(R, dtype=np.float64), 12).tobytes())
    return h.hexdigest()[:24]


def clear_cache() -> None:
    """Empty the in-memory remap cache."""
    _cache.clear()


def get_maps(
    profile: LensProfile, in_size: tuple[int, int], out_height: int, R_level: Any = None, feather_deg: float = 10.0,
    cache_dir: str | os.PathLike | None = None,
) -> tuple[UnwarpMaps, str]:
    """:func:`build_maps` through the in-memory LRU and the optional on-disk cache.

    Returns ``(maps, source)`` with ``source`` one of ``"memory"``, ``"disk"``, ``"built"``.
    """
    R = np.eye(3) if R_level is None else np.asarray(R_level, dtype=np.float64)
    key = _key(profile, in_size, out_height, R, feather_deg)
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key], "memory"
    path = Path(cache_dir) / f"unwarp-{key}.npz" if cache_dir is not None else None
    maps = None
    source = "built"
    if path is not None and path.is_file():
        try:
            with np.load(path) as z:
                maps = UnwarpMaps(z["map1"], z["map2"], z["weight"])
            source = "disk"
        except (OSError, ValueError, KeyError):
            maps = None  # unreadable cache file: rebuild and overwrite
    if maps is None:
        maps = build_maps(profile, in_size, out_height, R, feather_deg)
        if path is not None:
            from solidkit.fsutil import atomic_path

            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path, suffix=".npz") as tmp:
                with open(tmp, "wb") as f:
                    np.savez(f, map1=maps.map1, map2=maps.map2, weight=maps.weight)
    _cache[key] = maps
    while len(_cache) > CACHE_SIZE:
        _cache.popitem(last=False)
    return maps, source


# sRGB 8-bit -> linear float32 (exact per code value) and linear -> sRGB 8-bit through a 16-bit index
_DECODE_LUT: np.ndarray | None = None
_ENCODE_LUT: np.ndarray | None = None


def _luts() -> tuple[np.ndarray, np.ndarray]:
    global _DECODE_LUT, _ENCODE_LUT
    if _DECODE_LUT is None:
        from solidkit.envmap.io import srgb_decode, srgb_encode

        _DECODE_LUT = np.asarray(srgb_decode(np.arange(256, dtype=np.float64) / 255.0), np.float32)
        enc = np.asarray(srgb_encode(np.arange(65536, dtype=np.float64) / 65535.0))
        _ENCODE_LUT = np.round(np.clip(enc, 0, 1) * 255.0).astype(np.uint8)
    return _DECODE_LUT, _ENCODE_LUT


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear ``[0, 1]`` float -> sRGB uint8 (IEC 61966-2-1) through a 65536-entry table."""
    _, enc = _luts()
    x = np.clip(linear, 0.0, 1.0).astype(np.float32, copy=False)
    x *= 65535.0
    np.rint(x, out=x)
    return enc[x.astype(np.uint16)]


def _warp(image: np.ndarray, maps: UnwarpMaps, i: int) -> np.ndarray:
    """Lens ``i``'s image sampled at its map, ``(H, 2H, C)`` float32 *linear* (zeros outside).

    uint8 input is taken as sRGB-encoded: it is interpolated in that encoding (as cameras and
    ffmpeg do) and then decoded to linear exactly per code value.
    """
    w = cv2.remap(image, maps.map1[i], maps.map2[i], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if w.ndim == 2:
        w = w[..., None]
    if image.dtype == np.uint8:
        dec, _ = _luts()
        return dec[w]
    return w.astype(np.float32, copy=False)


def _stride(shape: tuple[int, ...], target: int = 1024) -> int:
    return max(1, shape[0] // target)


def match_gains(
    warped: list[np.ndarray], maps: UnwarpMaps, saturation: float | None = 0.98, floor: float = 1e-3,
    scale: np.ndarray | None = None,
) -> np.ndarray:
    """Per-lens, per-channel linear gains ``(L, C)`` equalising the lenses on their overlap.

    ``warped``: each lens' linear view ``(H, 2H, C)``. For two lenses: ``ratio_c = exp(median(log
    I_0 - log I_1))`` over feather-band pixels (both weights > 0; every k-th row and column for
    outputs above 1024 rows) that are neither black (``< floor``) nor saturated (``>= saturation``
    in any channel, for LDR input); lens 0 gets ``ratio^-1/2``, lens 1 ``ratio^+1/2``. More lenses
    are matched to lens 0 and renormalised to a geometric mean of 1. Returns ones when the overlap
    has < 100 usable pixels. ``scale`` ``(L, H, 2H)`` (optional): per-pixel factors already applied
    to ``warped`` (vignetting correction); the black/clipped tests use the values as captured,
    ``warped / scale``.
    """
    L, C = len(warped), warped[0].shape[-1]
    k = _stride(warped[0].shape)
    gains = np.ones((L, C), np.float64)
    valid = maps.weight[:, ::k, ::k] > 0
    for i in range(1, L):
        both = valid[0] & valid[i]
        a, b = warped[0][::k, ::k][both], warped[i][::k, ::k][both]
        a_cap, b_cap = a, b
        if scale is not None:
            a_cap = a / scale[0, ::k, ::k][both][:, None]
            b_cap = b / scale[i, ::k, ::k][both][:, None]
        ok = np.all((a_cap > floor) & (b_cap > floor), axis=-1)
        if saturation is not None:
            ok &= np.all((a_cap < saturation) & (b_cap < saturation), axis=-1)
        if ok.sum() < 100:
            continue
        gains[i] = np.exp(np.median(np.log(a[ok]) - np.log(b[ok]), axis=0))
    gains /= np.exp(np.mean(np.log(gains), axis=0, keepdims=True))
    return gains


def seam_disagreement(warped: list[np.ndarray], maps: UnwarpMaps, gains: np.ndarray | None = None) -> dict[str, float]:
    """Photometric disagreement of lenses 0 and 1 on their overlap (after ``gains``).

    Returns ``{"seam_mad": median |I_0 - I_1|, "seam_rmse": ..., "overlap_px": n}`` over the
    feather band (pixels where both lenses have weight > 0; channel-averaged, image units; every
    k-th row and column for outputs above 1024 rows, ``overlap_px`` counts the full band).
    """
    nan = {"seam_mad": math.nan, "seam_rmse": math.nan, "overlap_px": 0}
    if len(warped) < 2:
        return nan
    k = _stride(warped[0].shape)
    g = np.ones((len(warped), warped[0].shape[-1])) if gains is None else gains
    both = (maps.weight[0, ::k, ::k] > 0) & (maps.weight[1, ::k, ::k] > 0)
    diff = (warped[0][::k, ::k][both] * g[0] - warped[1][::k, ::k][both] * g[1]).mean(axis=-1)
    if diff.size == 0:
        return nan
    return {"seam_mad": float(np.median(np.abs(diff))), "seam_rmse": float(np.sqrt(np.mean(diff**2))),
            "overlap_px": int(((maps.weight[0] > 0) & (maps.weight[1] > 0)).sum())}


def load_vignetting(path: str | os.PathLike) -> Any:
    """A :class:`~solidkit.calibration.vignetting.VignettingProfile` from its JSON file (``solidkit calibrate vignetting``)."""
    from solidkit.calibration.vignetting import VignettingProfile

    return VignettingProfile.load(path)


def vignetting_gains(maps: UnwarpMaps, vignetting: Any, profile: LensProfile, in_size: tuple[int, int]) -> np.ndarray:
    """Per-lens inverse falloff ``1 / V_i(ρ_i)`` at every output pixel, ``(L, H, 2H)`` float32.

    ``ρ_i`` is the distance of the sample position of lens ``i`` (the remap table, in pixels of
    the ``in_size = (W, H)`` input) from that lens' optical centre over its ``r_norm`` in the
    vignetting profile (:meth:`~solidkit.calibration.vignetting.VignettingProfile.scaled`), and
    ``V`` the profile's radial polynomial (:func:`~solidkit.calibration.vignetting.falloff`):
    the same correction as :func:`~solidkit.calibration.vignetting.correct_vignetting` applied
    to each lens' own samples. The profile's lenses are matched to the lens profile's by name
    (by order when the names differ). 1 where the lens does not contribute.

    Raises :class:`~solidkit.calibration.vignetting.VignettingError` when the profile is for
    another layout, has another number of lenses, or its falloff drops below 5 % where a lens
    is used.
    """
    from solidkit.calibration.vignetting import VignettingError, falloff

    L = maps.weight.shape[0]
    vl = vignetting.scaled(*in_size)
    if len(vl) != L:
        raise VignettingError(f"vignetting profile has {len(vl)} lenses, lens profile {profile.model!r} has {L}")
    names = [lens.name for lens in profile.lenses]
    by_name = {v.name: v for v in vl}
    if sorted(by_name) == sorted(names):
        vl = [by_name[n] for n in names]
    key = ("vignetting", vignetting.model_dump_json(), tuple(in_size))
    cached = maps._derived.get("vignetting")
    if cached is not None and cached[0] == key:
        return cached[1]
    out = np.ones(maps.weight.shape, np.float32)
    for i, v in enumerate(vl):
        used = maps.weight[i] > 0
        xy = cv2.convertMaps(maps.map1[i], maps.map2[i], cv2.CV_32FC2)[0]  # (H, 2H, 2) sample positions
        rho = np.hypot(xy[..., 0][used] - v.center[0], xy[..., 1][used] - v.center[1]) / v.r_norm_px
        V = falloff(v.coeffs, rho)
        if V.size and (not np.all(np.isfinite(V)) or V.min() <= 0.05):
            raise VignettingError(f"lens {v.name}: the falloff drops below 5 % inside the image circle: the profile is unusable")
        out[i][used] = (1.0 / V).astype(np.float32)
    maps._derived["vignetting"] = (key, out)
    return out


def unwarp(
    image: np.ndarray,
    profile: LensProfile,
    out_height: int,
    R_level: Any = None,
    *,
    feather_deg: float = 10.0,
    gain_match: bool = True,
    saturation: float | None = None,
    cache_dir: str | os.PathLike | None = None,
    stats: dict | None = None,
    vignetting: Any = None,
) -> np.ndarray:
    """Unwarp a dual-fisheye image ``(h, w, C)`` to a *linear* equirect ``(out_height, 2 out_height, C)`` float32.

    ``image``: linear float (e.g. DNG, EXR, or decoded sRGB) or uint8 sRGB-encoded (interpolated
    in its encoding, then decoded to linear per code value: the fast path for JPEGs). Gains and
    blending are in linear light. ``saturation``: linear value at/above which a pixel counts as
    clipped when estimating gains (``None``: no clipping, e.g. HDR; uint8 input defaults to the
    linear value of code 250). ``stats`` (if given) receives the gains, the seam disagreement
    before/after gain matching, coverage and the remap-cache source. ``vignetting``
    (a :class:`~solidkit.calibration.vignetting.VignettingProfile`, optional): each lens' linear
    samples are divided by its falloff before gain matching and blending (:func:`vignetting_gains`).
    """
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3:
        raise InputError(f"expected an (H, W, C) image, got shape {image.shape}")
    if image.dtype not in (np.uint8, np.float32):
        image = image.astype(np.float32)
    if image.dtype == np.uint8 and saturation is None:
        saturation = float(_luts()[0][250])
    h, w = image.shape[:2]
    maps, source = get_maps(profile, (w, h), out_height, R_level, feather_deg, cache_dir)
    L = maps.weight.shape[0]
    warped = [_warp(image, maps, i) for i in range(L)]
    C = warped[0].shape[-1]
    inv_v = None
    if vignetting is not None:
        inv_v = vignetting_gains(maps, vignetting, profile, (w, h))
        for i in range(L):
            warped[i] *= inv_v[i][..., None]
    gains = match_gains(warped, maps, saturation, scale=inv_v) if gain_match and L > 1 else np.ones((L, C))
    if stats is not None:
        stats["gains"] = gains.tolist()
        stats["cache"] = source
        stats["coverage"] = float(maps.coverage.mean())
        stats["seam_mad_before_gain"] = seam_disagreement(warped, maps)["seam_mad"]
        stats["vignetting"] = vignetting is not None
        stats.update(seam_disagreement(warped, maps, gains))
    out = None
    for i in range(L):
        v = warped[i]
        v *= gains[i].astype(np.float32)
        v *= maps.weight[i][..., None]
        if out is None:
            out = v
        else:
            out += v
        warped[i] = None
    return out


def unwarp_srgb8(
    image: np.ndarray,
    profile: LensProfile,
    out_height: int,
    R_level: Any = None,
    *,
    feather_deg: float = 10.0,
    gain_match: bool = True,
    cache_dir: str | os.PathLike | None = None,
    stats: dict | None = None,
    vignetting: Any = None,
) -> np.ndarray:
    """Fast path of :func:`unwarp` for 8-bit sRGB in and out (JPEG -> PNG/JPEG), two lenses.

    Same geometry, gains and feathering as :func:`unwarp`, evaluated where it matters: outside
    the feather band each output pixel is one lens' sample with its gain applied exactly in
    linear light through a per-channel 8-bit table ``enc(g_c dec(v))``; inside the band the two
    samples are decoded to linear, gain-matched, blended and re-encoded. Returns uint8 sRGB.
    With a ``vignetting`` profile (a per-pixel correction no 8-bit table can carry) or other than
    two lenses it is :func:`unwarp` followed by :func:`encode_srgb8`.
    """
    if image.dtype != np.uint8 or image.ndim != 3:
        raise InputError("unwarp_srgb8 needs an (H, W, C) uint8 image")
    h, w = image.shape[:2]
    maps, source = get_maps(profile, (w, h), out_height, R_level, feather_deg, cache_dir)
    if maps.weight.shape[0] != 2 or vignetting is not None:
        lin = unwarp(image, profile, out_height, R_level, feather_deg=feather_deg, gain_match=gain_match,
                     cache_dir=cache_dir, stats=stats, vignetting=vignetting)
        return encode_srgb8(lin)
    dec, enc16 = _luts()
    raw = [cv2.remap(image, maps.map1[i], maps.map2[i], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
           for i in range(2)]
    C = image.shape[2]
    lead, idx, w0 = maps.band()
    band = [r.reshape(-1, C)[idx] for r in raw]  # (n, C) uint8 samples in the feather band
    lin = [dec[b] for b in band]
    gains = np.ones((2, C))
    if gain_match and idx.size:
        sat = float(dec[250])
        ok = np.all((lin[0] > 1e-3) & (lin[1] > 1e-3) & (lin[0] < sat) & (lin[1] < sat), axis=-1)
        if ok.sum() >= 100:
            ratio = np.exp(np.median(np.log(lin[0][ok]) - np.log(lin[1][ok]), axis=0))
            gains = np.stack([ratio**-0.5, ratio**0.5])
    if stats is not None:
        d0 = (lin[0] - lin[1]).mean(-1)
        d1 = (lin[0] * gains[0] - lin[1] * gains[1]).mean(-1)
        stats.update(gains=gains.tolist(), cache=source, coverage=float(maps.coverage.mean()), overlap_px=int(idx.size),
                     seam_mad_before_gain=float(np.median(np.abs(d0))) if d0.size else math.nan,
                     seam_mad=float(np.median(np.abs(d1))) if d1.size else math.nan,
                     seam_rmse=float(np.sqrt(np.mean(d1**2))) if d1.size else math.nan)
    if not np.allclose(gains, 1.0):
        for i in range(2):
            table = encode_srgb8(dec[:, None] * gains[i].astype(np.float32)[None, :])  # (256, C): enc(g dec(v))
            raw[i] = cv2.LUT(raw[i], table.reshape(256, 1, C) if C > 1 else table.reshape(256, 1))
            if raw[i].ndim == 2:
                raw[i] = raw[i][..., None]
    out = raw[1]
    cv2.copyTo(raw[0], lead.astype(np.uint8), out)
    if idx.size:
        blended = (lin[0] * gains[0].astype(np.float32)) * w0[:, None] + (lin[1] * gains[1].astype(np.float32)) * (1 - w0)[:, None]
        out.reshape(-1, C)[idx] = encode_srgb8(blended)
    return out


def render_fisheye(
    source: Any, profile: LensProfile, size: tuple[int, int], R_level: Any = None, interp: str = "linear"
) -> np.ndarray:
    """The forward model: a dual-fisheye image of ``size = (W, H)`` seeing ``source``.

    ``source`` is an equirect panorama ``(h, 2h, C)`` (sampled seam/pole-aware with
    :func:`solidkit.envmap.resample.sample_panorama`) or a callable ``f(d_pano (..., 3)) -> (..., C)``.
    Each pixel within ``r(max_angle)`` of a lens centre shows that lens' view of the scene
    (``d_pano = R_level d_cam``); other pixels are 0. Used to make ground truth for tests.
    """
    from solidkit.camera.lens import unproject
    from solidkit.envmap.resample import sample_panorama

    W, H = size
    prof = profile.scaled(W, H)
    R = np.eye(3) if R_level is None else np.asarray(R_level, dtype=np.float64)
    yy, xx = np.meshgrid(np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64), indexing="ij")
    out = None
    taken = np.zeros((H, W), bool)
    for lens in prof.lenses:
        r = np.hypot(xx - lens.center[0], yy - lens.center[1])
        sel = (r <= lens.max_radius()) & ~taken
        d_cam, _ = unproject(lens, xx[sel], yy[sel])
        d = d_cam @ R.T
        vals = source(d) if callable(source) else sample_panorama(np.asarray(source, np.float32), d, interp)
        vals = np.asarray(vals, np.float32).reshape(len(d), -1)
        if out is None:
            out = np.zeros((H, W, vals.shape[-1]), np.float32)
        out[sel] = vals
        taken |= sel
    return out


def parse_size(text: str | None) -> int | None:
    """``"2048x1024"`` -> output height 1024 (the equirect width must be twice the height)."""
    if text is None:
        return None
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WxH, e.g. 2048x1024") from None
    if w != 2 * h or h < 2:
        raise InputError(f"--size {text}: an equirectangular panorama needs W = 2 H (>= 4x2)")
    return h


def _read_input(path: Path) -> tuple[np.ndarray, float | None]:
    """Image for :func:`unwarp` and its linear clipping level (None for HDR/raw).

    EXR: linear float; raw/DNG: linear float (:func:`solidkit.camera.raw.read_raw`); 8-bit LDR:
    uint8 RGB as stored (sRGB-encoded; :func:`unwarp` decodes per code value). 16-bit LDR is
    decoded to linear float.
    """
    from solidkit.camera.raw import is_raw_file, read_raw
    from solidkit.envmap.io import imread, read_exr, read_ldr

    if path.suffix.lower() == ".exr":
        img, _ = read_exr(path)
        if not np.isfinite(img[..., :3]).all():
            raise InputError(f"{path}: {int((~np.isfinite(img[..., :3])).any(-1).sum())} pixel(s) are NaN or Inf")
        return img[..., :3], None
    if is_raw_file(path):
        return read_raw(path).linear, None
    raw = imread(path)
    if raw.dtype != np.uint8:
        return read_ldr(path, linear=True), 0.98
    if raw.ndim == 2:
        raw = np.repeat(raw[..., None], 3, axis=2)
    return cv2.cvtColor(np.ascontiguousarray(raw[..., :3]), cv2.COLOR_BGR2RGB), float(_luts()[0][250])


def _read_linear(path: Path) -> tuple[np.ndarray, float | None]:
    """:func:`_read_input` with 8-bit images decoded to linear float32."""
    img, sat = _read_input(path)
    if img.dtype == np.uint8:
        img = _luts()[0][img]
    return img, sat


def _write_srgb8(path: Path, enc: np.ndarray) -> None:
    """8-bit sRGB RGB image -> PNG (fast compression) / JPEG (q95) / other LDR, atomically."""
    from solidkit.fsutil import atomic_path

    params = {".png": [cv2.IMWRITE_PNG_COMPRESSION, 1], ".jpg": [cv2.IMWRITE_JPEG_QUALITY, 95],
              ".jpeg": [cv2.IMWRITE_JPEG_QUALITY, 95]}.get(path.suffix.lower(), [])
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(enc, cv2.COLOR_RGB2BGR), params):
            raise InputError(f"{path}: OpenCV cannot write this image format")


def _write(path: Path, linear: np.ndarray, meta: dict) -> None:
    """EXR (linear float, with ``meta``) or 8-bit sRGB LDR (PNG fast compression, JPEG q95), atomically."""
    from solidkit.envmap.io import write_exr

    if path.suffix.lower() == ".exr":
        write_exr(path, linear, meta)
        return
    _write_srgb8(path, encode_srgb8(linear))


def unwarp_file(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    profile: str | os.PathLike | None = None,
    size: str | None = None,
    feather_deg: float = 10.0,
    level: bool = True,
    gain_match: bool = True,
    cache_dir: str | os.PathLike | None = None,
    vignetting: str | os.PathLike | None = None,
) -> dict:
    """``solidkit capture unwarp``: a capture file -> an equirect panorama in the panorama frame.

    Dual-fisheye input goes through the lens profile (``profile``: a shipped name or a unit JSON;
    default: the shipped profile of the EXIF camera model), after dividing each lens by its
    falloff when a ``vignetting`` profile JSON is given; the output is ``size`` or, by default,
    as wide as the input (:func:`default_out_height`). Stitched equirect input is levelled
    from its metadata, or copied byte for byte when no rotation (and no resize) is needed
    (a vignetting profile does not apply to it: a warning says so).
    Returns a summary dict (what was done, gains, seam disagreement, timings).
    """
    import shutil
    import time

    from solidkit.camera.lens import load_profile, profile_for_metadata
    from solidkit.camera.metadata import level_rotation, read_metadata
    from solidkit.envmap.resample import resize, rotate
    from solidkit.fsutil import atomic_path, sha256_file

    from solidkit.envmap.io import LDR_SUFFIXES

    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise InputError(f"{dst}: refusing to overwrite the input (originals are never modified)")
    if dst.suffix.lower() != ".exr" and dst.suffix.lower() not in LDR_SUFFIXES:
        raise InputError(f"{dst}: unknown output type '{dst.suffix}' (use .exr, or .png/.jpg for sRGB)")
    if not (math.isfinite(feather_deg) and feather_deg >= 0):
        raise InputError(f"--feather must be a finite angle >= 0 degrees, got {feather_deg}")
    t0 = time.perf_counter()
    from solidkit.camera.raw import is_raw_file

    has_exif = src.suffix.lower() in (".jpg", ".jpeg", ".dng", ".tif", ".tiff") or is_raw_file(src)
    meta = read_metadata(src) if has_exif else None  # PNG/EXR inputs carry no camera metadata
    summary: dict[str, Any] = {"input": str(src), "output": str(dst), "warnings": list(meta.warnings) if meta else []}
    out_h = parse_size(size)
    vprof = load_vignetting(vignetting) if vignetting is not None else None
    R = level_rotation(meta) if (meta is not None and level) else np.eye(3)
    summary["level_pitch_roll_deg"] = (
        [meta.pitch_deg, meta.roll_deg] if meta is not None and level and not np.allclose(R, np.eye(3)) else None
    )
    stitched = meta is not None and meta.image_type == "equirect" and profile is None
    if stitched:
        if vprof is not None:
            summary["warnings"].append("vignetting_ignored: stitched input; the camera applied its own lens corrections")
        w, h = meta.width, meta.height
        if w != 2 * h:
            raise InputError(f"{src}: marked equirectangular but {w}x{h} is not 2:1")
        identity = np.allclose(R, np.eye(3), atol=1e-12)
        if identity and (out_h is None or out_h == h) and src.suffix.lower() == dst.suffix.lower():
            with atomic_path(dst) as tmp:
                shutil.copyfile(src, tmp)
            summary.update(mode="stitched: copied unchanged (no rotation needed)", resampled=False)
        else:
            img, _ = _read_linear(src)
            if out_h is not None and out_h < img.shape[0]:
                img = resize(img, out_h)  # energy-preserving downsampling first, then one rotation
            if not identity:
                img = rotate(img, R, "linear", height=out_h)  # out(d) = in(R^T d): camera -> level frame
            elif out_h is not None and out_h != img.shape[0]:
                img = resize(img, out_h)
            _write(dst, img, {"source": str(src), "source_sha256": sha256_file(src), "rotation": R.tolist()})
            summary.update(mode="stitched: levelled from metadata" if not identity else "stitched: re-encoded", resampled=not identity or out_h is not None)
        summary["seconds"] = time.perf_counter() - t0
        return summary
    img, saturation = _read_input(src)
    h, w = img.shape[:2]
    if profile is not None:
        prof = load_profile(profile)
    else:
        prof = profile_for_metadata(meta.model if meta else None, w, h)
    if meta is not None and meta.image_type == "dual_fisheye_upright":
        summary["warnings"].append("upright_dual_fisheye: the camera already rotated the circles upright; no gravity applied")
        R = np.eye(3)
    out_h = out_h or default_out_height(w)
    stats: dict[str, Any] = {}
    t1 = time.perf_counter()
    fast = img.dtype == np.uint8 and dst.suffix.lower() != ".exr" and len(prof.lenses) == 2
    if fast:  # 8-bit in and out: blend in linear light only where two lenses overlap
        pano = unwarp_srgb8(img, prof, out_h, R, feather_deg=feather_deg, gain_match=gain_match, cache_dir=cache_dir,
                            stats=stats, vignetting=vprof)
    else:
        pano = unwarp(img, prof, out_h, R, feather_deg=feather_deg, gain_match=gain_match, saturation=saturation,
                      cache_dir=cache_dir, stats=stats, vignetting=vprof)
    t2 = time.perf_counter()
    meta_out = {"source": str(src), "source_sha256": sha256_file(src), "profile": prof.model,
                "profile_key": prof.key(), "rotation": R.tolist(), "gains": stats["gains"],
                "vignetting": None if vignetting is None else {"path": str(vignetting), "sha256": sha256_file(vignetting)}}
    if fast:
        _write_srgb8(dst, pano)
    else:
        _write(dst, pano, meta_out)
    summary.update(mode="dual-fisheye unwarped", profile=prof.model, size=[2 * out_h, out_h], resampled=True,
                   unwarp_seconds=t2 - t1, seconds=time.perf_counter() - t0, **stats)
    return summary


def cut_columns(maps: UnwarpMaps) -> list[np.ndarray]:
    """Per output row, the columns where the dominant lens changes (the cut of a hard-cut unwarp)."""
    lab = np.argmax(maps.weight, axis=0)
    return [np.nonzero(row != np.roll(row, 1))[0] for row in lab]


def seam_step(gray: np.ndarray, cols_per_row: list, max_elevation_deg: float = 60.0) -> dict[str, float]:
    """How visible a hard cut between lenses is in an equirect image ``gray (H, W)``.

    ``step``: mean ``|g[r, c] - g[r, c - 1]|`` over the cut columns ``c`` of rows within
    ``max_elevation_deg`` of the horizon; ``baseline``: the same for columns 6-15 px beside the
    cut (the image's own texture). Tool-independent: works on any unwarper's output given
    where it cuts (ffmpeg's ``v360`` dfisheye cuts at azimuth ±90°: columns ``W/4`` and ``3W/4``).
    """
    g = np.asarray(gray, dtype=np.float64)
    H, W = g.shape
    el = 90.0 - (np.arange(H) + 0.5) * 180.0 / H
    steps, base = [], []
    for r in np.nonzero(np.abs(el) < max_elevation_deg)[0]:
        for c in cols_per_row[r]:
            steps.append(abs(g[r, c % W] - g[r, (c - 1) % W]))
            for o in (6, 9, 12, 15):
                base.append(abs(g[r, (c + o) % W] - g[r, (c + o - 1) % W]))
                base.append(abs(g[r, (c - o) % W] - g[r, (c - o - 1) % W]))
    if not steps:
        return {"step": math.nan, "baseline": math.nan}
    return {"step": float(np.mean(steps)), "baseline": float(np.mean(base))}
