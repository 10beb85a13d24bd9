"""A small EXIF reader (Pillow) for the fields calibration needs: exposure and focal geometry.

Only JPEG/TIFF-style EXIF is read (Pillow's ``getexif``); missing tags are ``None``.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path

from solidkit.errors import InputError

__all__ = ["ExifInfo", "read_exif"]

# Pillow's FocalPlaneResolutionUnit codes -> millimetres per unit.
_UNIT_MM = {1: None, 2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


@dataclass
class ExifInfo:
    """EXIF fields used by calibration (units in the names; ``None`` when absent)."""

    make: str | None = None
    model: str | None = None
    width: int | None = None
    height: int | None = None
    exposure_time_s: float | None = None
    f_number: float | None = None
    iso: float | None = None
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    #: Focal-plane resolution in pixels per millimetre (x, y), from FocalPlaneX/YResolution.
    focal_plane_px_per_mm: tuple[float, float] | None = None
    #: Image width/height recorded in the EXIF (PixelXDimension/PixelYDimension), when present.
    exif_width: int | None = None
    exif_height: int | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def _num(v) -> float | None:
    if v is None:
        return None
    if isinstance(v, tuple | list):
        v = v[0] if v else None
        if v is None:
            return None
    try:
        x = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return x if x == x else None  # NaN -> None


def _text(v) -> str | None:
    if v is None:
        return None
    if isinstance(v, bytes):
        v = v.decode("latin-1", "replace")
    s = str(v).strip("\x00 ").strip()
    return s or None


def read_exif(path: str | os.PathLike) -> ExifInfo:
    """Read the calibration-relevant EXIF fields of an image file.

    Raises :class:`~solidkit.errors.InputError` when the file is missing or not an image.
    """
    from PIL import ExifTags, Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with Image.open(path) as im:
            width, height = im.size
            exif = im.getexif()
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"{path}: not a readable image ({exc})") from None
    sub = exif.get_ifd(ExifTags.IFD.Exif) if exif else {}
    T = ExifTags.Base
    info = ExifInfo(make=_text(exif.get(T.Make)), model=_text(exif.get(T.Model)), width=width, height=height)
    info.exposure_time_s = _num(sub.get(T.ExposureTime))
    info.f_number = _num(sub.get(T.FNumber))
    info.iso = _num(sub.get(T.ISOSpeedRatings))
    info.focal_length_mm = _num(sub.get(T.FocalLength))
    info.focal_length_35mm = _num(sub.get(T.FocalLengthIn35mmFilm))
    info.exif_width = int(_num(sub.get(T.ExifImageWidth)) or 0) or None
    info.exif_height = int(_num(sub.get(T.ExifImageHeight)) or 0) or None
    xres, yres = _num(sub.get(T.FocalPlaneXResolution)), _num(sub.get(T.FocalPlaneYResolution))
    unit = int(_num(sub.get(T.FocalPlaneResolutionUnit)) or 2)  # EXIF default: inches
    mm = _UNIT_MM.get(unit)
    if xres and mm:
        info.focal_plane_px_per_mm = (xres / mm, (yres or xres) / mm)
    if info.exposure_time_s is not None and info.exposure_time_s <= 0:
        info.exposure_time_s = None
    if info.focal_length_mm is not None and info.focal_length_mm <= 0:
        info.focal_length_mm = None
    if info.focal_length_35mm is not None and info.focal_length_35mm <= 0:
        info.focal_length_35mm = None
    return info
