"""Capture metadata of Ricoh Theta (and other) JPEG and DNG files: EXIF, GPS, GPano XMP, Ricoh maker note.

This is solidkit's one EXIF reader: capture (grouping, merging, levelling) and calibration
(exposure times of response brackets, a photo's focal geometry for its intrinsics K) both use
:func:`read_metadata`.

Standard EXIF and GPS fields are read with ``exifread`` (this module); the containers by the
bounds-checked TIFF-IFD reader of :mod:`solidkit.camera.tiff`; the GPano XMP packet by
:mod:`solidkit.camera.xmp`; the Ricoh maker note ("RICOH THETA IFD", which no Python library
decodes) by :mod:`solidkit.camera.makernote`; gravity and heading from them by
:mod:`solidkit.camera.orientation`.

References
----------
- Ricoh, *THETA Metadata Spec*, ``ricohapi/theta-api-specs`` ``theta-metadata/README.md``:
  the maker note starts with ``b"Ricoh\\0\\0\\0"``; tag ``0x4001`` (LONG) of the maker-note IFD
  points to the RICOH THETA IFD, whose tags are ``0x0001`` image type (1 equirectangular,
  2 dual-fisheye, 3 dual-fisheye upright, 4-6 single fisheye), ``0x0007`` zenith correction
  (0 not applied, 1 applied), ``0x0109`` zenith direction as a rotation vector
  ``(ax, ay, az)`` (SRATIONAL[3]; V, Z1, SC2, X, A1).
- ExifTool ``Ricoh.pm`` (ThetaSubdir) and ``regen100/thetaexif``: tag ``0x0003`` is a pair
  of SRATIONAL angles in degrees (the "zenith" / accelerometer angles: ``[roll, pitch]``) and
  ``0x0004`` the compass heading in degrees (RATIONAL). On the Theta S sample
  ``Jobsite1.JPG`` these read ``[0.7, -0.5]`` and ``90.0``, equal to its GPano
  ``PoseRollDegrees``, ``PosePitchDegrees`` and ``PoseHeadingDegrees``.
- Google, *Photo Sphere XMP metadata* (GPano namespace ``http://ns.google.com/photos/1.0/panorama/``).

Frames
------
Ricoh camera axes (Ricoh's axis definition; the shutter-button side is the *rear*):
**X** right, **Y** toward the front lens (the lens on the side without the shutter button),
**Z** up along the body. Our camera/panorama frame (docs/conventions.md §1-2: x right, y down,
z forward) with "forward" = the front lens axis is reached by

    ``v_ours = M @ v_ricoh``,  ``M = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]``  (:data:`RICOH_TO_OURS`).

:attr:`CaptureMetadata.gravity` is the unit gravity vector (pointing *down*) **in the Ricoh
camera axes**: an upright, level camera records ``[0, 0, -1]``. :attr:`CaptureMetadata.pitch_deg`
and :attr:`CaptureMetadata.roll_deg` are the front-lens frame's orientation relative to the
level frame in our conventions (§4: ``R_cam = R(0, pitch, roll)``; pitch > 0 = front lens tilted
up, roll > 0 = right side down), the same sense as GPano's ``PosePitchDegrees`` /
``PoseRollDegrees``. Heading (compass) is kept in :attr:`CaptureMetadata.heading_deg` and never
used for levelling.

Everything odd (missing EXIF, malformed maker note, impossible values) becomes a named entry
in :attr:`CaptureMetadata.warnings` (``"code: detail"``); only a file that cannot be read as a
JPEG or TIFF/DNG at all raises :class:`solidkit.errors.InputError`.
"""

from __future__ import annotations

import datetime as _dt
import io
import logging
import math
import os
import re
import struct
from pathlib import Path
from typing import Any, Literal, cast

import exifread
import numpy as np
from pydantic import BaseModel, Field

from solidkit.camera.makernote import RICOH_IMAGE_TYPES, ricoh_makernote
from solidkit.camera.orientation import RICOH_TO_OURS, gravity_from_pitch_roll, pitch_roll_from_gravity, pose_fields
from solidkit.camera.tiff import Tiff, TiffError, dng_size, jpeg_segments
from solidkit.camera.xmp import XMP_APP1, parse_gpano
from solidkit.envmap.coords import rotation_from_ypr
from solidkit.errors import InputError

__all__ = [
    "CaptureMetadata",
    "ImageType",
    "RICOH_TO_OURS",
    "read_metadata",
    "gravity_from_pitch_roll",
    "pitch_roll_from_gravity",
    "level_rotation",
]

