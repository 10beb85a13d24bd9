"""Response curve: a known camera curve is recovered from synthetic brackets (ground truth)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from solidkit.calibration.profile import ProfileError, load_calibration_profile
from solidkit.calibration.response import (
    ResponseError,
    ResponseProfile,
    calibrate_response,
    calibrate_response_files,
    make_monotonic,
    plot_response,
    radiance_consistency,
    read_brackets,
    response_sanity,
)

TIMES = np.array([1 / 16, 1 / 4, 1, 4])
CODES = np.arange(256) / 255.0
# Forward camera curves (exposure -> [0, 1]) and their inverses normalised at code 128.
CURVES = {
    "gamma2.2": (lambda x: np.clip(x, 0, None) ** (1 / 2.2), CODES**2.2),
    "reinhard": (lambda x: x / (x + 0.18), 0.18 * CODES / np.maximum(1 - CODES, 1e-9)),
}


def _bracket(forward, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    log_e = rng.uniform(-9, 3, size=(120, 160, 1)) + np.array([0.0, 0.3, -0.3])
    radiance = 2.0**log_e
    out = []
    for t in TIMES:
        z = 255 * np.clip(forward(radiance * t), 0, 1) + rng.normal(0, noise, radiance.shape)
        out.append(np.clip(np.round(z), 0, 255).astype(np.uint8))
    return out


@pytest.mark.parametrize("name", sorted(CURVES))
def test_debevec_recovers_known_curve(name):
    forward, inverse = CURVES[name]
    truth = inverse / inverse[128]
    curve = calibrate_response(_bracket(forward), TIMES, method="debevec")
    assert curve.shape == (256, 3)
    np.testing.assert_allclose(curve[128], 1.0)
    err = np.abs(np.log2(curve[10:246] / truth[10:246, None]))
    # measured: max 0.011 stops (gamma 2.2), 0.018 stops (Reinhard); mean 0.003 / 0.005 stops
    assert err.max() < 0.04, err.max()
    assert err.mean() < 0.01
    san = response_sanity(curve, _bracket(forward))
    assert san["monotonic"], san["non_monotonic_codes"]


def test_robertson_runs_and_is_close_on_gamma():
    forward, inverse = CURVES["gamma2.2"]
    truth = inverse / inverse[128]
    curve = calibrate_response(_bracket(forward), TIMES, method="robertson")
    err = np.abs(np.log2(curve[10:246] / truth[10:246, None]))
    # OpenCV's Robertson is biased: measured max 0.35 stops, mean 0.17 stops on this bracket
    assert err.max() < 0.5 and err.mean() < 0.25
    assert response_sanity(curve)["monotonic"]


def test_consistency_residual_small_for_true_curve_and_large_for_wrong_one():
    forward, inverse = CURVES["gamma2.2"]
    imgs = _bracket(forward)
    truth = np.repeat((inverse / inverse[128])[:, None], 3, 1)
    good = radiance_consistency(truth, imgs, TIMES)["rms_stops_per_channel"]
    linear = np.repeat((np.arange(256) / 128.0)[:, None], 3, 1) + 1e-6
    bad = radiance_consistency(linear, imgs, TIMES)["rms_stops_per_channel"]
    assert max(good) < 0.05 and min(bad) > 5 * max(good)


def test_sanity_flags_non_monotonic_and_coverage():
    curve = np.repeat(np.linspace(0.01, 2, 256)[:, None], 3, 1)
    curve[100:110, 1] = 0.2  # a dip in green
    san = response_sanity(curve)
    assert not san["monotonic"] and san["non_monotonic_codes"][1] and not san["non_monotonic_codes"][0]
    imgs = [np.full((4, 4, 3), v, np.uint8) for v in (50, 60)]
    san = response_sanity(np.repeat(np.linspace(0.01, 2, 256)[:, None], 3, 1), imgs)
    assert san["code_range"][0] == [50, 60] and san["coverage_fraction"][0] == pytest.approx(2 / 256)


def test_make_monotonic_projects_a_dip_and_keeps_good_curves():
    good = np.repeat((np.linspace(1, 256, 256) / 128.0)[:, None] ** 2.2, 3, 1)
    np.testing.assert_allclose(make_monotonic(good), good, rtol=0.03)  # only the 1e-4-stop ramp changes it
    dipped = good.copy()
    dipped[100:110, 1] *= 0.5
    fixed = make_monotonic(dipped)
    assert np.all(np.diff(fixed, axis=0) > 0) and fixed[128].tolist() == [1.0, 1.0, 1.0]
    np.testing.assert_allclose(fixed[:, 0], good[:, 0] / good[128, 0], rtol=0.03)  # other channels untouched
    # least squares in log2: no increasing curve (e.g. the undipped one) is closer to the input
    d = np.log2(dipped[:, 1] / dipped[128, 1])
    assert np.sum((np.log2(fixed[:, 1]) - d) ** 2) <= np.sum((np.log2(good[:, 1] / good[128, 1]) - d) ** 2)


def test_files_profile_roundtrip_and_plot(tmp_path):
    forward, _ = CURVES["gamma2.2"]
    paths = []
    for i, img in enumerate(_bracket(forward)):
        p = tmp_path / f"b{i}.png"
        cv2.imwrite(str(p), img[..., ::-1])
        paths.append(p)
    with pytest.raises(ResponseError, match="ExposureTime"):
        read_brackets(paths)
    prof = calibrate_response_files(paths, times=TIMES.tolist())
    out = prof.save(tmp_path / "response.json")
    back = load_calibration_profile(out)
    assert isinstance(back, ResponseProfile) and back.array().shape == (256, 3)
    np.testing.assert_allclose(back.array(), prof.array())
    doc = json.loads(out.read_text())
    assert doc["kind"] == "response" and doc["format_version"] == 1
    assert len(doc["provenance"]["inputs"]) == 4 and len(doc["provenance"]["inputs"][0]["sha256"]) == 64
    assert plot_response(back.array(), tmp_path / "response.png").stat().st_size > 1000
    doc["format_version"] = 99
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ProfileError, match="format version"):
        ResponseProfile.load(tmp_path / "bad.json")


def test_bad_brackets_are_clear_errors(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    cv2.imwrite(str(a), np.zeros((4, 4, 3), np.uint8))
    cv2.imwrite(str(b), np.zeros((5, 4, 3), np.uint8))
    with pytest.raises(ResponseError, match="at least 2"):
        read_brackets([a])
    with pytest.raises(ResponseError, match="differ in size"):
        read_brackets([a, b], times=[1, 2])
    with pytest.raises(ResponseError, match="distinct"):
        read_brackets([a, a], times=[1, 1])


@pytest.mark.real
def test_real_frobisher_brackets(real_data):
    paths = sorted((real_data / "brackets_frobisher").glob("IMG_26*.jpg"))
    prof = calibrate_response_files(paths)
    assert prof.exposure_times_s == [0.125, 1.0, 8.0]  # from EXIF
    assert prof.sanity["monotonic"] and prof.sanity["monotonic_fix_max_stops"] < 1e-6
    rob = calibrate_response_files(paths, method="robertson")
    # measured: OpenCV's Robertson is not monotonic here; the projection moves it by 0.16 stops at most
    assert not rob.sanity["monotonic"] and np.all(np.diff(rob.array(), axis=0) > 0)
    assert rob.sanity["monotonic_fix_max_stops"] < 0.5
    # measured: 0.074 / 0.061 / 0.089 stops RMS radiance disagreement between exposures (R, G, B)
    assert max(prof.residuals["rms_stops_per_channel"]) < 0.15


def _write_bracket(tmp_path, forward, noise=1.0):
    paths = []
    for i, im in enumerate(_bracket(forward, seed=3, noise=noise)):
        p = tmp_path / f"b{i}.png"
        cv2.imwrite(str(p), im[..., ::-1])
        paths.append(p)
    return paths


def test_a_calibrated_curve_merges_as_well_as_the_merges_own_estimate(tmp_path):
    """`calibrate response` fits what `capture merge` estimates from the frames (same samples, same smoothness
    balance): merging with the calibrated curve gives the merge's own result, and the curve is monotonic. With
    the old default (lambda 10 at 400 samples) it bent back and differed from the merge's own curve."""
    from solidkit.capture.bracket_merge import merge_bracket
    from solidkit.capture.selfcal import estimate_response

    forward, inverse = CURVES["reinhard"]
    paths = _write_bracket(tmp_path, forward)
    prof = calibrate_response_files(paths, list(TIMES))
    assert prof.provenance.parameters["smoothness"] == pytest.approx(400 * 10 / 70)
    assert response_sanity(prof.array(), None)["monotonic"]
    own, _ = estimate_response([cv2.imread(str(p))[..., ::-1] for p in paths], list(TIMES))
    np.testing.assert_allclose(prof.array(), own, rtol=1e-6)
    calibrated, prov = merge_bracket(paths, list(TIMES), response=prof.array().astype(np.float64))
    estimated, _ = merge_bracket(paths, list(TIMES))
    np.testing.assert_allclose(calibrated.hdr, estimated.hdr, rtol=1e-3)  # the saved curve is float32
    assert not prov["warnings"]


