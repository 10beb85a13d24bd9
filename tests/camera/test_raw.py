"""Linear DNG decoding against the raw mosaic itself (black level, white level, WB, no gamma)."""

from __future__ import annotations

import numpy as np
import pytest

from solidkit.camera.raw import read_raw
from solidkit.capture.frame_merge import load_frame
from solidkit.errors import InputError


@pytest.fixture
def dng(real_data):
    p = real_data / "raw_dng" / "colorchart.dng"
    if not p.is_file():
        pytest.skip("colorchart.dng absent")
    return p


def mosaic_means(path):
    """Per-CFA-colour mean of (raw - black) / (white - black), straight from the mosaic."""
    import rawpy

    with rawpy.imread(str(path)) as r:
        vis = r.raw_image_visible.astype(np.float64)
        cols = r.raw_colors_visible
        black = np.asarray(r.black_level_per_channel, float)[cols]
        lev = (vis - black) / (r.white_level - black)
        return np.array([lev[cols == 0].mean(), lev[(cols == 1) | (cols == 3)].mean(), lev[cols == 2].mean()])


@pytest.mark.real
def test_dng_is_linear_black_subtracted_and_white_normalised(dng):
    img = read_raw(dng, wb="none", color="camera")
    assert img.linear.dtype == np.float32 and img.linear.shape == (1156, 1734, 3)
    assert img.black_level == [2056.0] * 4 and img.white_level == 15000.0
    # demosaicing preserves channel means: equal to the mosaic's normalised means (no gamma, no
    # auto-brightening, no per-file maximum adjustment)
    np.testing.assert_allclose(img.linear.reshape(-1, 3).mean(0), mosaic_means(dng), rtol=0.01)
    assert not img.saturated.any()  # this file peaks at 12128 < 15000


@pytest.mark.real
def test_dng_white_balance(dng):
    none = read_raw(dng, wb="none", color="camera").linear.reshape(-1, 3).mean(0)
    cam = read_raw(dng, wb="camera", color="camera")
    fixed = read_raw(dng, wb=(2.0, 1.0, 0.5), color="camera").linear.reshape(-1, 3).mean(0)
    assert cam.wb[1] == 1.0 and cam.wb[0] > 1.5  # as-shot neutral of a tungsten-ish scene
    np.testing.assert_allclose(cam.linear.reshape(-1, 3).mean(0) / none, cam.wb, rtol=0.01)
    np.testing.assert_allclose(fixed / none, [2.0, 1.0, 0.5], rtol=0.01)
    srgb = read_raw(dng, wb="camera", color="srgb")
    assert srgb.linear.shape == cam.linear.shape and srgb.color == "srgb"


@pytest.mark.real
def test_dng_as_merge_frame_and_errors(dng, tmp_path):
    f = load_frame(dng, 0.01)
    assert f.is_raw and f.exposure == 0.01
    bad = tmp_path / "broken.dng"
    bad.write_bytes(dng.read_bytes()[:5000])
    with pytest.raises(InputError):
        read_raw(bad)
    with pytest.raises(InputError, match="white-balance"):
        read_raw(dng, wb=(1.0, 0.0, 1.0))
