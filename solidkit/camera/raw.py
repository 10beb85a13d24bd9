"""Linear reading of camera raw files (DNG and other LibRaw formats) through rawpy.

The output is scene-linear: black level subtracted per CFA channel, divided by
``white - black`` so that a photosite at the sensor's white level reads 1.0 (before white
balance), white-balanced (the camera's as-shot multipliers or fixed ones), demosaiced by
LibRaw (AHD), converted to linear Rec.709/sRGB primaries (conventions §5) or kept in camera
RGB; **no gamma, no auto-brightening, no data-dependent white-level adjustment** (LibRaw's
``adjust_maximum_thr`` would otherwise rescale each file by its own brightest pixel, which
breaks linearity across the frames of a bracket).

Saturation is decided on the mosaic, before demosaicing mixes neighbours: a pixel is
saturated when any photosite in its 3x3 neighbourhood reaches ``saturation_fraction`` of the
white level.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, cast

import numpy as np

from solidkit.errors import InputError, LibraryOutput, library_output

__all__ = ["RawImage", "read_raw", "is_raw_file", "RAW_SUFFIXES"]

RAW_SUFFIXES = {".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf", ".pef"}


@dataclass(frozen=True)
class RawImage:
    """A raw frame decoded to linear RGB.

    Attributes
    ----------
    linear : ndarray (H, W, 3) float32
        Linear RGB; 1.0 = the white level of a green photosite (white-balanced channels may
        exceed 1). Rec.709 primaries when ``color == "srgb"``, camera RGB when ``"camera"``.
    saturated : ndarray (H, W) bool
        Pixels with a clipped photosite in their 3x3 mosaic neighbourhood.
    black_level : list of float
        Per-CFA-channel black levels (raw DN) that were subtracted.
    white_level : float
        Raw DN of sensor saturation.
    wb : list of float
        RGB white-balance multipliers applied (green = 1).
    color : str
        ``"srgb"`` (linear Rec.709 primaries) or ``"camera"``.
    """

    linear: np.ndarray
    saturated: np.ndarray
    black_level: list[float]
    white_level: float
    wb: list[float]
    color: str
    pattern: str = ""
    warnings: list[str] = field(default_factory=list)


def is_raw_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` has a raw-file suffix (``.dng``, ``.cr2``, ...)."""
    return Path(path).suffix.lower() in RAW_SUFFIXES


def _normalised_wb(mult: Sequence[float] | np.ndarray) -> np.ndarray:
    """RGB(G) multipliers -> RGB with green = 1 (LibRaw reports RGBG; G2 = 0 means 'same as G')."""
    m = np.asarray(list(mult)[:3], dtype=np.float64)
    if m.shape != (3,) or not np.all(np.isfinite(m)) or np.any(m <= 0):
        raise ValueError(f"bad white-balance multipliers {list(mult)}")
    return cast(np.ndarray, m / m[1])


