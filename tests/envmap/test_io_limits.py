"""Image readers and hostile headers: sizes checked before decoding, what codec libraries print kept in the one
error line (or an :class:`~solidkit.errors.InputWarning` naming the file), never on the terminal."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.envmap.io import MAX_IMAGE_PIXELS, image_size, imread, read_exr, write_exr
from solidkit.errors import InputError, InputWarning


def jpeg_bytes(h: int = 48, w: int = 64) -> bytes:
    img = (np.random.default_rng(0).random((h, w, 3)) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    return buf.tobytes()


def huge_jpeg(side: int = 65500) -> bytes:
    """A small JPEG whose frame header claims ``side x side`` pixels."""
    b = bytearray(jpeg_bytes())
    sof = b.find(b"\xff\xc0")
    b[sof + 5 : sof + 9] = struct.pack(">HH", side, side)
    return bytes(b)


def corrupt_jpeg() -> bytes:
    """One bit of the scan data flipped: Pillow decodes it without a word, libjpeg decodes it and prints
    "Corrupt JPEG data: ... extraneous bytes before marker 0xd9"."""
    b = bytearray(jpeg_bytes(64, 128))
    b[b.find(b"\xff\xda") + 20] ^= 0x80
    return bytes(b)


def bad_crc_png(path: Path) -> Path:
    cv2.imwrite(str(path), np.full((8, 8, 3), 100, np.uint8))
    b = bytearray(path.read_bytes())
    idat = b.find(b"IDAT")
    b[idat + 6] ^= 0xFF  # the compressed data, not its CRC
    path.write_bytes(bytes(b))
    return path


def bad_chunk_exr(path: Path) -> Path:
    """An EXR whose first chunk claims a packed size past the chunk's (OpenEXR: 'file has 0 parts')."""
    write_exr(path, (np.random.default_rng(0).random((32, 64, 3)) * 2).astype(np.float32))
    b = bytearray(path.read_bytes())
    pos = 8
    while b[pos] != 0:  # header attributes: name\0 type\0 size value
        end = b.index(0, b.index(0, pos) + 1)
        pos = end + 5 + struct.unpack("<i", b[end + 1 : end + 5])[0]
    chunk = struct.unpack("<Q", b[pos + 1 : pos + 9])[0]
    b[chunk + 4 : chunk + 8] = struct.pack("<i", 99999)
    path.write_bytes(bytes(b))
    return path


def test_image_size_from_headers(tmp_path: Path) -> None:
    img = np.zeros((6, 10, 3), np.uint8)
    for suffix in (".jpg", ".png", ".tif", ".bmp"):
        cv2.imwrite(str(tmp_path / f"a{suffix}"), img)
        assert image_size(tmp_path / f"a{suffix}") == (10, 6), suffix
    cv2.imwrite(str(tmp_path / "a.hdr"), img.astype(np.float32))
    assert image_size(tmp_path / "a.hdr") == (10, 6)
    assert image_size(write_exr(tmp_path / "a.exr", img.astype(np.float32))) == (10, 6)
    (tmp_path / "huge.jpg").write_bytes(huge_jpeg())
    assert image_size(tmp_path / "huge.jpg") == (65500, 65500)
    (tmp_path / "text.jpg").write_text("hello")
    assert image_size(tmp_path / "text.jpg") is None
    for length in (0, 1):  # a segment length that does not move the reader on
        (tmp_path / "stuck.jpg").write_bytes(b"\xff\xd8\xff\xe1" + length.to_bytes(2, "big") + jpeg_bytes()[2:])
        assert image_size(tmp_path / "stuck.jpg") is None


def test_a_header_past_the_limit_is_refused_before_decoding(tmp_path: Path, capfd) -> None:
    (tmp_path / "huge.jpg").write_bytes(huge_jpeg())
    with pytest.raises(InputError, match=r"huge.jpg: the header states 65500 x 65500 pixels, more than solidkit"):
        imread(tmp_path / "huge.jpg")  # OpenCV's own limit raised cv2.error (exit 1 "internal error") before
    side = int(MAX_IMAGE_PIXELS**0.5) + 1
    (tmp_path / "big.jpg").write_bytes(huge_jpeg(side))
    with pytest.raises(InputError, match="the header states"):
        imread(tmp_path / "big.jpg")
    assert capfd.readouterr().err == ""


def test_corrupt_jpeg_data_is_a_warning_naming_the_file(tmp_path: Path, capfd) -> None:
    path = tmp_path / "corrupt.jpg"
    path.write_bytes(corrupt_jpeg())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        img = imread(path)
    assert img.shape == (64, 128, 3)
    assert [w.category for w in caught] == [InputWarning]
    assert str(caught[0].message).startswith(f"{path}: corrupt image data, decoded with damaged blocks (libjpeg: ")
    assert "Corrupt JPEG data" not in capfd.readouterr().err  # libjpeg's own line used to reach the terminal


def test_libpng_error_goes_into_the_one_line(tmp_path: Path, capfd) -> None:
    path = bad_crc_png(tmp_path / "bad.png")
    with pytest.raises(InputError, match=r"bad.png: not a readable image \(libpng error: IDAT: "):
        imread(path)
    assert capfd.readouterr().err == ""


def test_corrupt_exr_chunk_says_what_openexr_found(tmp_path: Path, capfd) -> None:
    path = bad_chunk_exr(tmp_path / "bad.exr")
    with pytest.raises(InputError) as info:
        read_exr(path)
    message = str(info.value)
    assert message.startswith(f"{path}: not a readable EXR file (") and "EXR_ERR_BAD_CHUNK_LEADER" in message
    assert "0 parts" not in message  # the bindings' misleading summary
    out = capfd.readouterr()
    assert out.err == "" and out.out == ""  # OpenEXR's "Warning: Exception raised ..." went to stdout before
