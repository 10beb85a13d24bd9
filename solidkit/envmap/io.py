"""Panorama I/O: HDR EXR (OpenEXR 3.x) with header attributes, sRGB LDR, validation, tonemap.

Conventions §5: HDR is linear float32 in memory and EXR on disk; LDR is sRGB-encoded 8-bit.
All EXR I/O goes through OpenEXR: opencv-contrib 5.x has no EXR codec.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import struct
import warnings
from pathlib import Path
from typing import Any, BinaryIO, cast

import cv2
import numpy as np

from solidkit.envmap.coords import CONVENTIONS_VERSION, namespace
from solidkit.errors import InputError, InputWarning, LibraryOutput, PanoramaError, library_output
from solidkit.fsutil import atomic_path, errno_from_message, free_bytes, jpeg_truncated

__all__ = [
    "PAPER_EXPOSURE",
    "PAPER_GAMMA",
    "read_exr",
    "read_hdr",
    "read_panorama",
    "write_exr",
    "read_ldr",
    "write_ldr",
    "read_image",
    "image_size",
    "check_image_size",
    "jpeg_damage",
    "MAX_IMAGE_PIXELS",
    "validate_panorama",
    "tonemap",
    "inverse_tonemap",
    "srgb_encode",
    "srgb_decode",
    "decode_ldr",
]

PAPER_EXPOSURE = -0.3
PAPER_GAMMA = 2.2
LDR_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp"}
_META_KEY = "solidkit"


def read_exr(path: str | os.PathLike[str]) -> tuple[np.ndarray, dict[str, Any]]:
    """Read an EXR image as float32.

    Returns
    -------
    image : ndarray (H, W, C) float32
        RGB (C=3), RGBA (C=4) or a single channel (C=1), channels in that order.
    meta : dict
        The solidkit attributes written by :func:`write_exr` (e.g. ``exposure_time``,
        ``provenance``) plus ``"header"``: the raw OpenEXR header.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> path = write_exr(folder / 'sky.exr', np.full((2, 4, 3), 0.5, np.float32), {'note': 'a test'})
    >>> image, meta = read_exr(path)
    >>> image.shape, image.dtype, meta['note']
    ((2, 4, 3), dtype('float32'), 'a test')
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    import OpenEXR  # imported on use: commands that never touch EXR start faster

    check_image_size(path)
    printed = io.StringIO()  # the bindings print their warnings on sys.stdout, the C++ core on fd 2
    try:
        with library_output() as said, contextlib.redirect_stdout(printed):
            with OpenEXR.File(str(path)) as f:
                header = dict(f.header())
                channels = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:  # OpenEXR raises plain RuntimeError/TypeError on corrupt data
        why = str(exc)
        # a part whose pixels failed to read is dropped, and the bindings then report "file has 0 parts"
        if "has 0 parts" in why:
            warned = " ".join(printed.getvalue().split()).removeprefix("Warning: ")[:200]
            why = said.summary().replace(f"{path}: ", "") or warned or "corrupt pixel data"
        raise InputError(f"{path}: not a readable EXR file ({why})") from None
    if "RGBA" in channels:
        img = channels["RGBA"]
    elif "RGB" in channels:
        img = channels["RGB"]
    elif len(channels) == 1:
        img = next(iter(channels.values()))[..., None]
    else:
        raise InputError(f"{path}: EXR has channels {sorted(channels)}; expected RGB, RGBA or one channel")
    meta: dict[str, Any] = {}
    if _META_KEY in header:
        try:
            meta = json.loads(header[_META_KEY])
        except (TypeError, ValueError):
            meta = {}
    meta["header"] = header
    return np.ascontiguousarray(img, dtype=np.float32), meta


