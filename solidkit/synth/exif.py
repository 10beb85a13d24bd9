"""A minimal EXIF writer for the virtual campaign: camera, exposure, time (+ UTC offset), GPS (+ heading), Ricoh
maker note.

Writes a little-endian TIFF structure (IFD0 -> Exif IFD -> MakerNote, GPS IFD) into a JPEG's
APP1 segment. The Ricoh maker note follows Ricoh's *THETA Metadata Spec*
(``ricohapi/theta-api-specs``, ``theta-metadata``) as read by :mod:`solidkit.camera.metadata`:
``b"Ricoh\\0\\0\\0"``, an IFD whose tag ``0x4001`` (LONG) holds the TIFF-relative offset of the
RICOH THETA IFD with ``0x0001`` image type (2 = dual-fisheye), ``0x0003`` ``[roll, pitch]``
degrees (SRATIONAL[2]), ``0x0004`` compass heading (RATIONAL), ``0x0007`` zenith correction (0).
"""

from __future__ import annotations

import datetime as dt
import struct
from fractions import Fraction
from typing import Any, cast

__all__ = ["exif_app1", "insert_app1"]

ASCII, SHORT, LONG, RATIONAL, UNDEFINED, SRATIONAL, BYTE = 2, 3, 4, 5, 7, 10, 1


def _rational(values: list[float], signed: bool = False) -> bytes:
    out = b""
    for v in values:
        f = Fraction(v).limit_denominator(1_000_000)
        out += struct.pack("<ii" if signed else "<II", f.numerator, f.denominator)
    return out


def _entry(tag: int, typ: int, value: Any) -> tuple[int, int, bytes, int]:
    if typ == ASCII:
        b = str(value).encode("ascii") + b"\x00"
        return tag, typ, b, len(b)
    if typ == UNDEFINED:
        return tag, typ, bytes(value), len(value)
    vals = list(value) if isinstance(value, (list, tuple)) else [value]
    if typ == SHORT:
        return tag, typ, struct.pack("<" + "H" * len(vals), *[int(v) for v in vals]), len(vals)
    if typ == LONG:
        return tag, typ, struct.pack("<" + "I" * len(vals), *[int(v) for v in vals]), len(vals)
    if typ == BYTE:
        return tag, typ, bytes(int(v) for v in vals), len(vals)
    if typ in (RATIONAL, SRATIONAL):
        return tag, typ, _rational(vals, signed=typ == SRATIONAL), len(vals)
    raise ValueError(f"unsupported TIFF type {typ}")


def _ifd(entries: list[tuple[int, int, bytes, int]], base: int) -> tuple[bytes, dict[int, int]]:
    """Serialise an IFD placed at TIFF offset ``base``; returns bytes and each tag's payload offset."""
    entries = sorted(entries)
    n = len(entries)
    data_off = base + 2 + 12 * n + 4
    where: dict[int, int]
    head, data, where = struct.pack("<H", n), b"", {}
    for tag, typ, payload, count in entries:
        if len(payload) <= 4:
            head += struct.pack("<HHI", tag, typ, count) + payload.ljust(4, b"\x00")
            where[tag] = base + 2 + 12 * (len(where)) + 8
        else:
            where[tag] = data_off + len(data)
            head += struct.pack("<HHII", tag, typ, count, where[tag])
            data += payload + (b"\x00" if len(payload) % 2 else b"")
    return head + struct.pack("<I", 0) + data, where


def _ricoh_makernote(base: int, image_type: int, roll_deg: float, pitch_deg: float, heading_deg: float | None) -> bytes:
    """Maker note bytes for placement at TIFF offset ``base``."""
    theta_entries = [
        _entry(0x0001, SHORT, image_type),
        _entry(0x0003, SRATIONAL, [roll_deg, pitch_deg]),
        _entry(0x0007, SHORT, 0),
    ]
    if heading_deg is not None:
        theta_entries.append(_entry(0x0004, RATIONAL, heading_deg % 360.0))
    main_base = base + 8
    main_len = 2 + 12 + 4
    theta_base = main_base + main_len
    main, _ = _ifd([_entry(0x4001, LONG, theta_base)], main_base)
    assert len(main) == main_len
    theta, _ = _ifd(theta_entries, theta_base)
    return b"Ricoh\x00\x00\x00" + main + theta