def read_raw(
    path: str | os.PathLike[str],
    *,
    wb: Literal["camera", "daylight", "none"] | tuple[float, float, float] = "camera",
    color: Literal["srgb", "camera"] = "srgb",
    saturation_fraction: float = 0.98,
) -> RawImage:
    """Decode a raw file to linear RGB (see the module docstring).

    Parameters
    ----------
    path : path-like
        DNG (or any LibRaw-supported raw) file.
    wb : ``"camera"`` | ``"daylight"`` | ``"none"`` | (r, g, b)
        White balance: the camera's as-shot multipliers, LibRaw's daylight multipliers,
        none (unit gains), or fixed RGB multipliers (normalised so that green = 1).
    color : ``"srgb"`` | ``"camera"``
        Output primaries: linear Rec.709 (through the file's colour matrix) or camera RGB.
    saturation_fraction : float
        Fraction of ``white - black`` at which a photosite counts as clipped.

    Raises
    ------
    InputError
        Unreadable / not a raw file, or unusable white balance.
    """
    import rawpy  # lazy: LibRaw is needed by raw files only (and costs 0.1-0.3 s to import)

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    warnings: list[str] = []
    said = LibraryOutput()
    try:
        with library_output() as said:
            raw = rawpy.imread(str(path))
    except Exception as exc:  # rawpy raises LibRawFileUnsupportedError, LibRawIOError, ...
        raise InputError(f"{path}: not a readable raw file ({_reason(exc, said, path)})") from None
    with raw, library_output() as said:
        try:
            mosaic = raw.raw_image_visible.astype(np.float32)
            colors = raw.raw_colors_visible
            black = np.asarray(raw.black_level_per_channel, dtype=np.float32)
            white = float(raw.white_level)
            if white <= float(black.max()):
                raise InputError(f"{path}: white level {white} is not above the black level {black.max()}")
            if isinstance(wb, str):
                if wb == "camera":
                    mult = raw.camera_whitebalance
                    try:
                        wb_rgb = _normalised_wb(mult)
                    except ValueError:
                        warnings.append("camera_wb_missing: no usable as-shot white balance; using daylight")
                        wb_rgb = _normalised_wb(raw.daylight_whitebalance)
                elif wb == "daylight":
                    wb_rgb = _normalised_wb(raw.daylight_whitebalance)
                elif wb == "none":
                    wb_rgb = np.ones(3)
                else:
                    raise InputError(f"unknown white balance '{wb}' (camera, daylight, none or r,g,b)")
            else:
                try:
                    wb_rgb = _normalised_wb(wb)
                except ValueError as exc:
                    raise InputError(str(exc)) from None
            output_color = rawpy.ColorSpace.sRGB if color == "srgb" else rawpy.ColorSpace.raw
            if color not in ("srgb", "camera"):
                raise InputError(f"unknown colour space '{color}' (srgb or camera)")
            # LibRaw scales by 65535 / (white - black) and by the WB multipliers normalised to
            # min = 1; we pass multipliers with green = 1 and undo any renormalisation below.
            scale_mul = float(wb_rgb.min())
            rgb16 = raw.postprocess(
                gamma=(1, 1),
                no_auto_bright=True,
                output_bps=16,
                user_wb=[*wb_rgb.tolist(), wb_rgb[1]],
                output_color=output_color,
                user_flip=0,
                adjust_maximum_thr=0.0,
                highlight_mode=rawpy.HighlightMode.Clip,
            )
            pattern = raw.color_desc.decode(errors="replace")
            flip = int(raw.sizes.flip)
        except InputError:
            raise
        except Exception as exc:
            raise InputError(f"{path}: raw decoding failed ({_reason(exc, said, path)})") from None
    linear = rgb16.astype(np.float32) / 65535.0
    if scale_mul < 1.0:  # LibRaw renormalised the multipliers so that their minimum is 1
        linear *= scale_mul
    # saturation on the mosaic (before demosaicing), grown to the 3x3 demosaic footprint
    black_site = black[np.clip(colors, 0, len(black) - 1)]
    level = (mosaic - black_site) / (white - black_site)
    from scipy import ndimage  # imported on use: the CLI's JPEG paths never load SciPy

    sat = ndimage.maximum_filter(level, size=3) >= saturation_fraction
    if sat.shape != linear.shape[:2]:
        # LibRaw's output can differ from the visible area by a pixel or two (odd crops)
        h, w = linear.shape[:2]
        pad = np.zeros((h, w), dtype=bool)
        hh, ww = min(h, sat.shape[0]), min(w, sat.shape[1])
        pad[:hh, :ww] = sat[:hh, :ww]
        sat = pad
    linear, sat = _apply_flip(linear, flip), _apply_flip(sat, flip)
    return RawImage(
        linear=np.ascontiguousarray(linear),
        saturated=np.ascontiguousarray(sat),
        black_level=[float(b) for b in black],
        white_level=white,
        wb=[float(x) for x in wb_rgb],
        color=color,
        pattern=pattern,
        warnings=warnings,
    )


def _reason(exc: Exception, said: LibraryOutput, path: Path) -> str:
    """LibRaw's exception and what it printed (e.g. ``Unexpected end of file``), in one line."""
    printed = said.summary().replace(f"{path}: ", "")
    return f"{type(exc).__name__}: {exc}" + (f"; LibRaw: {printed}" if printed else "")


def _apply_flip(img: np.ndarray, flip: int) -> np.ndarray:
    """LibRaw ``sizes.flip`` (0 none, 3 180°, 5 90° CCW, 6 90° CW) applied to an image."""
    if flip == 3:
        return img[::-1, ::-1]
    if flip == 5:
        return np.rot90(img, 1)
    if flip == 6:
        return np.rot90(img, -1)
    return img
