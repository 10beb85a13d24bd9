"""Vignetting: a synthetic radial falloff is recovered from a flat field and from the lens overlap."""

from __future__ import annotations

import numpy as np
import pytest

from solidkit.calibration.profile import load_calibration_profile
from solidkit.calibration.vignetting import (
    VignettingError,
    VignettingProfile,
    correct_vignetting,
    falloff,
    fit_flat_field,
    fit_overlap,
    lenses_from_profile,
    make_profile,
    vignetting_map,
)
from solidkit.camera.lens import load_profile as load_lens_profile
from solidkit.capture.unwarp import render_fisheye

SIZE = (768, 384)


@pytest.fixture(scope="module")
def lens_profile():
    return load_lens_profile("theta-s").scaled(*SIZE)


def _scene(d):
    """A smooth outdoor-like radiance field (RGB, linear)."""
    return 0.4 * np.stack(
        [
            1 + 0.4 * d[:, 0] + 0.2 * d[:, 1] ** 2,
            0.9 + 0.3 * d[:, 2] - 0.2 * d[:, 0] * d[:, 1],
            0.8 + 0.3 * np.sin(2 * d[:, 0]),
        ],
        -1,
    )


def _with_falloff(lens_profile, coeffs):
    geo = lenses_from_profile(lens_profile)
    return make_profile("truth", [g.model_copy(update={"coeffs": list(coeffs)}) for g in geo], SIZE, {})


def test_falloff_polynomial():
    assert falloff([], 0.7) == 1.0
    np.testing.assert_allclose(falloff([-0.3, 0.1], np.array([0.0, 0.5, 1.0])), [1, 1 - 0.075 + 0.00625, 0.8])


def test_flat_field_recovers_falloff(lens_profile):
    truth = [-0.3, 0.08, -0.05]
    vig = vignetting_map(_with_falloff(lens_profile, truth), SIZE)
    disk = render_fisheye(lambda d: np.ones((len(d), 1)), lens_profile, SIZE)[..., 0]
    flat = 0.5 * vig * disk + np.random.default_rng(0).normal(0, 0.002, disk.shape)
    lenses, res = fit_flat_field(np.repeat(flat[..., None], 3, 2), lenses_from_profile(lens_profile))
    rho = np.linspace(0, 0.98, 50)
    for l in lenses:
        # measured: max relative error 0.015 % over rho in [0, 0.98]
        assert np.abs(falloff(l.coeffs, rho) / falloff(truth, rho) - 1).max() < 0.002
        assert res[l.name]["rms_rel"] < 0.002
    prof = make_profile("flat-field", lenses, SIZE, res)
    corrected = correct_vignetting(flat, prof)
    yy, xx = np.mgrid[0 : SIZE[1], 0 : SIZE[0]]
    c = lens_profile.lenses[0].center
    vals = corrected[np.hypot(xx - c[0], yy - c[1]) < 0.95 * lens_profile.lenses[0].max_radius()]
    # flat after correction: mean within 0.2 %, spread = the added noise only
    assert abs(vals.mean() / 0.5 - 1) < 0.002 and vals.std() / vals.mean() < 0.01


@pytest.mark.parametrize("noise", [0.0, 0.004])
def test_overlap_recovers_falloff_and_gain(lens_profile, noise):
    truth = [-0.35]
    img = render_fisheye(_scene, lens_profile, SIZE)
    vig = vignetting_map(_with_falloff(lens_profile, truth), SIZE)
    gain = np.ones((SIZE[1], SIZE[0], 1))
    gain[:, SIZE[0] // 2 :] = 1.1  # the back lens is 10 % brighter
    obs = img * vig[..., None] * gain + np.random.default_rng(1).normal(0, noise, img.shape)
    lenses, res = fit_overlap(obs.astype(np.float32), lens_profile, degree=1)
    # measured: a1 = -0.35000 noise-free; -0.3499 (stderr 0.0002) with noise 0.004 (~1.5 % of the signal)
    assert abs(lenses[0].coeffs[0] - truth[0]) < 0.01
    assert lenses[0].coeffs == lenses[1].coeffs
    np.testing.assert_allclose(res["gain_ratio_per_channel"], 1 / 1.1, rtol=0.005)
    assert res["log_ratio_robust_rms_stops_after"] < res["log_ratio_robust_rms_stops_before"]
    assert 0.8 < res["rho_range"][0] < res["rho_range"][1] <= 1.0  # the overlap band only


def test_profile_roundtrip_scaling_and_errors(lens_profile, tmp_path):
    prof = _with_falloff(lens_profile, [-0.2, 0.01])
    prof = make_profile("flat-field", prof.lenses, SIZE, {"x": 1}, lens_profile=lens_profile)
    back = load_calibration_profile(prof.save(tmp_path / "vig.json"))
    assert isinstance(back, VignettingProfile) and back.lenses == prof.lenses
    big = vignetting_map(back, (2 * SIZE[0], 2 * SIZE[1]))
    small = vignetting_map(back, SIZE)
    # the same physical point (pixel centre x -> 2x + 0.5) has the same falloff at both sizes
    assert abs(big[2 * 100 + 1, 2 * 150 + 1] - small[100, 150]) < 0.01
    with pytest.raises(VignettingError, match="768x384"):
        vignetting_map(back, (500, 500))
    one = lens_profile.model_copy(update={"lenses": lens_profile.lenses[:1]})
    with pytest.raises(VignettingError, match="two-lens"):
        fit_overlap(np.ones((*SIZE[::-1], 3), np.float32), one)
    with pytest.raises(VignettingError, match="usable flat-field pixels"):
        fit_flat_field(np.zeros((*SIZE[::-1], 3)), lenses_from_profile(lens_profile))
