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

The remap tables, their cache, per-lens sampling, gain matching and the seam metric are the camera
model's (:mod:`solidkit.camera.dualfisheye`, re-exported here); this module blends, applies
vignetting profiles and writes files.

8-bit sRGB in and out (JPEG -> PNG/JPEG) takes :func:`unwarp_srgb8`: the same geometry, gains and
feathering, but only the feather band is decoded to linear light and blended; elsewhere the one
lens' sample gets its gain through an exact 8-bit table ``enc(g dec(v))``. It matches the float
path within one code value (``tests/capture/test_unwarp.py``) at a fraction of the memory traffic.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np

from solidkit import __version__
from solidkit.calibration.circles import fit_image_circle
from solidkit.calibration.fitcheck import check_profile_fit, check_upright
from solidkit.camera.dualfisheye import (  # noqa: F401  (re-exported: the remap tables are the camera model's)
    CACHE_SIZE,
    UnwarpMaps,
    build_maps,
    clear_cache,
    encode_srgb8,
    feather_weights,
    get_cut_maps,
    get_maps,
    match_gains,
    read_input,
    read_linear,
    seam_disagreement,
    srgb8_luts,
    warp_lens,
)
from solidkit.camera.lens import LensProfile, load_profile, profile_for_metadata, unproject
from solidkit.camera.metadata import level_rotation, read_metadata
from solidkit.camera.raw import is_raw_file
from solidkit.envmap.coords import angles_from_coords, rotation_from_ypr
from solidkit.envmap.io import LDR_SUFFIXES, check_image_size, image_size, imread, read_exr, write_exr
from solidkit.envmap.perspective import scale_pixel_coordinates
from solidkit.envmap.resample import resize, rotate, sample_panorama
from solidkit.envmap.sun import LUMINANCE_WEIGHTS
from solidkit.envmap.tilt import TILT_FLAG_DEG, TiltEstimate, residual_tilt
from solidkit.errors import InputError, SolidkitError
from solidkit.fsutil import atomic_path, sha256_file

__all__ = [
    "CAPTURE_SUFFIXES",
    "unwarp_files",
    "CACHE_SIZE",
    "UnwarpMaps",
    "build_maps",
    "get_maps",
    "feather_weights",
    "match_gains",
    "unwarp",
    "unwarp_file",
    "seam_disagreement",
    "clear_cache",
    "default_cache_dir",
    "check_image_circles",
    "render_fisheye",
    "cut_columns",
    "seam_step",
    "unwarp_srgb8",
    "encode_srgb8",
    "vignetting_gains",
    "load_vignetting",
    "default_out_height",
    "LEVEL_MODES",
    "level_by_content",
]