ImageType = Literal["equirect", "dual_fisheye", "dual_fisheye_upright", "perspective", "unknown"]

_MAX_READ = 64 << 20  # metadata lives in the first MiBs; never slurp more than this

log = logging.getLogger(__name__)


class CaptureMetadata(BaseModel):
    """What a capture file says about itself. Units: seconds, degrees, metres; see module docstring for frames."""

    path: str
    width: int
    height: int
    make: str | None = None
    model: str | None = None
    serial: str | None = None
    firmware: str | None = None
    exposure_time: float | None = Field(None, description="seconds")
    f_number: float | None = None
    iso: float | None = None
    focal_length_mm: float | None = Field(None, description="EXIF FocalLength (actual, not 35 mm-equivalent), mm")
    focal_length_35mm: float | None = Field(None, description="EXIF FocalLengthIn35mmFilm, mm")
    focal_plane_px_per_mm: tuple[float, float] | None = Field(
        None, description="EXIF FocalPlaneX/YResolution in pixels per mm on the sensor (for exif_width/height)"
    )
    exif_width: int | None = Field(None, description="EXIF PixelXDimension: the width the camera recorded")
    exif_height: int | None = Field(None, description="EXIF PixelYDimension")
    datetime_original: _dt.datetime | None = Field(None, description="naive, camera clock")
    utc_offset: str | None = Field(None, description="e.g. '+09:00', as recorded")
    gps: dict[str, Any] | None = Field(
        None,
        description="lat_deg, lon_deg (signed), alt_m (may be None); img_direction_deg, "
        "img_direction_ref ('T' true / 'M' magnetic north) when recorded",
    )
    image_type: ImageType = "unknown"
    zenith_corrected: bool | None = None
    gravity: list[float] | None = Field(
        None, description="unit gravity (down) vector in Ricoh camera axes X right, Y front lens, Z up"
    )
    gravity_source: str | None = Field(None, description="which field gave `gravity`")
    pitch_deg: float | None = None
    roll_deg: float | None = None
    heading_deg: float | None = Field(None, description="compass heading of the front lens, degrees")
    gpano: dict[str, Any] = Field(default_factory=dict)
    sequence: int | None = None
    ricoh: dict[str, Any] = Field(default_factory=dict, description="decoded RICOH THETA IFD tags, by hex tag id")
    file_format: Literal["jpeg", "dng", "tiff"] = "jpeg"
    warnings: list[str] = Field(default_factory=list)


# --------------------------------------------------------------------------- orientation


def level_rotation(meta: CaptureMetadata) -> np.ndarray:
    """Rotation mapping front-lens camera directions (our axes) to the level panorama frame.

    ``R = R(0, pitch, roll)`` from the metadata (identity when no gravity is recorded, when the
    camera already applied zenith correction to an equirectangular image, or for a Ricoh
    in-camera-stitched still: Ricoh image type 1).

    Ricoh stitched stills: their pose tags (maker note ``0x0003``, mirrored in GPano) record the
    body's attitude, which the camera's stitcher has already used, whatever the zenith flag
    says. Evidence (:func:`solidkit.envmap.tilt.residual_tilt` on the shared Theta S
    still ``Jobsite1.JPG``, 1087 vertical edges, ±0.03°): as stored it is 1.74° off level;
    rotated by the recorded pose (pitch -0.5°, roll 0.7°) it is 2.10° off. The recorded pose
    does not describe what is left, so it is not applied; ingest and ``capture unwarp`` measure
    the residual tilt instead and flag it above 0.5°.
    """
    ricoh_stitched = meta.image_type == "equirect" and meta.ricoh.get("0x0001") == [1]
    if (
        meta.pitch_deg is None
        or meta.roll_deg is None
        or ricoh_stitched
        or (meta.image_type == "equirect" and meta.zenith_corrected)
    ):
        return np.eye(3)
    return np.asarray(rotation_from_ypr(0.0, math.radians(meta.pitch_deg), math.radians(meta.roll_deg)))


def _exifread_tags(data: bytes, warnings: list[str]) -> dict[str, Any]:
    logging.getLogger("exifread").setLevel(logging.CRITICAL)
    try:
        tags = exifread.process_file(io.BytesIO(data), details=False, extract_thumbnail=False)
    except Exception as exc:  # exifread raises many types on corrupt input
        warnings.append(f"exif_unreadable: {type(exc).__name__}: {exc}"[:200])
        return {}
    return dict(tags or {})


