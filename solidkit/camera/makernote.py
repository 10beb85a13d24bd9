"""The Ricoh maker note: the "RICOH THETA IFD" that no Python library decodes (references: solidkit.camera.metadata).

The maker note starts with ``b"Ricoh\\0\\0\\0"`` and an IFD whose tag ``0x4001`` points to the
RICOH THETA IFD (image type ``0x0001``, zenith angles ``0x0003``, compass ``0x0004``, zenith
correction ``0x0007``, time zone ``0x000A``, zenith rotation vector ``0x0109``).
"""

from __future__ import annotations

import struct
from typing import Any

from solidkit.camera.tiff import Tiff, TiffError

__all__ = ["RICOH_IMAGE_TYPES", "ricoh_makernote"]

#: RICOH THETA IFD tag 0x0001 -> image type (4-6, single fisheye, are not supported).
RICOH_IMAGE_TYPES = {1: "equirect", 2: "dual_fisheye", 3: "dual_fisheye_upright"}


def ricoh_makernote(tiff: Tiff, warnings: list[str]) -> tuple[dict[int, Any], dict[int, Any]] | None:
    """``(maker-note IFD, RICOH THETA IFD)`` decoded, or ``None`` when absent."""
    try:
        ifd0 = tiff.ifd(tiff.first_ifd)
        if 0x8769 not in ifd0:
            return None
        exif_off = tiff.value(ifd0[0x8769])[0]
        exif = tiff.ifd(exif_off)
        if 0x927C not in exif:
            return None
        _, cnt, mn = exif[0x927C]
    except (TiffError, struct.error, IndexError, KeyError) as exc:
        warnings.append(f"exif_ifd_unreadable: {exc}"[:120])
        return None
    if tiff.buf[mn : mn + 8] != b"Ricoh\x00\x00\x00":
        return None
    try:
        main = tiff.ifd(mn + 8)
    except (TiffError, struct.error) as exc:
        warnings.append(f"makernote_unreadable: {exc}"[:120])
        return None
    main_vals: dict[int, Any] = {}
    for tag, entry in main.items():
        try:
            main_vals[tag] = tiff.value(entry)
        except (struct.error, KeyError, UnicodeDecodeError):
            warnings.append(f"makernote_bad_tag: 0x{tag:04x}")
    theta: dict[int, Any] = {}
    if 0x4001 in main_vals and isinstance(main_vals[0x4001], list) and main_vals[0x4001]:
        off = int(main_vals[0x4001][0])
        ifd = None
        for base in (0, mn):  # offsets are TIFF-relative on the S; tolerate makernote-relative writers
            try:
                ifd = tiff.ifd(base + off)
                break
            except (TiffError, struct.error):
                continue
        if ifd is None:
            warnings.append("makernote_unreadable: RICOH THETA IFD offset invalid")
        else:
            for tag, entry in ifd.items():
                try:
                    theta[tag] = tiff.value(entry)
                except (struct.error, KeyError, UnicodeDecodeError):
                    warnings.append(f"makernote_bad_tag: theta 0x{tag:04x}")
    else:
        warnings.append("makernote_no_theta_ifd: the Ricoh maker note has no RICOH THETA IFD (tag 0x4001)")
    return main_vals, theta
