"""The dual-fisheye camera model as image formation: lens profile -> remap tables -> per-lens panoramas.

For every pixel of a ``(H, 2H)`` equirect panorama (direction from
:func:`solidkit.envmap.coords.direction_from_coords`, evaluated in row blocks to bound memory)
the direction is taken into the camera frame (``d_cam = R_levelᵀ d_pano``) and projected into
each lens through the profile (:func:`solidkit.camera.lens.project`); :class:`UnwarpMaps` holds
the resulting ``cv2.remap`` tables and the feather weights (:func:`feather_weights`),
:func:`warp_lens` samples one lens, :func:`match_gains` equalises the lenses on their overlap and
:func:`seam_disagreement` measures what is left. Blending, vignetting and file products are
:mod:`solidkit.capture.unwarp`'s; the overlap calibration
(:mod:`solidkit.calibration.overlap`) judges a lens profile by the same pieces.

Remap tables are cached per (profile, input size, output size, orientation): in memory (LRU of
:data:`CACHE_SIZE` entries) and optionally on disk (``.npz`` named by a SHA-256 of the key), as
OpenCV fixed-point maps (1/32 px, what ``cv2.remap`` uses internally for bilinear sampling).
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
from solidkit.camera.raw import is_raw_file, read_raw
from solidkit.envmap.coords import direction_from_coords
from solidkit.envmap.io import imread, read_exr, read_ldr, srgb_decode, srgb_encode
from solidkit.errors import InputError
from solidkit.fsutil import atomic_path

__all__ = [
    "CACHE_SIZE", "UnwarpMaps", "feather_weights", "build_maps", "get_maps", "clear_cache", "srgb8_luts",
    "encode_srgb8", "warp_lens", "match_gains", "seam_disagreement", "read_input", "read_linear",
]

CACHE_SIZE = 4
_ROWS = 256
_cache: "OrderedDict[str, UnwarpMaps]" = OrderedDict()


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


def srgb8_luts() -> tuple[np.ndarray, np.ndarray]:
    global _DECODE_LUT, _ENCODE_LUT
    if _DECODE_LUT is None:
        _DECODE_LUT = np.asarray(srgb_decode(np.arange(256, dtype=np.float64) / 255.0), np.float32)
        enc = np.asarray(srgb_encode(np.arange(65536, dtype=np.float64) / 65535.0))
        _ENCODE_LUT = np.round(np.clip(enc, 0, 1) * 255.0).astype(np.uint8)
    return _DECODE_LUT, _ENCODE_LUT


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear ``[0, 1]`` float -> sRGB uint8 (IEC 61966-2-1) through a 65536-entry table."""
    _, enc = srgb8_luts()
    x = np.clip(linear, 0.0, 1.0).astype(np.float32, copy=False)
    x *= 65535.0
    np.rint(x, out=x)
    return enc[x.astype(np.uint16)]


def warp_lens(image: np.ndarray, maps: UnwarpMaps, i: int) -> np.ndarray:
    """Lens ``i``'s image sampled at its map, ``(H, 2H, C)`` float32 *linear* (zeros outside).

    uint8 input is taken as sRGB-encoded: it is interpolated in that encoding (as cameras and
    ffmpeg do) and then decoded to linear exactly per code value.
    """
    w = cv2.remap(image, maps.map1[i], maps.map2[i], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if w.ndim == 2:
        w = w[..., None]
    if image.dtype == np.uint8:
        dec, _ = srgb8_luts()
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


def read_input(path: Path) -> tuple[np.ndarray, float | None]:
    """A capture file as the input of :func:`solidkit.capture.unwarp.unwarp`, and its linear clipping level (None for HDR/raw).

    EXR: linear float; raw/DNG: linear float (:func:`solidkit.camera.raw.read_raw`); 8-bit LDR:
    uint8 RGB as stored (sRGB-encoded; :func:`solidkit.capture.unwarp.unwarp` decodes per code value). 16-bit LDR is
    decoded to linear float.
    """
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
    return cv2.cvtColor(np.ascontiguousarray(raw[..., :3]), cv2.COLOR_BGR2RGB), float(srgb8_luts()[0][250])


def read_linear(path: Path) -> tuple[np.ndarray, float | None]:
    """:func:`read_input` with 8-bit images decoded to linear float32."""
    img, sat = read_input(path)
    if img.dtype == np.uint8:
        img = srgb8_luts()[0][img]
    return img, sat