def read_hdr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Radiance RGBE file (``.hdr``, ``.pic``) as linear RGB float32 ``(H, W, 3)``.

    Reference: G. Ward, "Real Pixels", Graphics Gems II (1991): the RGBE encoding, decoded by OpenCV's
    Radiance codec. Values are as stored (the publisher's scale, not absolute radiance).

    Examples
    --------
    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / 'sky.hdr'
    >>> rgb = np.zeros((2, 4, 3), np.float32); rgb[..., 0] = 2.0; rgb[..., 2] = 0.5
    >>> _ = cv2.imwrite(str(path), rgb[..., ::-1].copy())
    >>> read_hdr(path)[0, 0]  # red stays red: OpenCV's BGR is turned to RGB
    array([2. , 0. , 0.5], dtype=float32)
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    with open(path, "rb") as f:
        magic = f.read(10)
    if not (magic.startswith(b"#?RADIANCE") or magic.startswith(b"#?RGBE")):
        raise InputError(f"{path}: not a Radiance HDR file (no '#?RADIANCE' signature)")
    check_image_size(path)
    with library_output() as said:
        try:
            img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
        except cv2.error as exc:
            img, said.text = None, str(exc).strip().splitlines()[-1]
    if img is None or img.ndim != 3:
        why = said.summary()
        raise InputError(f"{path}: not a readable Radiance HDR file" + (f" ({why})" if why else ""))
    return np.ascontiguousarray(img[..., ::-1], dtype=np.float32)


HDR_SUFFIXES = {".exr", ".hdr", ".pic"}


def read_panorama(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a linear HDR panorama (EXR or Radiance HDR) as RGB float32 ``(H, W, 3)``, negatives and
    non-finite values set to 0; refuses an image that is not ``(H, 2H)``.

    Examples
    --------
    >>> import tempfile
    >>> sky = np.full((4, 8, 3), 0.5, np.float32); sky[0, 0] = -1.0
    >>> path = write_exr(Path(tempfile.mkdtemp()) / 'sky.exr', sky)
    >>> float(read_panorama(path).min()), read_panorama(path).shape
    (0.0, (4, 8, 3))
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        img, _ = read_exr(path)
        img = np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img[..., :3]
    elif suffix in (".hdr", ".pic"):
        img = read_hdr(path)
    else:
        raise InputError(f"{path}: unknown HDR panorama type '{path.suffix}' (expected .exr or .hdr)")
    validate_panorama(np.nan_to_num(img), path.name)
    return cast(np.ndarray, np.clip(np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0), 0.0, None).astype(np.float32))


def write_exr(
    path: str | os.PathLike[str],
    image: np.ndarray,
    meta: dict[str, Any] | None = None,
    *,
    half: bool = False,
) -> Path:
    """Write ``image (H, W, C)`` (C in 1, 3, 4) to EXR atomically.

    ``meta`` (JSON-serialisable: exposure time in seconds, provenance, ...) is stored in a
    ``solidkit`` string attribute together with the conventions version. ``half=True`` stores
    16-bit floats (values above 65504 become inf: refused).

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> path = write_exr(folder / 'sky.exr', np.ones((2, 4, 3), np.float32) * 1e4, {'exposure_time': 0.001})
    >>> float(read_exr(path)[0].max()), read_exr(path)[1]['exposure_time']
    (10000.0, 0.001)
    """
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[2] not in (1, 3, 4):
        raise InputError(f"cannot write image of shape {image.shape} as EXR")
    dtype = np.float16 if half else np.float32
    if half and np.nanmax(np.abs(image)) > np.finfo(np.float16).max:
        raise InputError("values exceed the half-float range; write with half=False")
    data = np.ascontiguousarray(image.astype(dtype))
    names = {1: "Y", 3: "RGB", 4: "RGBA"}[data.shape[2]]
    channels = {names: data if data.shape[2] > 1 else data[..., 0]}
    attrs = dict(meta or {})
    attrs.setdefault("conventions_version", CONVENTIONS_VERSION)
    import OpenEXR

    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        _META_KEY: json.dumps(attrs, sort_keys=True, default=str),
    }
    path = Path(path)
    with atomic_path(path, suffix=".exr") as tmp:
        try:
            with OpenEXR.File(header, channels) as f:
                f.write(str(tmp))
        except RuntimeError as exc:  # OpenEXR's write errors (disk full, I/O) name the temporary file
            raise _write_failed(errno_from_message(str(exc)), data.nbytes) from exc  # uncompressed size
    return path