def exif_app1(
    *,
    make: str,
    model: str,
    when: dt.datetime,
    exposure_time: float,
    f_number: float,
    iso: int,
    gps: tuple[float, float, float] | None = None,
    focal_length_mm: float | None = None,
    focal_35mm: float | None = None,
    theta: dict[str, Any] | None = None,
    software: str = "solidkit synth",
    img_direction_deg: float | None = None,
) -> bytes:
    """APP1 payload (``b"Exif\\0\\0"`` + TIFF) with the given fields.

    ``when``: naive (camera clock, no offset written) or aware: ``DateTime(Original)`` is then its
    local clock time, ``OffsetTime``/``OffsetTimeOriginal`` its UTC offset (``+HH:MM``) and, with
    ``gps``, ``GPSDateStamp``/``GPSTimeStamp`` the UTC date and time, as a phone writes them.
    ``gps``: (latitude, longitude, altitude m); ``img_direction_deg``: the true heading of the
    camera (``GPSImgDirectionRef = "T"``, ``GPSImgDirection``, degrees clockwise from true north;
    needs ``gps``); ``theta``: ``{"image_type", "roll_deg", "pitch_deg", "heading_deg"}`` adds
    the Ricoh maker note.
    """
    stamp = when.strftime("%Y:%m:%d %H:%M:%S")
    ifd0 = [
        _entry(0x010F, ASCII, make),
        _entry(0x0110, ASCII, model),
        _entry(0x0131, ASCII, software),
        _entry(0x0132, ASCII, stamp),
        _entry(0x8769, LONG, 0),
    ]
    if gps is not None:
        ifd0.append(_entry(0x8825, LONG, 0))
    exif = [
        _entry(0x829A, RATIONAL, exposure_time),
        _entry(0x829D, RATIONAL, f_number),
        _entry(0x8827, SHORT, iso),
        _entry(0x9003, ASCII, stamp),
    ]
    utc = None
    if when.tzinfo is not None and when.utcoffset() is not None:
        minutes = int(cast(dt.timedelta, when.utcoffset()).total_seconds() // 60)
        offset = f"{'+' if minutes >= 0 else '-'}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"
        exif += [_entry(0x9010, ASCII, offset), _entry(0x9011, ASCII, offset)]
        utc = when.astimezone(dt.timezone.utc)
    if focal_length_mm is not None:
        exif.append(_entry(0x920A, RATIONAL, focal_length_mm))
    if focal_35mm is not None:
        exif.append(_entry(0xA405, SHORT, round(focal_35mm)))
    # layout: header (8) | IFD0 | Exif IFD (+ maker note) | GPS IFD
    ifd0_bytes, _ = _ifd(ifd0, 8)
    exif_off = 8 + len(ifd0_bytes)
    if theta is not None:
        placeholder = _ricoh_makernote(
            0, theta["image_type"], theta["roll_deg"], theta["pitch_deg"], theta.get("heading_deg")
        )
        exif_probe = exif + [_entry(0x927C, UNDEFINED, placeholder)]
        _, where = _ifd(exif_probe, exif_off)
        mn = _ricoh_makernote(
            where[0x927C], theta["image_type"], theta["roll_deg"], theta["pitch_deg"], theta.get("heading_deg")
        )
        exif = exif + [_entry(0x927C, UNDEFINED, mn)]
    exif_bytes, _ = _ifd(exif, exif_off)
    gps_off = exif_off + len(exif_bytes)
    gps_bytes = b""
    if gps is not None:
        lat, lon, alt = gps

        def dms(v: float) -> list[float]:
            v = abs(v)
            d = int(v)
            m = int((v - d) * 60)
            return [d, m, round(((v - d) * 60 - m) * 60, 4)]

        gps_extra = []
        if utc is not None:
            gps_extra += [
                _entry(0x0007, RATIONAL, [utc.hour, utc.minute, utc.second + utc.microsecond / 1e6]),
                _entry(0x001D, ASCII, utc.strftime("%Y:%m:%d")),
            ]
        if img_direction_deg is not None:
            gps_extra += [_entry(0x0010, ASCII, "T"), _entry(0x0011, RATIONAL, float(img_direction_deg) % 360.0)]
        gps_bytes, _ = _ifd(
            [
                _entry(0x0000, BYTE, [2, 3, 0, 0]),
                _entry(0x0001, ASCII, "N" if lat >= 0 else "S"),
                _entry(0x0002, RATIONAL, dms(lat)),
                _entry(0x0003, ASCII, "E" if lon >= 0 else "W"),
                _entry(0x0004, RATIONAL, dms(lon)),
                _entry(0x0005, BYTE, 0 if alt >= 0 else 1),
                _entry(0x0006, RATIONAL, abs(alt)),
            ]
            + gps_extra,
            gps_off,
        )
    # now fill in the pointers
    ifd0 = [e for e in ifd0 if e[0] not in (0x8769, 0x8825)] + [_entry(0x8769, LONG, exif_off)]
    if gps is not None:
        ifd0.append(_entry(0x8825, LONG, gps_off))
    ifd0_final, _ = _ifd(ifd0, 8)
    assert len(ifd0_final) == len(ifd0_bytes)
    tiff = b"II" + struct.pack("<HI", 42, 8) + ifd0_final + exif_bytes + gps_bytes
    return b"Exif\x00\x00" + tiff


def insert_app1(jpeg: bytes, app1: bytes) -> bytes:
    """Insert an APP1 segment right after a JPEG's SOI marker."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG")
    if len(app1) + 2 > 0xFFFF:
        raise ValueError("APP1 segment too large")
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]
