"""Bracket registration: static brackets stay unshifted, shifted frames are moved, and each frame's decision is said.

Brackets rendered from the shipped real HDR panoramas through a film-like (non-sRGB) camera, 1 % noise,
JPEG q92: the truth is known, so "helps" is measured, not assumed.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from solidkit.capture.bracket_merge import merge_bracket
from solidkit.capture.register import _ranks, shift_agreement
from solidkit.envmap.io import read_exr
from solidkit.errors import InputError

ASSETS = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "hdr_panoramas"


def film(x: np.ndarray) -> np.ndarray:
    """A film-like response (toe and shoulder), normalised to [0, 1]."""
    y = 1.0 / (1.0 + np.exp(-0.9 * (np.log2(np.maximum(x, 1e-6)) + 2.0)))
    lo, hi = 1.0 / (1.0 + np.exp(-0.9 * -18.0)), 1.0 / (1.0 + np.exp(-0.9 * 2.0))
    return np.clip((y - lo) / (hi - lo), 0.0, 1.0)


def _panorama(name: str) -> np.ndarray:
    hdr, _ = read_exr(ASSETS / f"{name}.exr")
    hdr = cv2.resize(np.clip(hdr[..., :3], 0, None), (512, 256), interpolation=cv2.INTER_AREA)
    return hdr * np.float32(0.18 / np.median(hdr))


@pytest.fixture(scope="module")
def sunrise() -> np.ndarray:
    """A smooth sky (the hardest case for a static bracket: little texture, a hue gradient)."""
    return _panorama("sunrise")


@pytest.fixture(scope="module")
def city() -> np.ndarray:
    """Buildings: texture to register on."""
    return _panorama("city")


def film_inverse() -> np.ndarray:
    """The exact inverse of :func:`film`, ``(256, 3)``, strictly increasing."""
    xs = np.exp(np.linspace(np.log(1e-7), 0.0, 400001))
    inv = np.interp(np.arange(256) / 255.0, film(xs), xs) + np.arange(256) * 1e-12
    return np.repeat(np.maximum.accumulate(inv)[:, None], 3, axis=1)


def _bracket(folder: Path, hdr: np.ndarray, times, shifts=None, seed=0) -> list[Path]:
    rng = np.random.default_rng(seed)
    paths = []
    for i, t in enumerate(times):
        x = hdr
        if shifts and shifts.get(i):
            dx, dy = shifts[i]
            h, w = hdr.shape[:2]
            M = np.float32([[1, 0, dx], [0, 1, dy]])
            x = cv2.warpAffine(hdr, M, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        x = x * t * (1 + 0.01 * rng.standard_normal(x.shape).astype(np.float32))
        z = np.round(255 * film(x)).astype(np.uint8)
        p = folder / f"f{i}.jpg"
        cv2.imwrite(str(p), cv2.cvtColor(z, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])
        paths.append(p)
    return paths


def _error(hdr: np.ndarray, truth: np.ndarray, paths: list[Path]) -> float:
    """Median |log2| luminance error after the best global scale, over pixels well exposed in some frame."""
    well = np.any([((cv2.imread(str(p)) >= 10) & (cv2.imread(str(p)) <= 245)).all(-1) for p in paths], axis=0)
    ok = well & (hdr.mean(-1) > 0)
    lr = np.log2(hdr[ok].mean(-1) / truth[ok].mean(-1))
    return float(np.median(np.abs(lr - np.median(lr))))


@pytest.mark.parametrize("n, step", [(3, 4.0), (3, 8.0), (5, 4.0)])
def test_a_static_bracket_comes_out_unshifted(tmp_path, sunrise, n, step):
    """A tripod bracket is merged exactly as with --no-align (the shifts that registration once applied to these
    brackets, up to (-0.47, -0.18) px, made the merge worse: 0.0648 against 0.0494 for 3 frames 2 stops apart)."""
    times = [step ** (k - n // 2) for k in range(n)]
    paths = _bracket(tmp_path, sunrise, times)
    aligned, prov = merge_bracket(paths, times)
    plain, _ = merge_bracket(paths, times, align=False)
    reg = prov["registration"]
    assert not any(reg["applied"]), reg
    assert set(reg["decision"]) <= {"reference", "static", "below_min_shift", "no_improvement", "no_overlap"}, reg
    assert reg["decision"][reg["reference_frame"]] == "reference"
    np.testing.assert_array_equal(aligned.hdr, plain.hdr)


def test_a_shifted_frame_is_moved_and_the_merge_gets_better(tmp_path, city):
    """Frames shifted by (-0.7, +0.8) and (+2.6, -1.3) px are registered (measured within 0.15 px; 0.05 px here),
    the agreement measured before and after, and the merge (through the camera's exact curve, so that only the
    registration differs) is closer to the truth than without registration."""
    times = [0.25, 1.0, 4.0]
    true = {0: (-0.7, 0.8), 2: (2.6, -1.3)}
    paths = _bracket(tmp_path, city, times, shifts=true)
    aligned, prov = merge_bracket(paths, times, response=film_inverse())
    plain, _ = merge_bracket(paths, times, response=film_inverse(), align=False)
    reg = prov["registration"]
    for i, (dx, dy) in true.items():
        assert reg["decision"][i] == "applied" and reg["applied"][i], reg
        mx, my = reg["shifts_px"][i]
        assert abs(mx - dx) < 0.15 and abs(my - dy) < 0.15, reg
        before, after = reg["agreement_unshifted_shifted"][i]
        assert after < 0.97 * before, reg
    err_aligned, err_plain = _error(aligned.hdr, city, paths), _error(plain.hdr, city, paths)
    assert err_aligned < 0.8 * err_plain, (err_aligned, err_plain)
    assert aligned.ghost_fraction < plain.ghost_fraction


def test_shift_agreement_prefers_the_true_shift_and_no_shift_for_a_static_pair(sunrise):
    """The symmetric half-shift test: a static pair agrees worse under any shift, a shifted pair better under its
    own shift, although resampling alone would lower the noise of either."""
    rng = np.random.default_rng(5)
    g = sunrise[..., 1]

    def shot(t, dx=0.0, dy=0.0):
        x = cv2.warpAffine(g, np.float32([[1, 0, dx], [0, 1, dy]]), g.shape[::-1], flags=cv2.INTER_CUBIC)
        return np.round(255 * film(x * t * (1 + 0.01 * rng.standard_normal(x.shape)))).astype(np.float32)

    ref, same, moved = shot(1.0), shot(4.0), shot(4.0, 0.6, -0.4)
    mask = ((ref > 5) & (ref < 247) & (same > 5) & (same < 247)).astype(np.uint8)
    r_ref, r_same, r_moved = _ranks(ref, mask), _ranks(same, mask), _ranks(moved, mask)
    for dx, dy in [(0.5, 0.0), (0.0, -0.5), (0.6, -0.4)]:
        unshifted, shifted = shift_agreement(r_same, r_ref, mask, dx, dy)
        assert shifted > unshifted, (dx, dy, unshifted, shifted)
    unshifted, shifted = shift_agreement(r_moved, r_ref, mask, 0.6, -0.4)
    assert shifted < 0.9 * unshifted, (unshifted, shifted)


def test_ranks_share_ties():
    """Tied values get their mean rank (handed out in raster order, a dark frame's plateaus looked shifted)."""
    img = np.array([[1.0, 1.0, 2.0, 5.0, 0.5]], np.float32)
    mask = np.array([[1, 1, 1, 1, 0]], np.uint8)
    expected = [[1 / 6, 1 / 6, 2 / 3, 1.0, 0.5]]
    np.testing.assert_allclose(_ranks(img, mask), expected, atol=1e-6)
    np.testing.assert_allclose(_ranks((img * 10).astype(np.uint8), mask), expected, atol=1e-6)  # by histogram


def test_exposure_times_in_the_wrong_order_are_an_input_error(tmp_path, sunrise):
    """Times given in reverse (frames that get darker while the times grow) are refused, naming the frames,
    instead of a merge through an assumed sRGB curve; the CLI exits 2 with that one line."""
    times = [0.25, 1.0, 4.0]
    paths = _bracket(tmp_path, sunrise, times)
    with pytest.raises(InputError, match=r"f1\.jpg \(1 s\) is darker than f2\.jpg \(0\.25 s\)") as exc:
        merge_bracket(paths, times[::-1])
    assert "f0.jpg (4 s) is darker than f1.jpg (1 s)" in str(exc.value)
    from solidkit.cli import app

    r = CliRunner().invoke(
        app, ["capture", "merge", *map(str, paths), "-o", str(tmp_path / "m.exr"), "--times", "4,1,1/4"]
    )
    assert r.exit_code != 0 and "exposure times contradict the frames" in str(r.exception)
    assert not (tmp_path / "m.exr").exists()
    merge_bracket(paths, times)  # the right order merges


def test_valid_codes_match_the_frames_mask():
    """Registration of 8-bit frames reads the well-exposed mask from the codes alone: the same pixels a Frame keeps."""
    from solidkit.capture.bracket_merge import _valid_codes
    from solidkit.capture.frame_merge import frame_from_ldr

    codes = np.random.default_rng(0).integers(0, 256, (64, 96, 3)).astype(np.uint8)
    np.testing.assert_array_equal(_valid_codes(codes), frame_from_ldr(codes, 1.0).valid().all(axis=-1))
