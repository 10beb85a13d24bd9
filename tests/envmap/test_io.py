"""EXR/LDR I/O, validation, tonemap, atomic writes, import order."""

import subprocess
import sys

import numpy as np
import pytest
import torch

from solidkit.envmap import io
from solidkit.errors import InputError, PanoramaError


def test_exr_round_trip_with_metadata(tmp_path):
    img = np.random.default_rng(0).uniform(0, 5e4, (16, 32, 3)).astype(np.float32)
    p = io.write_exr(tmp_path / "a.exr", img, {"exposure_time": 1 / 2500, "provenance": {"src": "x"}})
    back, meta = io.read_exr(p)
    np.testing.assert_array_equal(back, img)
    assert meta["exposure_time"] == pytest.approx(1 / 2500)
    assert meta["provenance"] == {"src": "x"}
    assert meta["conventions_version"] == 1
    assert [f.name for f in tmp_path.iterdir()] == ["a.exr"]  # no temporary left behind


def test_exr_half_and_single_channel(tmp_path):
    img = np.linspace(0, 100, 8 * 16, dtype=np.float32).reshape(8, 16)
    back, _ = io.read_exr(io.write_exr(tmp_path / "y.exr", img, half=True))
    assert back.shape == (8, 16, 1)
    np.testing.assert_allclose(back[..., 0], img, rtol=1e-3)
    with pytest.raises(InputError):
        io.write_exr(tmp_path / "big.exr", img * 1e4, half=True)


def test_corrupt_exr_is_an_input_error(tmp_path):
    p = tmp_path / "bad.exr"
    p.write_bytes(b"\x76\x2f\x31\x01garbage" * 10)
    with pytest.raises(InputError, match="not a readable EXR"):
        io.read_exr(p)
    with pytest.raises(InputError, match="no such file"):
        io.read_exr(tmp_path / "missing.exr")


def test_failed_write_leaves_previous_file(tmp_path):
    p = io.write_exr(tmp_path / "keep.exr", np.ones((4, 8, 3), np.float32))
    with pytest.raises(InputError):
        io.write_exr(p, np.ones((4, 8, 2), np.float32))
    assert io.read_exr(p)[0].shape == (4, 8, 3)


def test_ldr_round_trip_and_srgb(tmp_path):
    lin = np.random.default_rng(2).uniform(0, 1, (8, 16, 3)).astype(np.float32)
    p = io.write_ldr(tmp_path / "a.png", lin, encode_srgb=True)
    back = io.read_ldr(p, linear=True)
    np.testing.assert_allclose(back, lin, atol=0.01)
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(io.srgb_decode(io.srgb_encode(x)), x, atol=1e-9)
    assert io.srgb_encode(np.array(0.5)) == pytest.approx(0.7354, abs=1e-4)


def test_tonemap_matches_paper_formula_numpy_and_torch():
    h = np.array([0.0, 0.1, 1.0, 1.5, 100.0])
    expected = np.clip((2**-0.3 * h) ** (1 / 2.2), 0, 1)
    np.testing.assert_allclose(io.tonemap(h), expected, atol=1e-9)
    np.testing.assert_allclose(io.tonemap(torch.tensor(h)).numpy(), expected, atol=1e-9)


def test_validate_panorama_errors():
    with pytest.raises(PanoramaError, match="width must be 2"):
        io.validate_panorama(np.zeros((10, 30, 3)))
    bad = np.zeros((10, 20, 3))
    bad[1, 2, 0] = np.nan
    with pytest.raises(PanoramaError, match="NaN or Inf"):
        io.validate_panorama(bad)


def test_pycolmap_then_png_does_not_abort(tmp_path):
    """Regression for the measured trap: pycolmap imported before cv2 breaks cv2's PNG writer."""
    code = (
        "import solidkit, numpy as np\n"
        "from solidkit._imports import pycolmap\n"
        "pycolmap()\n"
        "from solidkit.envmap.io import write_ldr\n"
        f"write_ldr(r'{tmp_path / 'x.png'}', np.zeros((4, 4, 3), np.uint8))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "x.png").stat().st_size > 0
