"""Pixels for the labeling app: downscaled previews, panorama tiles and full-resolution crops.

A 7296x3648 panorama is never sent whole: the browser gets a preview (at most
:data:`PREVIEW_WIDTH` wide) and then only the tiles (equirect panoramas) or crops (photos) it
looks at closely, each encoded once and kept in a small in-memory cache. Nothing is written to
disk. Decoded full-resolution images are kept in a least-recently-used cache bounded in bytes.

Display encoding: LDR files are shown as stored (sRGB); HDR (EXR) products are exposed so that
their median luminance maps to 18 % grey, then sRGB-encoded (conventions §5); the browser's
exposure slider works on top of that.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from solidkit.envmap.io import imread, read_exr, srgb_encode
from solidkit.envmap.sun import LUMINANCE_WEIGHTS
from solidkit.errors import InputError

__all__ = ["PREVIEW_WIDTH", "TILE_TARGET", "ImageRef", "ImageService", "tile_grid", "tile_box"]

PREVIEW_WIDTH = 2048  # px: the base texture of the panorama viewer, the photo's first view
TILE_TARGET = 512  # px: wanted tile edge; the grid is a power of two (the viewer's requirement)
MAX_CROP_OUT = 2048  # px: largest crop edge sent
JPEG_QUALITY = 88


@dataclass(frozen=True)
class ImageRef:
    """A campaign image the app may serve.

    Attributes
    ----------
    id : str
        Opaque id used in URLs (``img-`` + 16 hex digits of a hash of the path, size and mtime).
    path : Path
        Resolved absolute path, inside the campaign (checked by the caller).
    layout : {"equirect", "perspective"}
    hdr : bool
        EXR file (exposed for display).
    """

    id: str
    path: Path
    layout: str
    hdr: bool = False


def tile_grid(width: int) -> tuple[int, int]:
    """``(cols, rows)`` of the tile grid of an equirect panorama ``width`` px wide.

    Powers of two (Photo Sphere Viewer's tiles adapter), ``cols = 2 rows``, tiles close to
    :data:`TILE_TARGET` px; at least 2 x 1.
    """
    cols = 2 ** max(1, round(math.log2(max(width, 2) / TILE_TARGET)))
    return cols, cols // 2


def tile_box(width: int, height: int, cols: int, rows: int, col: int, row: int) -> tuple[int, int, int, int]:
    """Pixel box ``(x0, y0, x1, y1)`` of tile ``(col, row)``; edges rounded so tiles abut exactly."""
    return (
        round(col * width / cols),
        round(row * height / rows),
        round((col + 1) * width / cols),
        round((row + 1) * height / rows),
    )


def _to_display8(path: Path, hdr: bool) -> np.ndarray:
    """Decode to uint8 BGR for display (EXIF orientation ignored: pixels as stored, like K)."""
    if hdr:
        rgb, _ = read_exr(path)
        rgb = np.repeat(rgb, 3, axis=2) if rgb.shape[2] == 1 else rgb[..., :3]
        lum = rgb @ LUMINANCE_WEIGHTS
        med = float(np.median(lum[np.isfinite(lum) & (lum > 0)])) if np.any(lum > 0) else 1.0
        out = srgb_encode(np.nan_to_num(rgb * (0.18 / max(med, 1e-12)), posinf=1.0))
        return cv2.cvtColor(np.round(out * 255.0).astype(np.uint8), cv2.COLOR_RGB2BGR)
    img = imread(path, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)  # 16-bit PNGs come out 8-bit
    return img


def _jpeg(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 BGR
        raise InputError("could not encode a JPEG")
    return buf.tobytes()


class _LRU:
    """Thread-safe LRU cache bounded by the total ``nbytes`` of its values."""

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self.bytes = 0
        self._d: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            if key in self._d:
                self._d.move_to_end(key)
                return self._d[key]
        return None

    def put(self, key, value, size: int) -> None:
        with self._lock:
            if key in self._d:
                return
            self._d[key] = (value, size)
            self.bytes += size
            while self.bytes > self.max_bytes and len(self._d) > 1:
                _, (_, s) = self._d.popitem(last=False)
                self.bytes -= s

    def value(self, key):
        hit = self.get(key)
        return None if hit is None else hit[0]


class ImageService:
    """Previews, tiles and crops of :class:`ImageRef` images, cached in memory.

    Parameters
    ----------
    max_decoded_bytes : int
        Budget for decoded full-resolution images (a 7296x3648 RGB image is 80 MB).
    max_encoded_bytes : int
        Budget for encoded JPEG responses (previews, tiles, crops).
    """

    def __init__(self, max_decoded_bytes: int = 320 << 20, max_encoded_bytes: int = 96 << 20):
        self._decoded = _LRU(max_decoded_bytes)
        self._encoded = _LRU(max_encoded_bytes)
        self._sizes: dict[str, tuple[int, int]] = {}
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()

    def _lock(self, ref: ImageRef) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(ref.id, threading.Lock())

    def full(self, ref: ImageRef) -> np.ndarray:
        """The decoded display image, ``(H, W, 3)`` uint8 BGR (decoded once per cache life)."""
        img = self._decoded.value(ref.id)
        if img is None:
            with self._lock(ref):  # one decode per image even when many tiles ask at once
                img = self._decoded.value(ref.id)
                if img is None:
                    img = _to_display8(ref.path, ref.hdr)
                    self._decoded.put(ref.id, img, img.nbytes)
                    self._sizes[ref.id] = (img.shape[1], img.shape[0])
        return img

    def size(self, ref: ImageRef) -> tuple[int, int]:
        """``(width, height)`` in pixels (read from the header when possible)."""
        if ref.id not in self._sizes:
            if not ref.hdr:
                from PIL import Image  # header only; no decode

                try:
                    with Image.open(ref.path) as im:
                        self._sizes[ref.id] = im.size
                except OSError as exc:
                    raise InputError(f"{ref.path}: not a readable image ({exc})") from None
            else:
                self.full(ref)
        return self._sizes[ref.id]

    def _cached(self, key: tuple, make) -> bytes:
        data = self._encoded.value(key)
        if data is None:
            data = make()
            self._encoded.put(key, data, len(data))
        return data

    def preview(self, ref: ImageRef, max_width: int = PREVIEW_WIDTH) -> bytes:
        """JPEG at most ``max_width`` px wide (the whole image, aspect kept)."""

        def make() -> bytes:
            img = self.full(ref)
            h, w = img.shape[:2]
            if w > max_width:
                img = cv2.resize(img, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)
            return _jpeg(img)

        return self._cached((ref.id, "preview", max_width), make)

    def tile(self, ref: ImageRef, col: int, row: int) -> bytes:
        """JPEG of tile ``(col, row)`` of :func:`tile_grid` at full resolution."""
        w, h = self.size(ref)
        cols, rows = tile_grid(w)
        if not (0 <= col < cols and 0 <= row < rows):
            raise KeyError((col, row))

        def make() -> bytes:
            x0, y0, x1, y1 = tile_box(w, h, cols, rows, col, row)
            return _jpeg(self.full(ref)[y0:y1, x0:x1])

        return self._cached((ref.id, "tile", col, row), make)

    def crop(
        self, ref: ImageRef, x: float, y: float, cw: float, ch: float, out_width: int
    ) -> tuple[bytes, tuple[int, int, int, int]]:
        """JPEG of the region ``[x, x+cw) x [y, y+ch)`` (full-res px, clamped to the image),
        resized to at most ``out_width`` px wide (never enlarged); returns it and the box used."""
        w, h = self.size(ref)
        x0, y0 = max(0, math.floor(x)), max(0, math.floor(y))
        x1, y1 = min(w, math.ceil(x + cw)), min(h, math.ceil(y + ch))
        if x1 <= x0 or y1 <= y0:
            raise KeyError("empty crop")
        out_width = max(16, min(int(out_width), MAX_CROP_OUT, x1 - x0))
        box = (x0, y0, x1, y1)

        def make() -> bytes:
            img = self.full(ref)[y0:y1, x0:x1]
            if out_width < x1 - x0:
                img = cv2.resize(
                    img, (out_width, max(1, round((y1 - y0) * out_width / (x1 - x0)))), interpolation=cv2.INTER_AREA
                )
            return _jpeg(img)

        return self._cached((ref.id, "crop", box, out_width), make), box