def decode_ldr(ldr: np.ndarray, encoding: str | np.ndarray = "srgb") -> np.ndarray:
    """Relative linear values ``(H, W, 3)`` float32 behind an LDR image ``(H, W, 3)`` in [0, 1].

    ``encoding``: ``"srgb"`` (:func:`srgb_decode`: a camera's JPEG, display-referred sRGB),
    ``"paper"`` (:func:`inverse_tonemap`: an image made by the paper's tonemap, as rendered training
    crops are), or an inverse camera response ``(256, 3)`` (``curve[code, channel]``, e.g. from
    ``solidkit calibrate response``), looked up at each pixel's nearest 8-bit code. Only ratios
    between the values are meaningful (clipped pixels stay at the clip level).

    Examples
    --------
    >>> x = np.full((1, 1, 3), 0.5, np.float32)
    >>> [round(float(decode_ldr(x, e)[0, 0, 0]), 4) for e in ("srgb", "paper")]
    [0.214, 0.2679]
    >>> curve = np.repeat(np.linspace(0.0, 2.0, 256)[:, None], 3, axis=1)
    >>> round(float(decode_ldr(x, curve)[0, 0, 0]), 4)  # code 128 of a linear curve
    1.0039
    """
    x = np.clip(np.asarray(ldr, dtype=np.float32), 0.0, 1.0)
    if isinstance(encoding, str):
        if encoding == "srgb":
            return np.asarray(srgb_decode(x), dtype=np.float32)
        if encoding == "paper":
            return np.asarray(inverse_tonemap(x), dtype=np.float32)
        raise InputError(f"unknown LDR encoding {encoding!r} (expected 'srgb', 'paper' or a (256, 3) curve)")
    curve = np.asarray(encoding, dtype=np.float32)
    if curve.shape != (256, 3) or not np.isfinite(curve).all() or (curve < 0).any():
        raise InputError(f"an inverse response curve must be (256, 3), finite and >= 0; got shape {curve.shape}")
    codes = np.rint(x[..., :3] * 255.0).astype(np.intp)
    return np.take_along_axis(curve, codes.reshape(-1, 3), axis=0).reshape(codes.shape)


def _write_failed(code: int | None, needed: int | None) -> OSError:
    """The ``OSError`` of a library writer that failed (``code`` None: an I/O error), for
    :func:`~solidkit.fsutil.atomic_path` to name the final file and the space it needs."""
    code = errno.EIO if code is None else code
    err = OSError(code, os.strerror(code))
    err.needed_bytes = needed  # type: ignore[attr-defined]
    return err


def srgb_encode(linear: Any) -> Any:
    """IEC 61966-2-1 sRGB encoding of linear values in [0, 1] (NumPy or torch).

    Examples
    --------
    >>> np.round(srgb_encode(np.array([0.0, 0.0031308, 0.214, 1.0])), 6)
    array([0.      , 0.04045 , 0.499956, 1.      ])
    """
    xp = namespace(linear)
    x = xp.clip(linear, 0.0, 1.0)
    return xp.where(x <= 0.0031308, 12.92 * x, 1.055 * xp.clip(x, 0.0031308, 1.0) ** (1 / 2.4) - 0.055)


def srgb_decode(encoded: Any) -> Any:
    """Inverse of :func:`srgb_encode`.

    Examples
    --------
    >>> x = np.linspace(0.0, 1.0, 5)
    >>> bool(np.allclose(srgb_decode(srgb_encode(x)), x))
    True
    """
    xp = namespace(encoded)
    x = xp.clip(encoded, 0.0, 1.0)
    return xp.where(x <= 0.04045, x / 12.92, ((xp.clip(x, 0.04045, 1.0) + 0.055) / 1.055) ** 2.4)


def tonemap(hdr: Any, exposure: float = PAPER_EXPOSURE, gamma: float = PAPER_GAMMA) -> Any:
    """The paper's tonemap ``clip((2^e * H)^(1/gamma), 0, 1)`` (§4.3, L_tom); NumPy or torch.

    Negative inputs map to 0; the result is differentiable where ``0 < 2^e H < 1``.

    Examples
    --------
    >>> np.round(tonemap(np.array([0.0, 1.0, 10.0])), 6)
    array([0.      , 0.909809, 1.      ])
    """
    xp = namespace(hdr)
    scaled = xp.clip(hdr * (2.0**exposure), 1e-12, None)
    return xp.clip(scaled ** (1.0 / gamma), 0.0, 1.0) * (hdr > 0)


def inverse_tonemap(ldr: Any, exposure: float = PAPER_EXPOSURE, gamma: float = PAPER_GAMMA) -> Any:
    """The radiance behind an LDR image under :func:`tonemap`: ``clip(T, 0, 1)^gamma / 2^e``; NumPy or torch.

    Exact below saturation; a clipped pixel (``T = 1``) gives the clip level ``2^-e``.

    Examples
    --------
    >>> np.round(inverse_tonemap(tonemap(np.array([0.0, 0.5, 1.0]))), 6)
    array([0. , 0.5, 1. ])
    """
    xp = namespace(ldr)
    return xp.clip(ldr, 0.0, 1.0) ** gamma / (2.0**exposure)


