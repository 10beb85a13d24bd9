"""Pixels for the labeling app: an EXR's size from its header, its display encoding decoded in
strips, previews and tiles kept on disk."""

from __future__ import annotations

import numpy as np
import pytest

from solidkit.envmap.io import write_exr
from solidkit.errors import InputError
from solidkit.labeling.images import ImageRef, ImageService, tile_grid


def test_exr_display_encoding_and_size_from_the_header(tmp_path):
    img = np.full((300, 600, 3), 0.2, np.float32)  # 300 rows: strips of 128 and a remainder
    img[0, 0], img[0, 1], img[0, 2], img[0, 3] = np.nan, np.inf, -np.inf, -1.0
    img[299, 599] = (4.0, 0.0, 0.0)  # red, in the last strip
    write_exr(tmp_path / "a.exr", img)
    svc = ImageService(cache_dir=tmp_path / "cache")
    ref = ImageRef(id="img-0000000000000001", path=tmp_path / "a.exr", layout="equirect", hdr=True)
    assert svc.size(ref) == (600, 300)
    full = svc.full(ref)
    assert full.shape == (300, 600, 3) and full.dtype == np.uint8
    grey = round((1.055 * 0.18 ** (1 / 2.4) - 0.055) * 255)  # the median exposed to 18 % grey, sRGB-encoded
    assert abs(int(full[150, 300, 0]) - grey) <= 1
    assert full[0, 0].tolist() == [0, 0, 0] and full[0, 1].tolist() == [255, 255, 255]  # NaN black, +inf white
    assert full[0, 2].tolist() == [0, 0, 0] and full[0, 3].tolist() == [0, 0, 0]
    assert full[299, 599].tolist() == [0, 0, 255]  # BGR


def test_previews_and_tiles_come_from_the_disk_cache(tmp_path):
    img = np.random.default_rng(0).random((256, 512, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", img)
    ref = ImageRef(id="img-0000000000000002", path=tmp_path / "a.exr", layout="equirect", hdr=True)
    first = ImageService(cache_dir=tmp_path / "cache")
    assert first.warm([ref]) == 1 and first.cached_on_disk(ref)
    preview, tile = first.preview(ref), first.tile(ref, 1, 0)
    assert first.warm([ref]) == 0  # nothing left to make
    size = first.size(ref)
    (tmp_path / "a.exr").unlink()  # a restarted server: the cached JPEGs are sent without the source
    again = ImageService(cache_dir=tmp_path / "cache")
    again._sizes[ref.id] = size
    assert again.preview(ref) == preview and again.tile(ref, 1, 0) == tile
    assert tile_grid(size[0]) == (2, 1)
    with pytest.raises(InputError, match="a.exr"):
        ImageService(cache_dir=tmp_path / "elsewhere").preview(ref)  # and without it nothing to decode
