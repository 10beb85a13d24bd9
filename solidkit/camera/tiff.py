"""TIFF and JPEG containers of capture files: a bounds-checked TIFF-IFD reader, JPEG segments, the DNG main image.

The reader never trusts an offset or a count: every IFD, entry and value is checked against the
buffer (:class:`TiffError` otherwise), so that corrupt or hostile files give warnings, not
crashes (``tests/camera/test_metadata.py`` fuzzes it). References: Adobe, *TIFF 6.0*
(IFD layout, field types) and *DNG 1.6* (SubIFDs, NewSubFileType, DefaultCropSize); ITU T.81
(JPEG markers).
"""

from __future__ import annotations

import math
import struct
from typing import Any

__all__ = ["TiffError", "Tiff", "jpeg_segments", "dng_size"]

_TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}
_MAX_ENTRIES = 512


class TiffError(ValueError):
    """A TIFF structure (header, IFD, pointer) that cannot be read."""


class Tiff:
    """Bounds-checked reader of TIFF IFDs in ``buf`` (offsets relative to the TIFF header)."""

    def __init__(self, buf: bytes):
        if len(buf) < 8 or buf[:2] not in (b"II", b"MM"):
            raise TiffError("no TIFF header")
        self.buf = buf
        self.bo = "<" if buf[:2] == b"II" else ">"
        if struct.unpack(self.bo + "H", buf[2:4])[0] != 42:
            raise TiffError("bad TIFF magic")
        self.first_ifd = struct.unpack(self.bo + "I", buf[4:8])[0]

    def ifd(self, offset: int) -> dict[int, tuple[int, int, int]]:
        """Entries ``tag -> (type, count, value_offset_or_inline_pos)`` of the IFD at ``offset``."""
        buf, bo = self.buf, self.bo
        if not isinstance(offset, int):  # a pointer tag whose type byte was mangled into RATIONAL/ASCII
            raise TiffError(f"IFD pointer is a {type(offset).__name__}, not an offset")
        if offset <= 0 or offset + 2 > len(buf):
            raise TiffError(f"IFD offset {offset} out of range")
        n = struct.unpack(bo + "H", buf[offset : offset + 2])[0]
        if n == 0 or n > _MAX_ENTRIES or offset + 2 + 12 * n > len(buf):
            raise TiffError(f"IFD at {offset}: implausible entry count {n}")
        out: dict[int, tuple[int, int, int]] = {}
        for i in range(n):
            p = offset + 2 + 12 * i
            tag, typ, cnt = struct.unpack(bo + "HHI", buf[p : p + 8])
            size = _TYPE_SIZES.get(typ)
            if size is None:
                continue  # unknown type: skip the entry (TIFF 6.0 says readers should)
            nbytes = size * cnt
            pos = p + 8 if nbytes <= 4 else struct.unpack(bo + "I", buf[p + 8 : p + 12])[0]
            if pos + nbytes > len(buf):
                continue
            out[tag] = (typ, cnt, pos)
        return out

    def value(self, entry: tuple[int, int, int]) -> Any:
        """Decoded value: ``str`` for ASCII, ``bytes`` for UNDEFINED, else a list of numbers."""
        typ, cnt, pos = entry
        buf, bo = self.buf, self.bo
        raw = buf[pos : pos + _TYPE_SIZES[typ] * cnt]
        if typ == 2:
            return raw.split(b"\x00", 1)[0].decode("latin-1").strip()
        if typ in (1, 7):
            return raw if typ == 7 else list(raw)
        if typ in (5, 10):
            fmt = "I" if typ == 5 else "i"
            pairs = struct.unpack(bo + fmt * (2 * cnt), raw)
            return [(pairs[2 * i] / pairs[2 * i + 1]) if pairs[2 * i + 1] else math.nan for i in range(cnt)]
        fmt = {3: "H", 4: "I", 6: "b", 8: "h", 9: "i", 11: "f", 12: "d", 13: "I"}[typ]
        return list(struct.unpack(bo + fmt * cnt, raw))


def jpeg_segments(data: bytes) -> tuple[list[tuple[int, bytes]], tuple[int, int] | None]:
    """APPn segments ``(marker, payload)`` and the ``(width, height)`` from the SOF marker."""
    segs: list[tuple[int, bytes]] = []
    size = None
    p = 2
    n = len(data)
    while p + 4 <= n:
        if data[p] != 0xFF:
            break
        marker = data[p + 1]
        if marker == 0xFF:  # fill byte
            p += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            p += 2
            continue
        if marker == 0xD9:
            break
        length = struct.unpack(">H", data[p + 2 : p + 4])[0]
        if length < 2 or p + 2 + length > n:
            break
        payload = data[p + 4 : p + 2 + length]
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            if len(payload) >= 5:
                h, w = struct.unpack(">HH", payload[1:5])
                size = (w, h)
            break
        if marker == 0xDA:
            break
        segs.append((marker, payload))
        p += 2 + length
    return segs, size


def dng_size(tiff: Tiff, warnings: list[str]) -> tuple[int, int] | None:
    """Size of the full-resolution image of a TIFF/DNG (DefaultCropSize when present)."""
    seen: set[int] = set()
    stack = [tiff.first_ifd]
    best = None
    while stack and len(seen) < 32:
        off = stack.pop()
        if off in seen:
            continue
        seen.add(off)
        try:
            ifd = tiff.ifd(off)
        except (TiffError, struct.error):
            continue
        try:
            if 0x014A in ifd:  # SubIFDs
                stack.extend(int(x) for x in tiff.value(ifd[0x014A]))
            subfile = tiff.value(ifd[0x00FE])[0] if 0x00FE in ifd else 0
            if 0x0100 in ifd and 0x0101 in ifd and subfile == 0:
                w, h = tiff.value(ifd[0x0100])[0], tiff.value(ifd[0x0101])[0]
                if 0xC620 in ifd:  # DefaultCropSize
                    cw, ch = tiff.value(ifd[0xC620])[:2]
                    if cw > 0 and ch > 0:
                        w, h = cw, ch
                if best is None or w * h > best[0] * best[1]:
                    best = (int(w), int(h))
        except (struct.error, IndexError, TypeError, ValueError):
            continue
    if best is None:
        warnings.append("dng_no_main_image: no full-resolution IFD (NewSubFileType 0) found")
    return best