#: The most pixels an image may have to be decoded: Pillow's decompression-bomb limit (twice its
#: ``MAX_IMAGE_PIXELS``), which ingest's decode check has always applied; 13400 x 13400, seven times a Theta X
#: frame. Checked from the file's header before any decoder allocates (:func:`check_image_size`).
MAX_IMAGE_PIXELS = 178_956_970


def _jpeg_size(f: BinaryIO) -> tuple[int, int] | None:
    f.seek(2)
    while True:
        head = f.read(2)
        if len(head) < 2 or head[0] != 0xFF:
            return None
        marker = head[1]
        if marker == 0xFF:  # fill byte
            f.seek(-1, os.SEEK_CUR)
            continue
        if marker in (0x01, *range(0xD0, 0xD9)):  # markers without a length
            continue
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no frame header before it
            return None
        length = f.read(2)
        if len(length) < 2:
            return None
        n = struct.unpack(">H", length)[0]
        if n < 2:  # a length that counts less than itself: no forward progress
            return None
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # SOFn
            sof = f.read(5)
            if len(sof) < 5:
                return None
            h, w = struct.unpack(">HH", sof[1:5])
            return w, h
        f.seek(n - 2, os.SEEK_CUR)


def _exr_size(f: BinaryIO) -> tuple[int, int] | None:
    f.seek(8)  # magic and version
    while True:
        name = _cstring(f)
        if not name:
            return None
        kind = _cstring(f)
        size_bytes = f.read(4)
        if kind is None or len(size_bytes) < 4:
            return None
        size = struct.unpack("<i", size_bytes)[0]
        if size < 0:
            return None
        if name == b"dataWindow" and kind == b"box2i" and size == 16:
            box = f.read(16)
            if len(box) < 16:
                return None
            x0, y0, x1, y1 = struct.unpack("<4i", box)
            return x1 - x0 + 1, y1 - y0 + 1
        f.seek(size, os.SEEK_CUR)


def _cstring(f: BinaryIO, limit: int = 256) -> bytes | None:
    out = bytearray()
    while len(out) <= limit:
        c = f.read(1)
        if not c:
            return None
        if c == b"\0":
            return bytes(out)
        out += c
    return None


def _tiff_size(f: BinaryIO, order: str) -> tuple[int, int] | None:
    f.seek(4)
    offset = struct.unpack(order + "I", f.read(4))[0]
    f.seek(offset)
    count = f.read(2)
    if len(count) < 2:
        return None
    sizes: dict[int, int] = {}
    for _ in range(min(struct.unpack(order + "H", count)[0], 512)):
        entry = f.read(12)
        if len(entry) < 12:
            break
        tag, typ = struct.unpack(order + "HH", entry[:4])
        if tag in (256, 257) and typ in (3, 4):
            sizes[tag] = struct.unpack(order + ("H" if typ == 3 else "I"), entry[8 : 10 if typ == 3 else 12])[0]
    return (sizes[256], sizes[257]) if len(sizes) == 2 else None


def _radiance_size(f: BinaryIO) -> tuple[int, int] | None:
    f.seek(0)
    for line in f.read(65536).split(b"\n")[1:]:
        parts = line.split()
        if len(parts) == 4 and parts[0] in (b"-Y", b"+Y") and parts[2] in (b"+X", b"-X"):
            try:
                return int(parts[3]), int(parts[1])
            except ValueError:
                return None
    return None


def image_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """``(width, height)`` in pixels as the header of a JPEG, PNG, EXR, TIFF, BMP or Radiance HDR file states it,
    read without decoding; ``None`` for other formats or a header that cannot be read.

    Examples
    --------
    >>> import tempfile
    >>> path = write_exr(Path(tempfile.mkdtemp()) / 'sky.exr', np.zeros((2, 4, 3), np.float32))
    >>> image_size(path)
    (4, 2)
    """
    try:
        with open(path, "rb") as f:
            magic = f.read(8)
            if magic[:3] == b"\xff\xd8\xff":
                return _jpeg_size(f)
            if magic == b"\x89PNG\r\n\x1a\n":
                ihdr = f.read(16)
                return struct.unpack(">II", ihdr[8:16]) if len(ihdr) == 16 and ihdr[4:8] == b"IHDR" else None
            if magic[:4] == b"\x76\x2f\x31\x01":
                return _exr_size(f)
            if magic[:4] in (b"II*\x00", b"MM\x00*"):
                return _tiff_size(f, "<" if magic[:2] == b"II" else ">")
            if magic[:2] == b"BM":
                f.seek(18)
                w, h = struct.unpack("<ii", f.read(8))
                return abs(w), abs(h)
            if magic.startswith((b"#?RADIAN", b"#?RGBE")):
                return _radiance_size(f)
    except (OSError, struct.error, ValueError):
        return None
    return None