def default_out_height(in_width: int) -> int:
    """Default equirect height for a dual-fisheye input ``in_width`` px wide: the panorama is as wide
    as the input (``2 H = in_width``: 5792x2896 -> 5792x2896), keeping the lenses' centre resolution.

    Used by ``solidkit capture unwarp`` (no ``--size``) and by the campaign's products.
    """
    return max(2, int(in_width) // 2)


def load_vignetting(path: str | os.PathLike) -> Any:
    """A :class:`~solidkit.calibration.vignetting.VignettingProfile` from its JSON file (``solidkit calibrate
    vignetting``)."""
    from solidkit.calibration.vignetting import VignettingProfile  # SciPy: loaded only with a vignetting profile

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
    from solidkit.calibration.vignetting import VignettingError, falloff  # lazy: pulls in scipy.optimize

    L = maps.weight.shape[0]
    vl = vignetting.scaled(*in_size)
    if len(vl) != L:
        raise VignettingError(f"vignetting profile has {len(vl)} lenses, lens profile {profile.model!r} has {L}")
    names = [lens.name for lens in profile.lenses]
    by_name = {v.name: v for v in vl}
    if sorted(by_name) == sorted(names):
        vl = [by_name[n] for n in names]
    key = ("vignetting", vignetting.model_dump_json(), tuple(in_size))

    def gains() -> np.ndarray:
        out = np.ones(maps.weight.shape, np.float32)
        for i, v in enumerate(vl):
            used = maps.weight[i] > 0
            xy = cv2.convertMaps(maps.map1[i], maps.map2[i], cv2.CV_32FC2)[0]  # (H, 2H, 2) sample positions
            rho = np.hypot(xy[..., 0][used] - v.center[0], xy[..., 1][used] - v.center[1]) / v.r_norm_px
            V = falloff(v.coeffs, rho)
            if V.size and (not np.all(np.isfinite(V)) or V.min() <= 0.05):
                raise VignettingError(
                    f"lens {v.name}: the falloff drops below 5 % inside the image circle: the profile is unusable"
                )
            out[i][used] = (1.0 / V).astype(np.float32)
        return out

    return maps.derived("vignetting", key, gains)


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
        saturation = float(srgb8_luts()[0][250])
    h, w = image.shape[:2]
    maps, source = get_maps(profile, (w, h), out_height, R_level, feather_deg, cache_dir)
    L = maps.weight.shape[0]
    warped = [warp_lens(image, maps, i) for i in range(L)]
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
        warped[i] = None  # type: ignore[call-overload]  # each lens' image freed once blended
    return cast(np.ndarray, out)  # a profile has at least one lens


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
    The tables are :class:`~solidkit.camera.dualfisheye.CutMaps` (:func:`~solidkit.camera.dualfisheye.get_cut_maps`):
    one ``cv2.remap`` of the whole frame samples each pixel's dominant lens, only the band is sampled
    from both. The channels may be in any order (RGB, or OpenCV's BGR as read): ``stats["gains"]``
    follow it. With a ``vignetting`` profile (a per-pixel correction no 8-bit table can carry) or
    other than two lenses it is :func:`unwarp` followed by :func:`encode_srgb8`.
    """
    if image.dtype != np.uint8 or image.ndim != 3:
        raise InputError("unwarp_srgb8 needs an (H, W, C) uint8 image")
    h, w = image.shape[:2]
    if len(profile.lenses) != 2 or vignetting is not None:
        linear = unwarp(
            image,
            profile,
            out_height,
            R_level,
            feather_deg=feather_deg,
            gain_match=gain_match,
            cache_dir=cache_dir,
            stats=stats,
            vignetting=vignetting,
        )
        return encode_srgb8(linear)
    maps, source = get_cut_maps(profile, (w, h), out_height, R_level, feather_deg, cache_dir)
    dec, _ = srgb8_luts()
    C = image.shape[2]
    n = maps.band.size
    band = [maps.sample_band(image, i) for i in range(2)]  # (rows, 4096, C) codes of each lens in the feather band
    # gains and seam statistics from an even subsample of the band (at most ~2^18 pixels: medians to 1e-3)
    k = max(1, n >> 18)
    lin = [dec[b.reshape(-1, C)[:n:k]] for b in band]
    gains = np.ones((2, C))
    if gain_match and n:
        sat = float(dec[250])
        ok = np.all((lin[0] > 1e-3) & (lin[1] > 1e-3) & (lin[0] < sat) & (lin[1] < sat), axis=-1)
        if ok.sum() >= 100:
            ratio = np.exp(np.median(np.log(lin[0][ok]) - np.log(lin[1][ok]), axis=0))
            gains = np.stack([ratio**-0.5, ratio**0.5])
    if stats is not None:
        d0 = (lin[0] - lin[1]).mean(-1)
        d1 = (lin[0] * gains[0] - lin[1] * gains[1]).mean(-1)
        stats.update(
            gains=gains.tolist(),
            cache=source,
            coverage=maps.coverage,
            overlap_px=int(maps.band.size),
            seam_mad_before_gain=float(np.median(np.abs(d0))) if d0.size else math.nan,
            seam_mad=float(np.median(np.abs(d1))) if d1.size else math.nan,
            seam_rmse=float(np.sqrt(np.mean(d1**2))) if d1.size else math.nan,
        )
    out = cv2.remap(image, maps.map1, maps.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if out.ndim == 2:
        out = out[..., None]
    if not np.allclose(gains, 1.0):  # each lens' gain, exactly in linear light, through an 8-bit table enc(g dec(v))
        tables: list[np.ndarray] = [
            encode_srgb8(dec[:, None] * gains[i].astype(np.float32)[None, :]).reshape(256, 1, C) for i in range(2)
        ]
        if C == 1:
            tables = [t.reshape(256, 1) for t in tables]
        lens0 = cv2.LUT(out, tables[0])
        cv2.LUT(out, tables[1], dst=out)
        cv2.copyTo(lens0.reshape(out.shape), maps.lead, out)
        del lens0
    if n:  # blend in linear light, w0 g0 dec(v0) + (1 - w0) g1 dec(v1): g_i dec through a float table per lens
        lin_tables = [(dec[:, None] * gains[i][None, :]).astype(np.float32).reshape(256, 1, C) for i in range(2)]
        if C == 1:
            lin_tables = [t.reshape(256, 1) for t in lin_tables]
        w0 = maps.band_w0
        blended = cv2.blendLinear(cv2.LUT(band[0], lin_tables[0]), cv2.LUT(band[1], lin_tables[1]), w0, 1 - w0)
        out.reshape(-1, C)[maps.band] = encode_srgb8(blended).reshape(-1, C)[:n]
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
    return cast(np.ndarray, out)  # a profile has at least one lens


def _write_srgb8(path: Path, enc: np.ndarray, bgr: bool = False) -> None:
    """8-bit sRGB RGB (``bgr``: OpenCV's order) image -> PNG (fast compression) / JPEG (q95) / other LDR, atomically."""
    # PNG: zlib level 1, run-length strategy on the "Sub" filter: at Theta V size half the time of
    # zlib's default strategy with adaptive filters, and a smaller file (6.6 vs 7.1 MB)
    png = [
        cv2.IMWRITE_PNG_COMPRESSION,
        1,
        cv2.IMWRITE_PNG_STRATEGY,
        cv2.IMWRITE_PNG_STRATEGY_RLE,
        cv2.IMWRITE_PNG_FILTER,
        cv2.IMWRITE_PNG_FILTER_SUB,
    ]
    params = {".png": png, ".jpg": [cv2.IMWRITE_JPEG_QUALITY, 95], ".jpeg": [cv2.IMWRITE_JPEG_QUALITY, 95]}.get(
        path.suffix.lower(), []
    )
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), enc if bgr else cv2.cvtColor(enc, cv2.COLOR_RGB2BGR), params):
            raise InputError(f"{path}: OpenCV cannot write this image format")


def _write(path: Path, linear: np.ndarray, meta: dict) -> None:
    """EXR (linear float, with ``meta``) or 8-bit sRGB LDR (PNG fast compression, JPEG q95), atomically."""
    if path.suffix.lower() == ".exr":
        write_exr(path, linear, meta)
        return
    _write_srgb8(path, encode_srgb8(linear))


def check_image_circles(
    image: np.ndarray,
    profile: LensProfile,
    *,
    max_offset: float = 0.05,
    radius_range: tuple[float, float] = (0.85, 1.2),
    min_inliers: float = 0.4,
    max_width: int = 1536,
    min_contrast: float = 12.0,
    bgr: bool = False,
) -> tuple[list[dict[str, float]], list[str]]:
    """Does the frame show its image circles where the lens profile puts them?

    Each lens's circle is fitted from the profile's position
    (:func:`solidkit.calibration.overlap.fit_image_circle` on linear luminance, robust to a start
    tens of pixels off). A circle centre more than ``max_offset`` x the profile's radius (at least
    4 px) from the profile's centre, a radius outside ``radius_range`` x the profile's, or no
    circle edge around the expected place (fewer than ``min_inliers`` of the rays) means another
    camera, another layout (stacked, rotated, cropped) or a unit far from the model's profile: a
    ``profile_mismatch`` warning, with what was found. Returns ``(per-lens fits, warnings)``.

    A lens is judged only when the frame shows something lit near its circle's edge: the median
    luminance on the profile's disc between 0.5 and 0.9 of its radius at least ``min_contrast`` x
    the frame's 10th percentile (the black surround, its noise included). A bracket's 1/25000 s sun
    frame (the sun on noise: 3-5 x on the virtual Theta V brackets, the other frames 30-650 x) has
    no edge to find and gets no warning; the bracket's HDR product is checked instead.

    The tolerances are loose on purpose: on noisy JPEGs of the right camera (virtual Theta V
    brackets, 1920 px) bright content at the circle's edge pulls the fit up to 16 px / +5 % off;
    the real Theta S frame fits within 4 px / +3 %; a Gear 360 frame under a Theta V profile is 130 px off.

    Frames wider than ``max_width`` are fitted reduced by an integer factor (area averaging; at
    Theta V size 1/4: 0.02 s instead of 4 s, circles within about a pixel); results are in
    full-size pixels. ``bgr``: the channels are OpenCV's order.
    """
    h, w = image.shape[:2]
    k = max(1, -(-w // max_width))
    if k > 1:
        image = cv2.resize(image, (w // k, h // k), interpolation=cv2.INTER_AREA)
    prof = profile.scaled(*image.shape[1::-1]) if tuple(profile.reference_size) != image.shape[1::-1] else profile
    # linear light: sRGB-encoded sensor noise outside the circles (a few codes) would pass for image
    img = srgb8_luts()[0][image] if image.dtype == np.uint8 else np.asarray(image, np.float32)
    weights = np.asarray(LUMINANCE_WEIGHTS, np.float32)
    lum = img[..., :3] @ (weights[::-1] if bgr else weights) if img.ndim == 3 else img
    fits, warnings = [], []
    full = profile.scaled(w, h) if tuple(profile.reference_size) != (w, h) else profile
    # the dark surround (a third of a dual-fisheye frame): its level, noise included
    floor = max(float(np.percentile(lum, 10)), 1e-9)
    yy, xx = np.mgrid[0 : lum.shape[0], 0 : lum.shape[1]]

    for i, lens in enumerate(full.lenses):
        r0 = lens.max_radius()
        small = prof.lenses[i]
        d = np.hypot(xx - small.center[0], yy - small.center[1]) / small.max_radius()
        band = lum[(d >= 0.5) & (d <= 0.9)]
        # a frame with nothing lit near the circle's edge (a 1/25000 s sun frame) shows no edge to check
        judged = band.size > 0 and float(np.median(band)) >= min_contrast * floor
        # search +-12 %: wider, a ray from one lens reaches into the other's circle (Theta V side by side)
        cx, cy, r, frac = fit_image_circle(lum, small.center, small.max_radius(), search=0.12, rel_threshold=0.25)
        cx, cy, r = scale_pixel_coordinates(cx, k), scale_pixel_coordinates(cy, k), r * k  # full-size pixels
        fits.append(
            {
                "center": [round(cx, 2), round(cy, 2)],
                "radius": round(r, 2),
                "inliers": round(frac, 3),
                "profile_center": [round(lens.center[0], 2), round(lens.center[1], 2)],
                "profile_radius": round(r0, 2),
            }
        )
        if not judged:
            continue
        if not (math.isfinite(r) and frac >= min_inliers):
            warnings.append(
                f"profile_mismatch: lens {i}: no image circle edge near the profile's circle "
                f"(centre ({lens.center[0]:.0f}, {lens.center[1]:.0f}), radius {r0:.0f} px): another camera "
                "or layout? (check --profile; 'solidkit calibrate overlap' fits a unit's profile)"
            )
            continue
        off = math.hypot(cx - lens.center[0], cy - lens.center[1])
        if off > max(4.0, max_offset * r0) or not radius_range[0] <= r / r0 <= radius_range[1]:
            warnings.append(
                f"profile_mismatch: lens {i}: image circle at ({cx:.0f}, {cy:.0f}) radius {r:.0f} px, the "
                f"profile expects ({lens.center[0]:.0f}, {lens.center[1]:.0f}) radius {r0:.0f} px "
                f"({off:.0f} px apart): another camera or layout? (check --profile; 'solidkit calibrate "
                "overlap' fits a unit's profile)"
            )
    return fits, warnings


def default_cache_dir() -> Path:
    """Per-user on-disk cache of remap tables: ``$SOLIDKIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/solidkit``,
    else ``~/.cache/solidkit``; a sub-folder per solidkit version (a new version never reads tables an
    older one built). Files are keyed by profile, sizes, levelling and feather
    (:func:`solidkit.camera.dualfisheye.get_maps`) and written atomically (safe for concurrent runs).
    """
    root = (
        os.environ.get("SOLIDKIT_CACHE_DIR")
        or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "solidkit"
    )
    return Path(root) / f"v{__version__}" / "unwarp"


def report_tilt(summary: dict, pano: Any) -> None:
    """Add the output's residual tilt (:func:`solidkit.envmap.tilt.residual_tilt`) to ``summary``,
    and a warning when it is reliably above :data:`~solidkit.envmap.tilt.TILT_FLAG_DEG`.

    ``pano``: the panorama array, the written file (read at half size: edges survive), or its
    :class:`~solidkit.envmap.tilt.TiltEstimate` already made.
    """
    if isinstance(pano, (str, os.PathLike)):
        path = Path(pano)
        pano = read_exr(path)[0] if path.suffix.lower() == ".exr" else cv2.imread(str(path), cv2.IMREAD_REDUCED_COLOR_2)
        if pano is None:
            return
    est = pano if isinstance(pano, TiltEstimate) else residual_tilt(np.asarray(pano))
    summary["residual_tilt"] = est.to_json()
    if est.reliable and est.tilt_deg > TILT_FLAG_DEG:
        summary["warnings"].append(
            f"residual_tilt: the panorama is {est.tilt_deg:.2f}° ± {est.uncertainty_deg:.2f}° off level by its "
            f"vertical edges (correction pitch {est.pitch_deg:.2f}°, roll {est.roll_deg:.2f}°)"
        )


def unwarp_file(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    profile: str | os.PathLike | None = None,
    out_height: int | None = None,
    feather_deg: float = 10.0,
    level: bool | str = "auto",
    gain_match: bool = True,
    cache_dir: str | os.PathLike | None = None,
    vignetting: str | os.PathLike | None = None,
) -> dict:
    """``solidkit capture unwarp``: a capture file -> an equirect panorama in the panorama frame.

    Dual-fisheye input goes through the lens profile (``profile``: a shipped name or a unit JSON;
    default: the shipped profile of the EXIF camera model), after dividing each lens by its
    falloff when a ``vignetting`` profile JSON is given; the output is ``(out_height, 2 out_height)``
    or, by default, as wide as the input (:func:`default_out_height`). Stitched equirect input is levelled
    from its metadata, or copied byte for byte when no rotation (and no resize) is needed
    (a vignetting profile does not apply to it: a warning says so).

    ``level`` (:data:`LEVEL_MODES`; ``True`` is ``"auto"``, ``False`` ``"off"``): ``"metadata"`` applies
    the recorded gravity (:func:`~solidkit.camera.metadata.level_rotation`); ``"content"`` then levels
    the output by its own vertical edges (:func:`level_by_content`: the measured correction is kept only
    when it lowers the residual tilt); ``"auto"`` is ``"metadata"`` when the metadata gives a pose that
    is applied (a dual-fisheye frame's gravity), else ``"content"`` (stitched stills, whose recorded pose
    is not the remaining tilt, frames without gravity); ``"off"`` neither. ``summary["levelling"]`` says
    what was done, with the residual tilt before and after.
    Returns a summary dict (what was done, gains, seam disagreement, timings).
    """
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise InputError(f"{dst}: refusing to overwrite the input (originals are never modified)")
    if dst.suffix.lower() != ".exr" and dst.suffix.lower() not in LDR_SUFFIXES:
        raise InputError(f"{dst}: unknown output type '{dst.suffix}' (use .exr, or .png/.jpg for sRGB)")
    if not (math.isfinite(feather_deg) and feather_deg >= 0):
        raise InputError(f"--feather must be a finite angle >= 0 degrees, got {feather_deg}")
    t0 = time.perf_counter()
    has_exif = src.suffix.lower() in (".jpg", ".jpeg", ".dng", ".tif", ".tiff") or is_raw_file(src)
    meta = read_metadata(src) if has_exif else None  # PNG/EXR inputs carry no camera metadata
    summary: dict[str, Any] = {"input": str(src), "output": str(dst), "warnings": list(meta.warnings) if meta else []}
    if out_height is not None and int(out_height) < 2:
        raise InputError(f"output height must be at least 2 pixels, got {out_height}")
    out_h = None if out_height is None else int(out_height)
    vprof = load_vignetting(vignetting) if vignetting is not None else None
    mode = _level_mode(level)
    R = level_rotation(meta) if (meta is not None and mode != "off") else np.eye(3)
    upright = meta is not None and meta.image_type == "dual_fisheye_upright"
    pose_applied = not upright and not np.allclose(R, np.eye(3), atol=1e-12)
    by_content = mode == "content" or (mode == "auto" and not pose_applied)
    summary["level_pitch_roll_deg"] = [meta.pitch_deg, meta.roll_deg] if meta is not None and pose_applied else None
    stitched = meta is not None and meta.image_type == "equirect" and profile is None
    if stitched:
        assert meta is not None
        if vprof is not None:
            summary["warnings"].append(
                "vignetting_ignored: stitched input; the camera applied its own lens corrections"
            )
        w, h = meta.width, meta.height
        if w != 2 * h:
            raise InputError(f"{src}: marked equirectangular but {w}x{h} is not 2:1")

        def write_still(R: np.ndarray) -> tuple[dict[str, Any], TiltEstimate | None]:
            done = _write_stitched(src, dst, R, h, out_h, "metadata" if np.array_equal(R, R_meta) else "content")
            return done, _read_tilt(dst, out_h or h)

        R_meta = R
        done, est = write_still(R)
        summary.update(done)
        if by_content:
            done, est, R = level_by_content(est, R, write_still, summary)
            summary.update(done)
        if est is not None:
            report_tilt(summary, est)
        summary["seconds"] = time.perf_counter() - t0
        return summary
    if profile is not None:
        prof = load_profile(profile)
    with ThreadPoolExecutor(1) as pool:  # the 8-bit path's tables are built (or read) while the file is decoded
        given = prof if profile is not None else None
        tables = _prefetch_cut_maps(pool, src, dst, given, meta, out_h, R, upright, feather_deg, cache_dir, vprof)
        img, saturation, bgr = _read_for_unwarp(
            src, len(prof.lenses) == 2 if profile is not None else True, dst.suffix.lower() != ".exr" and vprof is None
        )
        try:
            prefetched = None if tables is None else tables.result()
        except (SolidkitError, ValueError, OSError, cv2.error):
            prefetched = None  # the tables are built again below, where what went wrong is said
    h, w = img.shape[:2]
    if profile is None:
        prof = profile_for_metadata(meta.model if meta else None, w, h)
        if bgr and len(prof.lenses) != 2:  # the 8-bit path needs two lenses: RGB for the general one
            img, bgr = cv2.cvtColor(img, cv2.COLOR_BGR2RGB), False
    if upright:
        summary["warnings"].append(
            "upright_dual_fisheye: the camera already rotated the circles upright; no gravity applied"
        )
        R = np.eye(3)
    out_h = out_h or default_out_height(w)
    stats: dict[str, Any] = {}
    t1 = time.perf_counter()
    fast = img.dtype == np.uint8 and dst.suffix.lower() != ".exr" and len(prof.lenses) == 2

    def run(R: np.ndarray, stats: dict[str, Any]) -> np.ndarray:
        if fast:  # 8-bit in and out: blend in linear light only where two lenses overlap
            pano = unwarp_srgb8(
                img,
                prof,
                out_h,
                R,
                feather_deg=feather_deg,
                gain_match=gain_match,
                cache_dir=cache_dir,
                stats=stats,
                vignetting=vprof,
            )
            if bgr:
                stats["gains"] = [g[::-1] for g in stats["gains"]]
            return pano
        return unwarp(
            img,
            prof,
            out_h,
            R,
            feather_deg=feather_deg,
            gain_match=gain_match,
            saturation=saturation,
            cache_dir=cache_dir,
            stats=stats,
            vignetting=vprof,
        )

    turned: list[list[str]] = []

    def tilt_and_upright(pano: np.ndarray) -> TiltEstimate:
        turned[:] = [check_upright(pano, fit)]  # a sideways panorama: the layout contradicts the profile
        return cast(TiltEstimate, _tilt_of(pano))

    def write(pano: np.ndarray, R: np.ndarray, stats: dict[str, Any]) -> TiltEstimate:
        with ThreadPoolExecutor(1) as pool:  # the tilt (LSD) and upright checks run on the other core while the
            tilt = pool.submit(tilt_and_upright, pano)  # file is encoded
            if fast:
                _write_srgb8(dst, pano, bgr=bgr)
            else:
                meta_out = {
                    "source": str(src),
                    "source_sha256": sha256_file(src),
                    "profile": prof.model,
                    "profile_key": prof.key(),
                    "rotation": R.tolist(),
                    "gains": stats["gains"],
                    "vignetting": None
                    if vignetting is None
                    else {"path": str(vignetting), "sha256": sha256_file(vignetting)},
                }
                _write(dst, pano, meta_out)
            return cast(TiltEstimate, tilt.result())

    with ThreadPoolExecutor(2) as pool:  # the frame's checks run beside the tables' application
        circle_check = pool.submit(check_image_circles, img, prof, bgr=bgr)
        fit_check = pool.submit(check_profile_fit, img, prof, saturation, bgr=bgr)
        pano = run(R, stats)
        if prefetched is not None and fast and prefetched[1] == (prof.key(), (w, h), out_h):
            stats["cache"] = prefetched[0]  # where the tables came from, not the in-memory copy the prefetch left
        (circles, circle_warnings), (fit, fit_warnings) = circle_check.result(), fit_check.result()
    summary["image_circles"] = circles
    summary["warnings"] += circle_warnings
    summary["seam_error"], summary["profile_fit"] = fit.get("seam_error"), fit
    summary["warnings"] += fit_warnings
    t2 = time.perf_counter()
    est = write(pano, R, stats)
    if by_content:
        first = (R, pano, stats)

        def redo(R_new: np.ndarray) -> tuple[dict[str, Any], TiltEstimate]:
            nonlocal pano, stats
            if R_new is first[0]:
                _, pano, stats = first
            else:
                stats = {}
                pano = run(R_new, stats)
            return {}, write(pano, R_new, stats)

        _, est, R = level_by_content(est, R, redo, summary)
        del first
    summary.update(
        mode="dual-fisheye unwarped",
        profile=prof.model,
        size=[2 * out_h, out_h],
        resampled=True,
        unwarp_seconds=t2 - t1,
        **stats,
    )
    summary["warnings"] += turned[0]  # of the panorama kept
    report_tilt(summary, est)
    summary["seconds"] = time.perf_counter() - t0
    return summary


#: ``level`` of :func:`unwarp_file` (``solidkit capture unwarp --level``).
LEVEL_MODES = ("auto", "metadata", "content", "off")
#: Content levelling corrects a reliable tilt above this (degrees) only: below it a resampling costs more than it
#: gains (the estimator's own error on rendered streets is ~0.05-0.2°: benchmarks/results/tilt.md).
LEVEL_MIN_DEG = 0.2


def _level_mode(level: bool | str) -> str:
    if level is True:
        return "auto"
    if level is False:
        return "off"
    if level not in LEVEL_MODES:
        raise InputError(f"--level must be one of {', '.join(LEVEL_MODES)}, got {level!r}")
    return str(level)


def level_by_content(
    before: TiltEstimate | None,
    R: np.ndarray,
    redo: Any,
    summary: dict[str, Any],
) -> tuple[dict[str, Any], TiltEstimate | None, np.ndarray]:
    """Level an output by its own vertical edges, when that lowers its residual tilt.

    ``before``: the residual tilt (:func:`~solidkit.envmap.tilt.residual_tilt`) of the output made
    with the rotation ``R`` (camera -> output frame); ``redo(R_new) -> (summary fields, tilt)``
    makes (and writes) the output again with ``R_new``. A reliable tilt above :data:`LEVEL_MIN_DEG`
    (and 3 times its uncertainty) gives the correction ``C = R(0, pitch, roll)`` of the estimate; the
    output is redone with ``C R`` and kept when its measured tilt is lower, else redone with ``R``
    (never worse than leaving the image alone). Returns ``(summary fields, tilt, rotation)`` of the
    output kept and records ``summary["levelling"]``: ``source`` (``"content"`` or ``"none"``),
    ``applied``, ``tilt_before_deg`` / ``tilt_after_deg`` and the correction's pitch and roll (degrees).
    """
    info: dict[str, Any] = {
        "source": "none",
        "applied": False,
        "tilt_before_deg": None if before is None else round(before.tilt_deg, 4),
        "tilt_after_deg": None if before is None else round(before.tilt_deg, 4),
    }
    summary["levelling"] = info
    if before is None or not before.reliable:
        info["note"] = "too few vertical edges to measure the tilt: left as it is"
        return {}, before, R
    if before.tilt_deg <= max(LEVEL_MIN_DEG, 3 * before.uncertainty_deg):
        info["note"] = f"level within {max(LEVEL_MIN_DEG, 3 * before.uncertainty_deg):.2f}°: left as it is"
        return {}, before, R
    C = np.asarray(rotation_from_ypr(0.0, math.radians(before.pitch_deg), math.radians(before.roll_deg)))
    R_new = C @ R
    done, after = redo(R_new)
    info["correction_pitch_roll_deg"] = [round(before.pitch_deg, 4), round(before.roll_deg, 4)]
    if after is not None and after.reliable and after.tilt_deg < before.tilt_deg:
        info.update(source="content", applied=True, tilt_after_deg=round(after.tilt_deg, 4))
        return done, after, R_new
    got = "unmeasured" if after is None or not after.reliable else f"{after.tilt_deg:.2f}°"
    info["note"] = f"the correction did not lower the measured tilt ({before.tilt_deg:.2f}° -> {got}): left as it is"
    done, again = redo(R)
    return done, again, R


def _read_tilt(path: Path, height: int) -> TiltEstimate | None:
    """:func:`~solidkit.envmap.tilt.residual_tilt` of a written panorama ``height`` px high (8-bit read at half
    size when that keeps 1024 rows, what the estimate measures at: edges survive)."""
    pano: Any
    if path.suffix.lower() == ".exr":
        pano = read_exr(path)[0]
    else:
        pano = cv2.imread(str(path), cv2.IMREAD_REDUCED_COLOR_2 if height >= 2048 else cv2.IMREAD_COLOR)
    return None if pano is None else residual_tilt(np.asarray(pano))


def _write_stitched(src: Path, dst: Path, R: np.ndarray, h: int, out_h: int | None, source: str) -> dict[str, Any]:
    """A stitched equirect ``src`` (``h`` px high) turned by ``R`` (camera -> level frame) into ``dst``: copied
    byte for byte when no rotation and no resize is needed."""
    identity = np.allclose(R, np.eye(3), atol=1e-12)
    if identity and (out_h is None or out_h == h) and src.suffix.lower() == dst.suffix.lower():
        with atomic_path(dst) as tmp:
            shutil.copyfile(src, tmp)
        return {"mode": "stitched: copied unchanged (no rotation needed)", "resampled": False}
    img, _ = read_linear(src)
    if out_h is not None and out_h < img.shape[0]:
        img = resize(img, out_h)  # energy-preserving downsampling first, then one rotation
    if not identity:
        img = rotate(img, R, "linear", height=out_h)  # out(d) = in(R^T d): camera -> level frame
    elif out_h is not None and out_h != img.shape[0]:
        img = resize(img, out_h)
    _write(dst, img, {"source": str(src), "source_sha256": sha256_file(src), "rotation": R.tolist()})
    return {
        "mode": f"stitched: levelled from {source}" if not identity else "stitched: re-encoded",
        "resampled": not identity or out_h is not None,
    }


def _prefetch_cut_maps(
    pool: ThreadPoolExecutor,
    src: Path,
    dst: Path,
    prof: LensProfile | None,
    meta: Any,
    out_h: int | None,
    R: np.ndarray,
    upright: bool,
    feather_deg: float,
    cache_dir: Any,
    vignetting: Any,
) -> Any:
    """Start :func:`~solidkit.camera.dualfisheye.get_cut_maps` for an 8-bit JPEG bound for the 8-bit path, at the size
    its header states (``None`` where that path is not sure to be taken): a future of ``(source, (profile key, size,
    output height))``; the tables stay in the in-memory cache, where :func:`unwarp_srgb8` finds them."""
    if src.suffix.lower() not in (".jpg", ".jpeg") or dst.suffix.lower() == ".exr" or vignetting is not None:
        return None
    size = image_size(src)
    if size is None or min(size) < 2:
        return None
    try:
        check_image_size(src, size)  # a header stating too many pixels is refused where the file is read
        prof = prof or profile_for_metadata(meta.model if meta else None, *size)
    except SolidkitError:
        return None  # said again, where the file is read
    if len(prof.lenses) != 2:
        return None
    h = out_h or default_out_height(size[0])
    R_tables = np.eye(3) if upright else R

    def fetch() -> tuple[str, tuple]:
        return get_cut_maps(prof, size, h, R_tables, feather_deg, cache_dir)[1], (prof.key(), size, h)

    return pool.submit(fetch)


def _read_for_unwarp(src: Path, two_lenses: bool, srgb8_out: bool) -> tuple[np.ndarray, float | None, bool]:
    """The capture as :func:`~solidkit.camera.dualfisheye.read_input` reads it, except that an 8-bit
    colour file bound for the 8-bit path stays in OpenCV's BGR order (no full-size channel swap);
    returns ``(image, clipping level, bgr)``."""
    if srgb8_out and two_lenses and src.suffix.lower() != ".exr" and not is_raw_file(src):
        raw = imread(src)
        if raw.dtype == np.uint8 and raw.ndim == 3 and raw.shape[2] == 3:
            return raw, float(srgb8_luts()[0][250]), True
    img, saturation = read_input(src)
    return img, saturation, False


#: The residual tilt is measured at this height (what :func:`~solidkit.envmap.tilt.residual_tilt` reduces to).
TILT_HEIGHT = 1024


def _tilt_of(pano: np.ndarray) -> Any:
    """:func:`~solidkit.envmap.tilt.residual_tilt` of an output, an 8-bit one reduced in colour to
    :data:`TILT_HEIGHT` rows first (area): a fifth of the time at Theta V size, 2688 rows (the estimate reduces
    its grey copy to that height anyway)."""
    if pano.dtype == np.uint8 and pano.shape[0] > TILT_HEIGHT:
        pano = cv2.resize(pano, (2 * TILT_HEIGHT, TILT_HEIGHT), interpolation=cv2.INTER_AREA)
    return residual_tilt(pano)


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
    _, el = angles_from_coords(0.0, np.arange(H) + 0.5, H)  # row centres' elevation, radians
    steps, base = [], []
    for r in np.nonzero(np.abs(el) < math.radians(max_elevation_deg))[0]:
        for c in cols_per_row[r]:
            steps.append(abs(g[r, c % W] - g[r, (c - 1) % W]))
            for o in (6, 9, 12, 15):
                base.append(abs(g[r, (c + o) % W] - g[r, (c + o - 1) % W]))
                base.append(abs(g[r, (c - o) % W] - g[r, (c - o - 1) % W]))
    if not steps:
        return {"step": math.nan, "baseline": math.nan}
    return {"step": float(np.mean(steps)), "baseline": float(np.mean(base))}


CAPTURE_SUFFIXES = (".jpg", ".jpeg", ".dng", ".exr", ".png", ".tif", ".tiff")
"""Files :func:`unwarp_files` takes from a folder (by suffix, any case)."""


def unwarp_files(
    sources: Sequence[str | os.PathLike], out_dir: str | os.PathLike, *, fmt: str = "exr", **options: Any
) -> list[dict[str, Any]]:
    """Several captures (files, or folders whose :data:`CAPTURE_SUFFIXES` files are taken, sorted) unwarped
    in one process, each into ``out_dir/<stem>.<fmt>`` (``fmt``: ``exr``, ``png`` or ``jpg``) by
    :func:`unwarp_file` with ``options``; the remap tables of one camera and size are built once.

    Returns one summary per capture, in order; a capture that cannot be unwarped gets
    ``{"input", "output", "error"}`` and the others go on. Two captures that would write the same output,
    or an output that is one of the inputs, are refused (:class:`InputError`) before any work.
    """
    if fmt not in ("exr", "png", "jpg"):
        raise InputError(f"--format must be exr, png or jpg, got {fmt!r}")
    files: list[Path] = []
    for src in map(Path, sources):
        if src.is_dir():
            found = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in CAPTURE_SUFFIXES)
            if not found:
                raise InputError(f"{src}: no capture files ({', '.join(CAPTURE_SUFFIXES)}) in this folder")
            files += found
        elif src.is_file():
            files.append(src)
        else:
            raise InputError(f"{src}: no such file or folder")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder (several captures write one file each into a folder)")
    targets = [out / f"{f.stem}.{fmt}" for f in files]
    seen: dict[Path, Path] = {}
    inputs = {f.resolve() for f in files}
    for f, t in zip(files, targets):
        if t.resolve() in inputs:
            raise InputError(f"{t}: refusing to overwrite an input (originals are never modified)")
        if t in seen:
            raise InputError(f"{seen[t]} and {f} would both write {t}: unwarp them into separate folders")
        seen[t] = f
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for f, t in zip(files, targets):
        try:
            results.append(unwarp_file(f, t, **options))
        except SolidkitError as exc:
            results.append({"input": str(f), "output": str(t), "error": str(exc)})
    return results