def test_a_given_curve_that_does_not_fit_the_frames_is_warned_about(tmp_path):
    """A curve given for the merge is checked on the frames: sRGB for a Reinhard camera explains them far worse
    than a curve estimated from them, and the merge says so (it still uses the given curve)."""
    from solidkit.capture.bracket_merge import merge_bracket
    from solidkit.capture.frame_merge import srgb_response

    paths = _write_bracket(tmp_path, CURVES["reinhard"][0])
    _, prov = merge_bracket(paths, list(TIMES), response=srgb_response())
    assert any(
        w.startswith("response_check: the given response curve explains these frames worse") for w in prov["warnings"]
    )
    assert prov["response"]["kind"] == "array"


def test_times_that_contradict_the_frames_are_refused_naming_them(tmp_path):
    paths = _write_bracket(tmp_path, CURVES["gamma2.2"][0])
    with pytest.raises(ResponseError, match=r"b2\.png \(0\.25 s\) is darker than b3\.png \(0\.0625 s\)"):
        calibrate_response_files(paths, list(TIMES[::-1]))


def test_the_channels_solved_apart_are_opencvs_curve_bit_for_bit():
    """Each channel's Debevec solve runs in its own thread: the curve is OpenCV's three-channel solve, every bit
    (a bracket of the shipped mini card at half size; BLAS on one thread as in every merge)."""
    from pathlib import Path

    from solidkit.calibration.response import _debevec_per_channel
    from solidkit.camera.metadata import read_metadata
    from solidkit.threads import deterministic

    cam = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "campaign_mini" / "card" / "scene01" / "cam"
    files = sorted(cam.glob("R*.JPG"))[:3]
    imgs = [np.ascontiguousarray(cv2.imread(str(f), cv2.IMREAD_REDUCED_COLOR_2)[..., ::-1]) for f in files]
    t = np.asarray([read_metadata(f).exposure_time for f in files], np.float32)
    assert len(set(t.tolist())) == 3
    with deterministic():
        whole = cv2.createCalibrateDebevec(samples=400, lambda_=400 / 7).process(imgs, t)[:, 0, :]
        apart = _debevec_per_channel(imgs, t, 400, 400 / 7)
    assert apart.dtype == np.float64 and apart.shape == (256, 3)
    assert np.array_equal(apart, whole.astype(np.float64))