def check_image_size(path: str | os.PathLike[str], size: tuple[int, int] | None = None) -> None:
    """Refuse (:class:`InputError`) an image whose header states no pixels or more than :data:`MAX_IMAGE_PIXELS`,
    before a decoder allocates for it; ``size``: the ``(width, height)`` already read (default :func:`image_size`).

    Examples
    --------
    >>> check_image_size('frame.jpg', (5376, 2688))  # a Theta V frame: fine
    >>> check_image_size('huge.jpg', (65500, 65500))
    Traceback (most recent call last):
        ...
    solidkit.errors.InputError: huge.jpg: the header states 65500 x 65500 pixels, more than solidkit decodes (...)
    """
    size = image_size(path) if size is None else size
    if size is None:
        return
    w, h = size
    if w <= 0 or h <= 0:
        raise InputError(f"{path}: the header states an empty image ({w} x {h} pixels)")
    if w * h > MAX_IMAGE_PIXELS:
        raise InputError(
            f"{path}: the header states {w} x {h} pixels, more than solidkit decodes ({MAX_IMAGE_PIXELS} at most)"
        )


def _damage(output: LibraryOutput) -> str:
    said = (s for s in output.lines() if s.startswith(("Corrupt JPEG data", "Premature end of JPEG")))
    return "; ".join(dict.fromkeys(said))


def _corrupt_data(path: str | os.PathLike[str], damage: str) -> None:
    """Warn (:class:`InputWarning`) when libjpeg reported corrupt data in an image it decoded anyway."""
    if damage:
        warnings.warn(f"{path}: corrupt image data, decoded with damaged blocks (libjpeg: {damage})", InputWarning, 3)


def jpeg_damage(path: str | os.PathLike[str], *, warn: bool = False) -> str:
    """What libjpeg reports as corrupt in the JPEG ``path`` (``"Corrupt JPEG data: ..."``; ``""`` for none, or for a
    file OpenCV cannot read), from a decode at 1/8 scale that still reads every entropy-coded byte: for readers
    that decode past damage without a word (Pillow). ``warn``: also an :class:`InputWarning` naming the file.

    Examples
    --------
    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / 'ok.jpg'
    >>> _ = write_ldr(path, np.full((16, 16, 3), 0.5))
    >>> jpeg_damage(path)
    ''
    """
    with library_output() as said:
        try:
            cv2.imread(str(path), cv2.IMREAD_REDUCED_GRAYSCALE_8)
        except cv2.error:
            pass
    damage = _damage(said)
    if warn:
        _corrupt_data(path, damage)
    return damage


