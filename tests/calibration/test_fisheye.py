"""Fisheye intrinsics: boards rendered through a known Kannala-Brandt lens are recovered."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from solidkit.calibration.boards import BoardView, detect_views, render_board, subpixel_rays
from solidkit.calibration.fisheye import (
    FisheyeCalibrationError,
    FisheyeProfile,
    calibrate_fisheye,
    fit_kb,
    fit_mei,
    fit_model,
    lens_model_from_fit,
    lens_profile_from_calibrations,
)
from solidkit.calibration.profile import load_calibration_profile
from solidkit.camera.lens import LensModel, project, unproject
from solidkit.camera.lens import load_profile as load_lens_profile

SIZE = (512, 512)
F = 240.0
KB = [-0.02, 0.03, -0.045, 0.02]
CENTRE = (258.3, 254.2)
PATTERN = (8, 6)
TRUTH = LensModel(name="truth", center=CENTRE, poly=[F] + [F * k for k in KB], max_angle_deg=100)


def _poses(n, seed=3):
    rng = np.random.default_rng(seed)
    centre = np.array([(PATTERN[0] - 1) / 2, (PATTERN[1] - 1) / 2, 0.0])
    out = []
    for _ in range(n):
        R, _ = cv2.Rodrigues(rng.uniform(-0.5, 0.5, 3))
        az, ang = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(0, 45))
        look = np.array([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)])
        out.append((R, -R @ centre + look * rng.uniform(6, 8)))
    return out


@pytest.fixture(scope="module")
def rendered():
    rays = subpixel_rays(lambda x, y: unproject(TRUTH, x, y)[0], SIZE, supersample=2)
    poses = _poses(9)
    imgs = [render_board(rays, SIZE, R, t, PATTERN, supersample=2) for R, t in poses]
    imgs.append(np.full(SIZE[::-1], 120, np.uint8))  # no board
    imgs.append(cv2.GaussianBlur(imgs[0], (0, 0), 4.0))  # heavily blurred
    names = [f"v{i}.png" for i in range(len(imgs))]
    return detect_views(imgs, PATTERN, names=names), poses


@pytest.fixture(scope="module")
def calibrated(rendered):
    views, _ = rendered
    return calibrate_fisheye(views, PATTERN)


def test_bad_views_rejected_with_reason(rendered):
    views, _ = rendered
    assert views[-2].reason == "no 8x6 board found"
    assert views[-1].reason.startswith("blurred: edge width")
    assert all(v.ok for v in views[:9])


def test_kb_recovers_focal_and_centre(calibrated):
    kb = calibrated.models["kb"]
    # measured (512 px, f = 240): fx, fy +0.07 %, centre off by (-0.34, +0.04) px, RMS 0.11 px
    assert abs(kb["fx"] / F - 1) < 0.005 and abs(kb["fy"] / F - 1) < 0.005
    assert abs(kb["cx"] - CENTRE[0]) < 0.5 and abs(kb["cy"] - CENTRE[1]) < 0.5
    assert kb["rms_px"] < 0.3


def test_both_models_held_out_and_choice(calibrated):
    for m in ("kb", "mei"):
        ho = calibrated.models[m]["held_out"]
        assert ho["rms_px"] is not None and ho["rms_px"] < 0.5
        assert len(ho["per_view_rms_px"]) == 9
    best = min(("kb", "mei"), key=lambda m: calibrated.models[m]["held_out"]["rms_px"])
    assert calibrated.chosen_model == best
    assert calibrated.views["v9.png"] == "no 8x6 board found" and calibrated.views["v10.png"].startswith("blurred")
    assert calibrated.residuals["views_used"] == 9


def test_exported_lens_matches_truth(calibrated, tmp_path):
    lens = calibrated.lens_model()
    th = np.radians(np.linspace(0, calibrated.observed_max_angle_deg, 100))
    # measured: exported r(theta) within 0.39 px of the true lens up to the observed 66 deg
    assert np.abs(lens.radius(th) - TRUTH.radius(th)).max() < 0.5
    assert np.hypot(lens.center[0] - CENTRE[0], lens.center[1] - CENTRE[1]) < 0.5
    # random directions inside the observed cone project to the same pixel as the truth
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    d[:, 2] = np.abs(d[:, 2]) + 1.2
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x0, y0, th0 = project(TRUTH, d)
    x1, y1, _ = project(lens, d)
    inside = th0 <= np.radians(calibrated.observed_max_angle_deg)
    err = np.hypot(x1 - x0, y1 - y0)[inside]
    # measured: median 0.35 px, max 0.60 px (mostly the 0.34 px principal-point error)
    assert inside.sum() > 300 and err.max() < 0.8 and np.median(err) < 0.5
    # a one-lens profile in the shared lens-profile format, loadable by camera.lens
    prof = lens_profile_from_calibrations([calibrated], "unit-test", SIZE)
    back = load_lens_profile(prof.save(tmp_path / "lens.json"))
    assert back.lenses[0].name == "front" and back.reference_size == SIZE
    assert back.residuals["front"]["model"] == calibrated.chosen_model
    # and the calibration record itself (versioned, with provenance) round-trips
    rec = load_calibration_profile(calibrated.save(tmp_path / "front.calibration.json"))
    assert isinstance(rec, FisheyeProfile) and rec.chosen_model == calibrated.chosen_model
    assert json.loads((tmp_path / "front.calibration.json").read_text())["kind"] == "fisheye"


def test_crop_offset_moves_the_centre(rendered):
    views, _ = rendered
    fit = fit_model("kb", views, PATTERN)
    a = lens_model_from_fit(fit, "front")
    b = lens_model_from_fit(fit, "back", offset=(512.0, 0.0), ypr_deg=(180.0, 0.0, 0.0))
    assert b.center == (a.center[0] + 512.0, a.center[1]) and b.poly == a.poly and b.ypr_deg == (180.0, 0.0, 0.0)


def test_offset_and_second_lens_added(calibrated, tmp_path):
    base = lens_profile_from_calibrations([calibrated], "dual", (1024, 512))
    back = calibrated.model_copy(
        update={"lens_name": "back", "lens": calibrated.lens | {"name": "back", "ypr_deg": [180.0, 0.0, 0.0]}}
    )
    both = lens_profile_from_calibrations([back], "dual", (1024, 512), base=base)
    assert [l.name for l in both.lenses] == ["front", "back"]
    with pytest.raises(FisheyeCalibrationError, match="1024x512"):
        lens_profile_from_calibrations([back], "dual", (2048, 1024), base=base)


def test_omnidir_all_views_rejected_names_them():
    rng = np.random.default_rng(0)
    views = [BoardView(f"junk{i}.jpg", SIZE, rng.uniform(0, 512, (48, 2))) for i in range(4)]
    with pytest.raises(
        FisheyeCalibrationError, match=r"cv2.omnidir rejected every view \(junk0.jpg, junk1.jpg, junk2.jpg, junk3.jpg\)"
    ):
        fit_mei(views, PATTERN)


def test_too_few_views_lists_rejections():
    views = [
        BoardView("a.jpg", SIZE, reason="no 8x6 board found"),
        BoardView("b.jpg", SIZE, reason="blurred: edge width 9 px"),
    ]
    with pytest.raises(FisheyeCalibrationError, match="a.jpg: no 8x6 board found; b.jpg: blurred"):
        fit_kb(views, PATTERN)


def test_garbage_view_among_good_ones_is_rejected(rendered):
    views, _ = rendered
    junk = BoardView("junk.jpg", SIZE, np.random.default_rng(1).uniform(0, 512, (48, 2)))
    for model in ("kb", "mei"):
        fit = fit_model(model, [v for v in views if v.ok][:6] + [junk], PATTERN)
        assert "junk.jpg" in fit.rejected and fit.rms_px < 0.5


@pytest.mark.real
def test_real_fisheye_chessboard(real_data):
    paths = sorted((real_data / "fisheye_chessboard").glob("*.jpg"))
    views = detect_views(paths, (6, 9))
    prof = calibrate_fisheye(views, (6, 9), inputs=paths)
    r = prof.residuals
    # measured: 15/15 views used; kb RMS 0.278 px (held-out 0.296), mei RMS 0.275 px (held-out 0.289)
    assert r["views_used"] == 15
    assert r["rms_px"] < 0.4 and r["held_out_rms_px"] < 0.45
    assert max(r["held_out_per_view_rms_px"].values()) < 1.0
    assert 300 < prof.models["kb"]["fx"] < 320
    # measured: the boards reach 60.4°, the model 82.8° at the image corners; exported up to 60.25°, with a warning
    assert prof.lens_model().max_angle_deg <= prof.observed_max_angle_deg
    assert any(w.startswith("field_limited_to_boards") for w in prof.warnings)


def test_charuco_partial_views_recover_the_lens():
    from solidkit.calibration.boards import CharucoTarget

    target = CharucoTarget((7, 5))
    rays = subpixel_rays(lambda x, y: unproject(TRUTH, x, y)[0], SIZE, supersample=2)
    rng = np.random.default_rng(7)
    imgs = []
    for _ in range(9):
        R, _ = cv2.Rodrigues(rng.uniform(-0.5, 0.5, 3))
        az, ang = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(0, 50))
        look = np.array([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)])
        t = -R @ np.array([3.5, 2.5, 0.0]) + look * rng.uniform(5.5, 7.5)
        imgs.append(render_board(rays, SIZE, R, t, target.pattern, texture=target.texture(48)))
    imgs.append(cv2.GaussianBlur(imgs[0], (0, 0), 5.0))
    views = detect_views(imgs, target)
    assert views[-1].reason.startswith("no ChArUco board found")
    counts = [len(v.corners) for v in views[:-1]]
    assert min(counts) < 24 <= max(counts)  # partial views (corners hidden by markers/edges) are used
    prof = calibrate_fisheye(views, target.pattern)
    kb = prof.models["kb"]
    # measured: f +0.13 %, centre off by (0.05, -0.24) px, RMS 0.14 px
    assert abs(kb["fx"] / F - 1) < 0.005 and abs(kb["cx"] - CENTRE[0]) < 0.5 and abs(kb["cy"] - CENTRE[1]) < 0.5
    assert prof.residuals["views_used"] == 9


@pytest.fixture(scope="module")
def board_images():
    rays = subpixel_rays(lambda x, y: unproject(TRUTH, x, y)[0], SIZE, supersample=2)
    return [render_board(rays, SIZE, R, t, PATTERN, supersample=2) for R, t in _poses(9)]


def test_the_same_image_three_times_is_one_view(board_images):
    img = board_images[0]
    views = detect_views([img, img, img, board_images[1]], PATTERN, names=["a.png", "b.png", "c.png", "d.png"])
    assert views[1].reason == "duplicate: the same image as a.png (identical pixels)" and views[2].reason
    with pytest.raises(FisheyeCalibrationError, match=r"got 2 .*b.png: duplicate: the same image as a.png"):
        calibrate_fisheye(views, PATTERN)


def test_a_near_duplicate_board_pose_is_rejected(board_images):
    noisy = np.clip(board_images[0] + np.random.default_rng(0).normal(0, 2, SIZE[::-1]), 0, 255).astype(np.uint8)
    views = detect_views([*board_images[:6], noisy], PATTERN, names=[f"v{i}.png" for i in range(7)])
    assert views[-1].ok  # other pixels: detection alone does not see the repeat
    prof = calibrate_fisheye(views, PATTERN, models=("kb",))
    assert prof.views["v6.png"].startswith("duplicate: the board pose of v0.png")
    assert prof.residuals["views_used"] == 6


def test_export_stops_where_the_boards_stopped(calibrated, rendered):
    # the boards reach ~66° of this 100° lens: the exported field must not claim more without saying so
    obs = calibrated.observed_max_angle_deg
    assert calibrated.lens_model().max_angle_deg <= obs + 1e-9
    assert calibrated.residuals["model_max_angle_deg"] > obs + 10
    assert any(w.startswith("field_limited_to_boards") for w in calibrated.warnings)
    views, _ = rendered
    wide = calibrate_fisheye(views, PATTERN, models=("kb",), max_angle_deg=95.0)
    assert wide.lens_model().max_angle_deg > obs + 10
    assert any(w.startswith("extrapolated") for w in wide.warnings)


def test_a_model_choice_from_few_views_says_it_is_unreliable(rendered):
    views, _ = rendered
    few = calibrate_fisheye([v for v in views if v.ok][:5], PATTERN)
    assert few.residuals["model_choice_reliable"] is False
    assert "too few views" in few.choice_reason
    assert any(w.startswith("model_choice_unreliable") for w in few.warnings)
    best = min(few.models, key=lambda m: few.models[m]["held_out"]["rms_px"])
    assert few.chosen_model == best