def _ratio(tag: Any) -> list[float]:
    out = []
    for v in getattr(tag, "values", []) or []:
        if isinstance(v, tuple):  # exifread returns FLOAT/DOUBLE values as 1-tuples (e.g. Pillow-written EXIF)
            v = v[0] if len(v) == 1 else math.nan
        if hasattr(v, "num"):
            out.append(v.num / v.den if v.den else math.nan)
        else:
            out.append(float(v))
    return out


#: EXIF FocalPlaneResolutionUnit -> millimetres per unit (1: no unit; 2: inch, the EXIF default;
#: 3: cm; 4: mm and 5: µm as some writers use).
_FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


def _focal_geometry(tags: dict[str, Any], warnings: list[str]) -> dict[str, Any]:
    """Focal length (mm), its 35 mm equivalent, focal-plane resolution (px/mm) and the recorded size."""
    out: dict[str, Any] = {
        "focal_length_mm": _first_number(tags, ("EXIF FocalLength",), "focal_length", warnings),
        "focal_length_35mm": _first_number(tags, ("EXIF FocalLengthIn35mmFilm",), "focal_length_35mm", warnings),
    }
    for key, name in (("EXIF ExifImageWidth", "exif_width"), ("EXIF ExifImageLength", "exif_height")):
        v = _first_number(tags, (key,), name, warnings)
        out[name] = int(v) if v is not None and v < 2**31 and v == int(v) else None
        if v is not None and out[name] is None:
            warnings.append(f"bad_{name}: {v!r}")
    xres = _first_number(tags, ("EXIF FocalPlaneXResolution",), "focal_plane_resolution", warnings)
    yres = _first_number(tags, ("EXIF FocalPlaneYResolution",), "focal_plane_resolution", warnings)
    unit = _first_number(tags, ("EXIF FocalPlaneResolutionUnit",), "focal_plane_unit", warnings) or 2.0
    mm = _FOCAL_PLANE_UNIT_MM.get(int(unit)) if unit == int(unit) else None
    out["focal_plane_px_per_mm"] = None
    if xres is not None:
        if mm is None:
            warnings.append(f"bad_focal_plane_unit: {unit!r} (no physical unit; focal-plane resolution ignored)")
        else:
            out["focal_plane_px_per_mm"] = (xres / mm, (yres or xres) / mm)
    return out


def _first_number(
    tags: dict[str, Any], keys: tuple[str, ...], name: str, warnings: list[str], positive: bool = True
) -> float | None:
    for key in keys:
        if key not in tags:
            continue
        try:
            vals = _ratio(tags[key])
        except (TypeError, ValueError, ZeroDivisionError):
            vals = []
        if not vals or not math.isfinite(vals[0]) or (positive and vals[0] <= 0):
            warnings.append(f"bad_{name}: {str(tags[key])[:40]!r}")
            return None
        return float(vals[0])
    return None


def _text(tags: dict[str, Any], key: str) -> str | None:
    if key not in tags:
        return None
    s = str(tags[key].printable if hasattr(tags[key], "printable") else tags[key]).strip().strip("\x00").strip()
    return s or None


def _parse_datetime(s: str | None, warnings: list[str]) -> _dt.datetime | None:
    if not s:
        return None
    m = re.fullmatch(r"(\d{4})[:-](\d{2})[:-](\d{2})[ T](\d{2}):(\d{2}):(\d{2})(?:\.\d+)?.*", s.strip())
    if not m:
        warnings.append(f"bad_datetime: {s[:40]!r}")
        return None
    try:
        y, mo, d, hh, mi, ss = (int(g) for g in m.groups())
        return _dt.datetime(y, mo, d, hh, mi, ss)
    except ValueError:
        warnings.append(f"bad_datetime: {s[:40]!r}")
        return None