def imread(path: str | os.PathLike[str], flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    """``cv2.imread`` that refuses missing, undecodable and truncated files with an :class:`InputError`.

    OpenCV decodes a truncated JPEG without complaint (the missing rows come out grey), hence
    :func:`solidkit.fsutil.jpeg_truncated` first, and :func:`check_image_size` before any allocation. What the
    codec libraries print goes into the error's line; corrupt JPEG data decoded anyway is an :class:`InputWarning`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if jpeg_truncated(path):
        raise InputError(f"{path}: truncated JPEG (no end-of-image marker)")
    check_image_size(path)
    with library_output() as said:
        try:
            img = cv2.imread(str(path), flags)
        except cv2.error as exc:  # e.g. a size past OpenCV's own limits in a header image_size cannot read
            img, said.text = None, str(exc).strip().splitlines()[-1]
    if img is None:
        why = said.summary()
        raise InputError(f"{path}: not a readable image" + (f" ({why})" if why else ""))
    _corrupt_data(path, _damage(said))
    return img


def read_ldr(path: str | os.PathLike[str], *, linear: bool = False) -> np.ndarray:
    """Read an 8/16-bit image as RGB float32 in [0, 1]; ``linear=True`` undoes sRGB.

    Examples
    --------
    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / 'grey.png'
    >>> _ = write_ldr(path, np.full((2, 2, 3), 0.5))
    >>> float(read_ldr(path)[0, 0, 0])  # code 128 / 255
    0.501960813999176
    >>> round(float(read_ldr(path, linear=True)[0, 0, 0]), 6)  # sRGB-decoded
    0.215861
    """
    img = imread(path)
    scale = float(np.iinfo(img.dtype).max) if np.issubdtype(img.dtype, np.integer) else 1.0
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB).astype(np.float32) / scale
    return srgb_decode(img).astype(np.float32) if linear else img


def write_ldr(path: str | os.PathLike[str], image: np.ndarray, *, encode_srgb: bool = False, quality: int = 95) -> Path:
    """Write RGB float in [0, 1] (or uint8) as 8-bit PNG/JPEG atomically.

    ``encode_srgb=True`` applies the sRGB transfer function to linear input first.

    Examples
    --------
    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / 'mid.png'
    >>> _ = write_ldr(path, np.full((2, 2, 3), 0.214, np.float32), encode_srgb=True)
    >>> int(cv2.imread(str(path))[0, 0, 0])  # linear 0.214 is sRGB 0.49996: code 127
    127
    """
    image = np.asarray(image)
    if image.dtype != np.uint8:
        x = srgb_encode(image.astype(np.float32)) if encode_srgb else np.clip(image, 0.0, 1.0)
        image = np.round(np.nan_to_num(x) * 255.0).astype(np.uint8)
    if image.ndim == 2:
        image = image[..., None]
    bgr = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2BGR) if image.shape[2] >= 3 else image
    path = Path(path)
    params = [cv2.IMWRITE_JPEG_QUALITY, quality] if path.suffix.lower() in (".jpg", ".jpeg") else []
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), bgr, params):
            if not cv2.haveImageWriter(str(path)):
                raise InputError(f"{path}: OpenCV could not write this format")
            # a codec that writes this format failed (libpng's "Write Error"): the disk, not the image
            ok, encoded = cv2.imencode(path.suffix, bgr, params)
            needed = int(encoded.nbytes) if ok else None
            free = free_bytes(tmp.parent)
            full = needed is not None and free is not None and free < needed + 65536
            raise _write_failed(errno.ENOSPC if full else None, needed)
    return path


def read_image(path: str | os.PathLike[str]) -> tuple[np.ndarray, dict[str, Any]]:
    """Read an EXR (linear HDR) or an LDR file (sRGB decoded to linear); ``(H, W, 3)`` float32.

    Examples
    --------
    >>> import tempfile
    >>> path = write_exr(Path(tempfile.mkdtemp()) / 'p.exr', np.ones((4, 8, 1), np.float32))
    >>> image, meta = read_image(path)
    >>> image.shape  # one channel repeated to RGB
    (4, 8, 3)
    """
    path = Path(path)
    if path.suffix.lower() == ".exr":
        img, meta = read_exr(path)
        if img.shape[2] == 1:
            img = np.repeat(img, 3, axis=2)
        return img[..., :3], meta
    if path.suffix.lower() in (".hdr", ".pic"):
        return read_hdr(path), {}
    if path.suffix.lower() in LDR_SUFFIXES:
        return read_ldr(path, linear=True), {"ldr": True}
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not an image file")
    raise InputError(f"{path}: unknown image type '{path.suffix}' (expected .exr, .hdr or an LDR format)")


def validate_panorama(image: np.ndarray, name: str = "panorama") -> np.ndarray:
    """Check an equirectangular panorama: ``(H, 2H, C)``, finite; returns it unchanged.

    Raises :class:`~solidkit.errors.PanoramaError` with a one-line reason otherwise.

    Examples
    --------
    >>> validate_panorama(np.zeros((4, 8, 3))).shape
    (4, 8, 3)
    >>> validate_panorama(np.zeros((4, 6, 3)), 'photo.exr')
    Traceback (most recent call last):
        ...
    solidkit.errors.PanoramaError: photo.exr: not an equirectangular panorama: 6x4 (width must be 2 x height)
    """
    if image.ndim != 3:
        raise PanoramaError(f"{name}: expected an (H, W, C) image, got shape {image.shape}")
    h, w = image.shape[:2]
    if w != 2 * h:
        raise PanoramaError(f"{name}: not an equirectangular panorama: {w}x{h} (width must be 2 x height)")
    bad = ~np.isfinite(image)
    if bad.any():
        n = int(bad.any(axis=-1).sum())
        raise PanoramaError(f"{name}: {n} pixel(s) are NaN or Inf")
    return image
