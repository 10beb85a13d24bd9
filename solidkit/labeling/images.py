"""Pixels for the labeling app: downscaled previews, panorama tiles and full-resolution crops.

A 7296x3648 panorama is never sent whole: the browser gets a preview (at most
:data:`PREVIEW_WIDTH` wide) and then only the tiles (equirect panoramas) or crops (photos) it
looks at closely. Previews and tiles are encoded once and kept on disk (``cache_dir``, by
default ``CAMPAIGN/labels/image-cache/<image id>/``; the id changes with the file, so a stale
copy is never served), so a restarted server sends them without decoding anything; crops are
kept in a small in-memory cache. Decoded full-resolution images are kept in a least-recently-used
cache bounded in bytes. An image's size is read from its header
(:func:`solidkit.envmap.io.image_size`), never by decoding it; an EXR is decoded in strips of scanlines
straight to 8-bit, so a 7296x3648 HDR never exists as a float image in memory (about 200 MB at peak instead of 2 GB).

Display encoding: LDR files are shown as stored (sRGB); HDR (EXR) products are exposed so that
their median luminance (estimated from one block of scanlines in eight) maps to 18 % grey, then
encoded with the sRGB power curve (the linear toe near black is left out: at most 4 of 255 grey
levels in the deepest shadows); the browser's exposure slider works on top of that.
"""

from __future__ import annotations

import math
import os
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from solidkit.envmap.io import image_size, imread
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


_STRIP = 128  # EXR scanlines decoded at once: 7296 x 128 x 3 float32 = 11 MB


def _exr_display8(path: Path) -> np.ndarray:
    """An EXR exposed for display as uint8 BGR ``(H, W, 3)``, decoded strip by strip."""
    import Imath
    import OpenEXR

    try:
        f = OpenEXR.InputFile(str(path))
        header = f.header()
        dw = header["dataWindow"]
        w, h, y_min = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1, dw.min.y
        names = sorted(header["channels"])
        bgr = "BGR" if all(c in names for c in "RGB") else (names[0],) * 3 if len(names) == 1 else None
        if bgr is None:
            raise InputError(f"{path}: EXR has channels {names}; expected RGB, RGBA or one channel")
        FLOAT = Imath.PixelType(Imath.PixelType.FLOAT)

        def strip(y0: int, y1: int) -> list[np.ndarray]:
            return [np.frombuffer(c, np.float32).reshape(y1 - y0, w) for c in f.channels(list(bgr), FLOAT,
                    y_min + y0, y_min + y1 - 1)]  # fmt: skip

        lum = []  # the median from one block of 16 scanlines in eight (ZIP's block: one decode each)
        for y0 in range(0, h, 8 * 16):
            b, g, r = strip(y0, min(h, y0 + 16))
            lum.append((LUMINANCE_WEIGHTS[0] * r + LUMINANCE_WEIGHTS[1] * g + LUMINANCE_WEIGHTS[2] * b)[:, ::3])
        vals = np.concatenate([v.ravel() for v in lum])
        vals = vals[np.isfinite(vals) & (vals > 0)]
        med = float(np.median(vals)) if vals.size else 1.0
        gain = (0.18 / max(med, 1e-12)) ** (1 / 2.4)
        hi = (4.0 / gain) ** 2.4  # well above white, well below what overflows the 8-bit conversion
        out = np.empty((h, w, 3), np.uint8)
        for y0 in range(0, h, _STRIP):
            y1 = min(h, y0 + _STRIP)
            x = cv2.merge(strip(y0, y1))
            cv2.patchNaNs(x, 0.0)  # in place (numpy's nan_to_num took a third of the time); +inf clipped, shown white
            x = cv2.pow(np.clip(x, 0.0, hi, out=x), 1 / 2.4)
            out[y0:y1] = cv2.addWeighted(x, 255 * 1.055 * gain, x, 0.0, -0.055 * 255, dtype=cv2.CV_8U)
        f.close()
    except InputError:
        raise
    except Exception as exc:  # OpenEXR raises plain errors on corrupt data
        raise InputError(f"{path}: not a readable EXR file ({exc})") from None
    return out


def _to_display8(path: Path, hdr: bool) -> np.ndarray:
    """Decode to uint8 BGR for display (EXIF orientation ignored: pixels as stored, like K)."""
    if hdr:
        return _exr_display8(path)
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
        Budget for encoded JPEG responses kept in memory (previews, tiles, crops).
    cache_dir : Path, optional
        Folder for encoded previews and tiles (one subfolder per image id); None: memory only.
    """

    def __init__(
        self, max_decoded_bytes: int = 160 << 20, max_encoded_bytes: int = 64 << 20, cache_dir: Path | None = None
    ):
        self._decoded = _LRU(max_decoded_bytes)
        self._encoded = _LRU(max_encoded_bytes)
        self.cache_dir = cache_dir
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
            size = image_size(ref.path)
            if size is None:
                raise InputError(f"{ref.path}: not a readable image (no width and height in its header)")
            self._sizes[ref.id] = size
        return self._sizes[ref.id]

    def _cached(self, key: tuple, make, disk: str | None = None) -> bytes:
        data = self._encoded.value(key)
        if data is not None:
            return data
        path = self.cache_dir / key[0] / disk if self.cache_dir is not None and disk else None
        if path is not None and path.is_file():
            data = path.read_bytes()
        else:
            data = make()
            if path is not None:
                _write_atomic(path, data)
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

        return self._cached((ref.id, "preview", max_width), make, f"preview-{max_width}.jpg")

    def tile(self, ref: ImageRef, col: int, row: int) -> bytes:
        """JPEG of tile ``(col, row)`` of :func:`tile_grid` at full resolution."""
        w, h = self.size(ref)
        cols, rows = tile_grid(w)
        if not (0 <= col < cols and 0 <= row < rows):
            raise KeyError((col, row))

        def make() -> bytes:
            x0, y0, x1, y1 = tile_box(w, h, cols, rows, col, row)
            return _jpeg(self.full(ref)[y0:y1, x0:x1])

        return self._cached((ref.id, "tile", col, row), make, f"tile-{cols}x{rows}-{col}-{row}.jpg")

    def cached_on_disk(self, ref: ImageRef) -> bool:
        """The preview and (equirect) every tile of ``ref`` are in the disk cache."""
        if self.cache_dir is None:
            return False
        folder = self.cache_dir / ref.id
        if not (folder / f"preview-{PREVIEW_WIDTH}.jpg").is_file():
            return False
        if ref.layout != "equirect":
            return True
        cols, rows = tile_grid(self.size(ref)[0])
        return all((folder / f"tile-{cols}x{rows}-{c}-{r}.jpg").is_file() for r in range(rows) for c in range(cols))

    def warm(self, refs: list[ImageRef], stop: threading.Event | None = None) -> int:
        """Make the previews and tiles of ``refs`` in turn (those not on disk yet), so that first views
        come from the disk cache; returns how many images were made. Meant for a background thread."""
        made = 0
        for ref in refs:
            if self.cache_dir is None or (stop is not None and stop.is_set()):
                break
            try:
                if self.cached_on_disk(ref):
                    continue
                self.preview(ref)
                if ref.layout == "equirect":
                    cols, rows = tile_grid(self.size(ref)[0])
                    for r in range(rows):
                        for c in range(cols):
                            self.tile(ref, c, r)
                made += 1
            except InputError:
                continue
        return made

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


def _write_atomic(path: Path, data: bytes) -> None:
    """Write a cache file so that a reader never sees half of it (a failure only loses the cache)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".part")
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except OSError:
        pass