def _gps(tags: dict[str, Any], warnings: list[str]) -> dict[str, Any] | None:
    if "GPS GPSLatitude" not in tags or "GPS GPSLongitude" not in tags:
        return None
    try:

        def dms(key: str) -> float:
            v = _ratio(tags[key])
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                raise ValueError(key)
            return v[0] + v[1] / 60.0 + v[2] / 3600.0

        lat, lon = dms("GPS GPSLatitude"), dms("GPS GPSLongitude")
        if _text(tags, "GPS GPSLatitudeRef") in ("S", "s"):
            lat = -lat
        if _text(tags, "GPS GPSLongitudeRef") in ("W", "w"):
            lon = -lon
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise ValueError("out of range")
        alt = None
        if "GPS GPSAltitude" in tags:
            a = _ratio(tags["GPS GPSAltitude"])
            if a and math.isfinite(a[0]):
                alt = -a[0] if str(tags.get("GPS GPSAltitudeRef", "0")).strip() in ("1", "Below Sea Level") else a[0]
        out: dict[str, Any] = {"lat_deg": lat, "lon_deg": lon, "alt_m": alt}
    except (ValueError, TypeError, ZeroDivisionError, IndexError) as exc:
        warnings.append(f"bad_gps: {exc}"[:80])
        return None
    # GPSImgDirection: the direction the camera points, degrees clockwise from true ("T") or magnetic ("M") north
    if "GPS GPSImgDirection" in tags:
        try:
            d = _ratio(tags["GPS GPSImgDirection"])[0]
            if not (math.isfinite(d) and 0.0 <= d <= 360.0):
                raise ValueError(d)
            out["img_direction_deg"] = d % 360.0
            out["img_direction_ref"] = "M" if _text(tags, "GPS GPSImgDirectionRef") in ("M", "m") else "T"
        except (ValueError, TypeError, ZeroDivisionError, IndexError) as exc:
            warnings.append(f"bad_gps_direction: {exc}"[:80])
    return out


#: Seconds by which the clock (DateTimeOriginal, as UTC) may differ from GPSTimeStamp: the GPS
#: fix a camera stamps may be some tens of seconds old.
GPS_CLOCK_TOLERANCE_S = 90.0


def _offset_minutes(text: str | None) -> int | None:
    """``"+09:00"`` / ``"-05:30"`` -> minutes east of UTC (None: absent or unreadable)."""
    m = re.fullmatch(r"([+-])(\d{2}):?(\d{2})", (text or "").strip())
    if not m or int(m.group(2)) > 14 or int(m.group(3)) > 59:
        return None
    return (1 if m.group(1) == "+" else -1) * (60 * int(m.group(2)) + int(m.group(3)))


def gps_clock_warning(
    tags: dict[str, Any], local: _dt.datetime | None, utc_offset: str | None, warnings: list[str]
) -> None:
    """``clock_mismatch`` when the camera clock disagrees with the photo's own GPS time (UTC).

    GPS time is ``GPSDateStamp`` + ``GPSTimeStamp``. With a UTC offset known, ``local - offset``
    must be within :data:`GPS_CLOCK_TOLERANCE_S` of it (a clock an hour off is caught). Without
    an offset the zone is unknown: the difference must be a whole number of quarter hours within
    ±14 h (UTC offsets are; a clock off by whole hours is then indistinguishable from the zone).
    """
    date = _text(tags, "GPS GPSDate") or _text(tags, "GPS GPSDateStamp")  # exifread names tag 0x001D GPSDate
    if local is None or "GPS GPSTimeStamp" not in tags or date is None:
        return
    try:
        hms = _ratio(tags["GPS GPSTimeStamp"])
        y, mo, d = (int(x) for x in re.split(r"[:-]", date)[:3])
        if len(hms) != 3 or not all(math.isfinite(x) for x in hms):
            raise ValueError("GPSTimeStamp")
        gps = _dt.datetime(y, mo, d) + _dt.timedelta(hours=hms[0], minutes=hms[1], seconds=hms[2])
    except (ValueError, TypeError, ZeroDivisionError, OverflowError):
        warnings.append("bad_gps_time: GPSDateStamp/GPSTimeStamp unreadable; not compared with the clock")
        return
    off = _offset_minutes(utc_offset)
    delta = (local - gps).total_seconds()  # local clock minus UTC, seconds
    if off is not None:
        err = delta - 60.0 * off
        if abs(err) > GPS_CLOCK_TOLERANCE_S:
            warnings.append(
                f"clock_mismatch: DateTimeOriginal {local:%Y-%m-%d %H:%M:%S} {utc_offset} is {err:+.0f} s from "
                f"the photo's GPS time {gps:%Y-%m-%d %H:%M:%S} UTC (camera clock or UTC offset wrong?)"
            )
        return
    zone = 900.0 * round(delta / 900.0)
    if abs(delta - zone) > GPS_CLOCK_TOLERANCE_S or abs(zone) > 14 * 3600:
        warnings.append(
            f"clock_mismatch: DateTimeOriginal {local:%Y-%m-%d %H:%M:%S} (no UTC offset) is {delta:+.0f} s from the "
            f"photo's GPS time {gps:%Y-%m-%d %H:%M:%S} UTC, not a time zone's offset (camera clock wrong?)"
        )


def read_metadata(path: str | os.PathLike[str]) -> CaptureMetadata:
    """Read the capture metadata of a JPEG or DNG/TIFF file.

    Parameters
    ----------
    path : path to a JPEG (``FF D8``) or TIFF/DNG (``II*\\0`` / ``MM\\0*``) file.

    Returns
    -------
    CaptureMetadata
        Never raises on odd or missing fields: each problem is a named warning
        (``"code: detail"``) in ``.warnings``.

    Raises
    ------
    InputError
        Missing, empty or unreadable file; neither JPEG nor TIFF/DNG; no image size found.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    try:
        with open(p, "rb") as f:
            data = f.read(_MAX_READ)
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from exc
    return _read_metadata_bytes(data, str(p))


def _container(data: bytes, name: str, warnings: list[str]) -> tuple[str, Tiff | None, bytes | None, tuple[int, int]]:
    """``(file format, TIFF structure of the EXIF block or file, XMP packet, (width, height))`` of a JPEG or
    TIFF/DNG."""
    if len(data) == 0:
        raise InputError(f"{name}: empty file (0 bytes)")
    tiff: Tiff | None = None
    xmp_packet: bytes | None = None
    size: tuple[int, int] | None = None
    if data[:2] == b"\xff\xd8":
        fmt = "jpeg"
        segs, size = jpeg_segments(data)
        for marker, payload in segs:
            if marker == 0xE1 and payload.startswith(b"Exif\x00\x00") and tiff is None:
                try:
                    tiff = Tiff(payload[6:])
                except (TiffError, struct.error) as exc:
                    warnings.append(f"exif_unreadable: {exc}")
            elif marker == 0xE1 and payload.startswith(XMP_APP1) and xmp_packet is None:
                xmp_packet = payload[len(XMP_APP1) :]
        if size is None:
            raise InputError(f"{name}: corrupt or truncated JPEG (no frame header found)")
        if tiff is None and not any(w.startswith("exif_unreadable") for w in warnings):
            warnings.append("no_exif: the file carries no EXIF block")
    elif data[:4] in (b"II*\x00", b"MM\x00*"):
        try:
            tiff = Tiff(data)
        except (TiffError, struct.error) as exc:
            raise InputError(f"{name}: corrupt TIFF/DNG header ({exc})") from exc
        try:
            ifd0 = tiff.ifd(tiff.first_ifd)
        except (TiffError, struct.error) as exc:
            raise InputError(f"{name}: corrupt TIFF/DNG ({exc})") from exc
        fmt = "dng" if 0xC612 in ifd0 else "tiff"  # DNGVersion
        if 0x02BC in ifd0:  # XMLPacket
            try:
                xmp_packet = bytes(tiff.value(ifd0[0x02BC]))
            except (struct.error, KeyError, TypeError):
                warnings.append("xmp_unparsable: bad XMLPacket tag")
        size = dng_size(tiff, warnings)
        if size is None:
            raise InputError(f"{name}: TIFF/DNG without a readable main image")
    else:
        raise InputError(f"{name}: not a JPEG or DNG/TIFF file (starts with {data[:4]!r})")
    if size[0] <= 0 or size[1] <= 0:
        raise InputError(f"{name}: invalid image size {size[0]}x{size[1]}")

    return fmt, tiff, xmp_packet, size


def _read_metadata_bytes(data: bytes, name: str) -> CaptureMetadata:
    warnings: list[str] = []
    fmt, tiff, xmp_packet, size = _container(data, name, warnings)
    tags = _exifread_tags(data, warnings) if tiff is not None else {}
    meta: dict[str, Any] = {"path": name, "width": size[0], "height": size[1], "file_format": fmt}
    meta["make"] = _text(tags, "Image Make")
    meta["model"] = _text(tags, "Image Model")
    meta["firmware"] = _text(tags, "Image Software")
    meta["serial"] = _text(tags, "EXIF BodySerialNumber") or _text(tags, "Image CameraSerialNumber")
    meta["exposure_time"] = _first_number(tags, ("EXIF ExposureTime",), "exposure_time", warnings)
    if meta["exposure_time"] is None and "EXIF ShutterSpeedValue" in tags:
        apex = _first_number(tags, ("EXIF ShutterSpeedValue",), "shutter_speed", warnings, positive=False)
        if apex is not None and apex != 0 and abs(apex) < 40:
            meta["exposure_time"] = 2.0 ** (-apex)
            warnings.append("exposure_from_apex: ExposureTime missing, used ShutterSpeedValue")
    meta["f_number"] = _first_number(tags, ("EXIF FNumber",), "f_number", warnings)
    meta["iso"] = _first_number(tags, ("EXIF ISOSpeedRatings", "EXIF PhotographicSensitivity"), "iso", warnings)
    meta.update(_focal_geometry(tags, warnings))
    if tiff is not None and meta["exposure_time"] is None:
        warnings.append("no_exposure_time: EXIF ExposureTime absent or invalid")
    dt_text = _text(tags, "EXIF DateTimeOriginal") or _text(tags, "Image DateTime")
    meta["datetime_original"] = _parse_datetime(dt_text, warnings)
    meta["utc_offset"] = _text(tags, "EXIF OffsetTimeOriginal") or _text(tags, "EXIF OffsetTime")
    meta["gps"] = _gps(tags, warnings)
    seq = _first_number(tags, ("EXIF ImageNumber",), "sequence", warnings, positive=False)
    meta["sequence"] = int(seq) if seq is not None and abs(seq) < 2**31 else None

    # --- GPano XMP
    gpano: dict[str, Any] = {}
    if xmp_packet is not None:
        gpano = parse_gpano(xmp_packet, warnings)
    meta["gpano"] = gpano

    # --- Ricoh maker note
    ricoh_main: dict[int, Any] = {}
    theta: dict[int, Any] = {}
    if tiff is not None:
        mn = ricoh_makernote(tiff, warnings)
        if mn is not None:
            ricoh_main, theta = mn
    is_ricoh = (meta["make"] or "").upper().startswith("RICOH")
    if is_ricoh and not ricoh_main:
        warnings.append("no_ricoh_makernote: RICOH file without a readable Ricoh maker note")
    meta["ricoh"] = {f"0x{k:04x}": (v.hex() if isinstance(v, bytes) else v) for k, v in theta.items()}
    if meta["serial"] is None and isinstance(ricoh_main.get(0x0005), bytes):
        s = ricoh_main[0x0005].split(b"\x00", 1)[0].decode("latin-1", "replace").strip()
        meta["serial"] = s or None
    if meta["utc_offset"] is None and isinstance(theta.get(0x000A), str) and theta[0x000A]:
        meta["utc_offset"] = theta[0x000A]

    # image type
    image_type: ImageType = "unknown"
    t = theta.get(0x0001)
    if isinstance(t, list) and t:
        image_type = cast(ImageType, RICOH_IMAGE_TYPES.get(int(t[0]), "unknown"))
        if image_type == "unknown":
            warnings.append(f"unsupported_image_type: Ricoh image type {t[0]} (single fisheye or unknown)")
    elif str(gpano.get("ProjectionType", "")).lower() == "equirectangular":
        image_type = "equirect"
    elif tiff is not None and not is_ricoh and meta["make"] is not None:
        image_type = "perspective"
    elif size[0] == 2 * size[1]:
        warnings.append("image_type_guessed: 2:1 image without Ricoh or GPano metadata; treated as unknown")
    meta["image_type"] = image_type

    zc = theta.get(0x0007)
    meta["zenith_corrected"] = bool(zc[0]) if isinstance(zc, list) and zc and zc[0] in (0, 1) else None
    if isinstance(zc, list) and zc and zc[0] not in (0, 1):
        warnings.append(f"bad_zenith_correction: {zc[0]}")

    meta.update(pose_fields(theta, gpano, warnings))

    # sanity
    if meta["datetime_original"] is not None and is_ricoh and meta["datetime_original"].date() == _dt.date(2015, 1, 1):
        warnings.append("clock_unset: 2015-01-01 is the Theta's factory date; the camera clock was probably never set")
    gps_clock_warning(tags, meta["datetime_original"], meta["utc_offset"], warnings)
    fw, fh = gpano.get("FullPanoWidthPixels"), gpano.get("FullPanoHeightPixels")
    if isinstance(fw, int) and isinstance(fh, int) and (fw, fh) != size:
        warnings.append(f"gpano_size_mismatch: GPano {fw}x{fh}, image {size[0]}x{size[1]}")
    meta["warnings"] = warnings
    return CaptureMetadata(**meta)
