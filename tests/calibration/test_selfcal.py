"""A lens profile for any dual-fisheye camera from one frame, and profiles that do not fit.

Frames are rendered from the real HDR panorama city.exr through the project's forward lens model
(:func:`solidkit.capture.unwarp.render_fisheye`) with a known truth -- lens family, field of view,
image circles, layout -- and stored as 8-bit sRGB like a camera's JPEG. The measured failures of
the issue each have a test here: another camera's frame refined from ``theta-v`` (the Gear 360
case: centres ran 130 px, the seam got worse), a ±90°-turned layout unwarped without a warning.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from solidkit.calibration.circles import Circle, CircleError, find_image_circles
from solidkit.calibration.fitcheck import SEAM_ERROR_WARN, check_profile_fit, check_upright
from solidkit.calibration.lensfit import fit_dual_fisheye, start_profile
from solidkit.calibration.seam import prepare_seam_image, seam_error
from solidkit.camera.lens import load_profile
from solidkit.capture.unwarp import render_fisheye, unwarp_srgb8
from solidkit.envmap.io import read_exr, srgb_decode, srgb_encode, tonemap, write_ldr
from solidkit.envmap.sun import luminance
from tests.conftest import ASSETS

SIZE = (640, 320)
CIRCLES = [Circle(158.3, 161.2, 150.0, 1.0), Circle(479.6, 159.4, 149.0, 1.0)]


@pytest.fixture(scope="module")
def city() -> np.ndarray:
    pano, _ = read_exr(ASSETS / "hdr_panoramas" / "city.exr")
    return np.clip(tonemap(pano), 0, 1).astype(np.float32)


def truth_profile(family: str, half_fov: float, roll: float = 0.0, circles=CIRCLES, size=SIZE, offset=(0.0, 0.0)):
    """Lenses whose field ``half_fov`` ends exactly on the given circles (no usable-field margin)."""
    p = start_profile(circles, size, family, half_fov, 0.0, roll, back_offset_deg=offset)
    return p.model_copy(update={"lenses": [l.model_copy(update={"max_angle_deg": half_fov}) for l in p.lenses]})


def camera_frame(pano: np.ndarray, profile, size=SIZE) -> np.ndarray:
    """Linear float frame as an 8-bit sRGB camera JPEG would decode (quantised)."""
    fish = render_fisheye(pano, profile, size)
    codes = np.round(np.clip(np.asarray(srgb_encode(fish)), 0, 1) * 255.0) / 255.0
    return np.asarray(srgb_decode(codes), np.float32)


def to_uint8(img: np.ndarray) -> np.ndarray:
    return (np.clip(np.asarray(srgb_encode(img)), 0, 1) * 255.0 + 0.5).astype(np.uint8)


def test_image_circles_side_by_side_and_stacked(city):
    frame = camera_frame(city, truth_profile("equidistant", 95.0))
    circles, arrangement = find_image_circles(luminance(frame))
    assert arrangement == "side_by_side"
    for c, t in zip(circles, CIRCLES):
        assert math.hypot(c.cx - t.cx, c.cy - t.cy) < 0.5 and abs(c.r - t.r) < 1.0
    stacked = [Circle(161.0, 158.0, 150.0, 1.0), Circle(159.0, 481.0, 149.0, 1.0)]
    frame = camera_frame(city, truth_profile("equidistant", 95.0, circles=stacked, size=(320, 640)), (320, 640))
    circles, arrangement = find_image_circles(luminance(frame))
    assert arrangement == "stacked"
    assert all(math.hypot(c.cx - t.cx, c.cy - t.cy) < 0.5 for c, t in zip(circles, stacked))
    with pytest.raises(CircleError, match="no fisheye image circle|no circular image edge"):
        find_image_circles(luminance(city[::2, ::2]))  # an equirect panorama: no black surround
    with pytest.raises(CircleError):
        find_image_circles(np.zeros((320, 640), np.float32))


@pytest.mark.parametrize(
    "family, half_fov, roll, layout",
    [
        ("equidistant", 95.0, 0.0, "side by side, upright"),
        pytest.param(
            "equisolid", 100.0, 90.0, "side by side, rotated +90°", marks=pytest.mark.slow
        ),  # the CLI test has one
        ("theta", 100.0, -90.0, "side by side, rotated -90°"),
    ],
)
def test_start_profile_recovers_family_fov_layout(city, family, half_fov, roll, layout):
    truth = truth_profile(family, half_fov, roll)
    fit = fit_dual_fisheye(camera_frame(city, truth), 0.98, refine=False)
    fov = 2 * fit.half_fov_deg
    centre_err = [math.dist(a.center, b.center) for a, b in zip(fit.profile.lenses, truth.lenses)]
    print(
        f"{family} {2 * half_fov}° roll {roll}: found {fit.family} {fov:.2f}°, {fit.layout}, centres {centre_err} px, "
        f"seam {fit.seam_final['seam_error']:.3f}, families {fit.scans['families']}"
    )
    assert fit.family == family
    assert abs(fov - 2 * half_fov) < 1.5
    assert fit.layout == layout and fit.upright.confident
    assert max(centre_err) < 0.6
    assert fit.seam_final["seam_error"] < 0.15


@pytest.mark.slow  # ~5 s; the default suite's perturbation test is test_calibration_overlap's
def test_refinement_brings_back_a_perturbed_profile(city, tmp_path, cli):
    """calibrate overlap from a perturbed correct profile (back lens 1.5° off, front centre 4 px off) improves it."""
    truth = truth_profile("equidistant", 97.0)
    src = tmp_path / "frame.png"
    write_ldr(src, camera_frame(city, truth), encode_srgb=True)
    start = truth_profile("equidistant", 97.0, offset=(1.0, -1.1))
    start = start.model_copy(
        update={"lenses": [start.lenses[0].model_copy(update={"center": (162.3, 159.2)}), start.lenses[1]]}
    )
    start.save(tmp_path / "perturbed.json")
    code, out, err = cli(
        "calibrate",
        "overlap",
        str(src),
        "--base",
        str(tmp_path / "perturbed.json"),
        "-o",
        str(tmp_path / "unit.json"),
        "--json",
    )
    assert code == 0, err
    s = json.loads(out)
    unit = load_profile(tmp_path / "unit.json")
    before = math.dist(start.lenses[0].center, truth.lenses[0].center)
    after = math.dist(unit.lenses[0].center, truth.lenses[0].center)
    print(
        f"perturbed: seam error {s['seam_error_before']:.3f} -> {s['seam_error_after']:.3f}, front centre {before:.2f} "
        f"-> {after:.2f} px"
    )
    assert s["refused"] is None and s["seam_error_after"] < 0.5 * s["seam_error_before"] and after < 0.5 * before


#: another camera's image circles (Gear-360-like: both ~10 % off theta-v's place and size at 640x320)
GEAR = [Circle(171.0, 152.0, 138.0, 1.0), Circle(466.0, 171.0, 139.0, 1.0)]


def test_refinement_from_another_cameras_profile_is_bounded_and_flagged(city, tmp_path):
    """A real Gear 360 frame refined from theta-v once moved the centres by 130-138 px and the back lens by 16°.
    Measured without the bound on this rendered stand-in: centres moved 203/261 px (at 5792 px), back lens 23.6°."""
    from solidkit.calibration.overlap import refine_files

    src = tmp_path / "gear.png"
    write_ldr(src, camera_frame(city, truth_profile("equidistant", 97.5, circles=GEAR)), encode_srgb=True)
    s = refine_files([src], "theta-v", tmp_path / "unit.json")
    shift = [math.hypot(*c) for c in s["center_shift_px"]]  # px at theta-v's 5792-px reference size
    print(
        f"theta-v on a Gear-like frame: seam error {s['seam_error_before']} -> {s['seam_error_after']}, "
        f"refused {s['refused']}, centre shifts {shift} px, back lens {s['back_rotation_change_deg']:.2f}°"
    )
    bound = 0.03 * load_profile("theta-v").lenses[0].max_radius() * math.sqrt(2)
    assert max(shift) <= bound + 1e-6 and s["back_rotation_change_deg"] <= 3.0 * math.sqrt(3) + 1e-6
    assert sum(w.startswith("profile_mismatch") for w in s["warnings"]) == 2
    kept = load_profile(tmp_path / "unit.json")
    r = kept.residuals  # never worse than the start: better, or refused and the start kept (NaN: unmeasurable)
    assert (
        r["seam_error_before"] is not None
        and r["seam_error_after"] is not None
        and r["seam_error_after"] < r["seam_error_before"]
    ) or (s["refused"] and kept.lenses == load_profile("theta-v").lenses)


def test_profile_fit_checks_correct_wrong_and_turned(city):
    """capture unwarp's checks: the right profile passes; another camera's profile and a ±90° turned layout warn."""
    theta = load_profile("theta-v")
    right = to_uint8(render_fisheye(city, theta.scaled(*SIZE), SIZE))
    report, warns = check_profile_fit(right, theta, 0.98)
    assert report["seam_error"] < SEAM_ERROR_WARN and not warns
    assert report["seam_disparity"]["median_deg"] < 0.5  # measured 0.16° over 69 matches
    assert not check_upright(unwarp_srgb8(right, theta, 160), report) and report["ok"]
    other = to_uint8(camera_frame(city, truth_profile("equidistant", 95.0)))
    report, warns = check_profile_fit(other, theta, 0.98)
    # measured: 5.3° median disparity (the seam error, 0.80, no longer decides where the disparity is measured)
    assert report["seam_disparity"]["median_deg"] > report["seam_disparity_warn_deg"]
    assert [w for w in warns if w.startswith("seam")][0].startswith("seam_disparity: the two lenses put")
    elsewhere = to_uint8(
        camera_frame(city, truth_profile("equidistant", 97.5, circles=GEAR))
    )  # theta-v's ring on black
    report, warns = check_profile_fit(elsewhere, theta, 0.98)
    assert report["seam_disparity"]["median_deg"] is None  # nothing to match: the seam error's check decides
    assert report["seam_error"] is None and any(w.startswith("seam_mismatch") for w in warns)
    turned_truth = start_profile(
        [Circle(l.center[0], l.center[1], l.max_radius(), 1) for l in theta.scaled(*SIZE).lenses],
        SIZE,
        "theta",
        100.0,
        0.0,
        90.0,
    )
    turned = to_uint8(render_fisheye(city, turned_truth, SIZE))
    report, warns = check_profile_fit(turned, theta, 0.98)
    assert report["seam_error"] < SEAM_ERROR_WARN  # a turned camera still agrees with itself on the overlap
    up = check_upright(unwarp_srgb8(turned, theta, 160), report)
    assert up and up[0].startswith("layout_mismatch") and not report["ok"] and report["roll_deg"] == 90.0


def test_cli_unwarp_reports_seam_error_and_warns_with_exit_0(city, tmp_path, cli):
    other = tmp_path / "gear.png"
    write_ldr(other, camera_frame(city, truth_profile("equidistant", 95.0)), encode_srgb=True)
    code, out, err = cli(
        "capture",
        "unwarp",
        str(other),
        "-o",
        str(tmp_path / "p.png"),
        "--profile",
        "theta-v",
        "--size",
        "256x128",
        "--json",
        "--no-disk-cache",
    )
    assert code == 0, err
    s = json.loads(out)
    fit = s["profile_fit"]
    assert fit["seam_disparity"]["median_deg"] > fit["seam_disparity_warn_deg"] and not fit["ok"]
    assert any(w.startswith("seam_disparity") for w in s["warnings"])


def test_cli_calibrate_fisheye_writes_a_profile_unwarp_uses(city, tmp_path, cli):
    truth = truth_profile("equisolid", 99.0, 90.0)
    src = tmp_path / "cam.png"
    write_ldr(src, camera_frame(city, truth), encode_srgb=True)
    out = tmp_path / "cam.json"
    code, text, err = cli(
        "calibrate", "fisheye", str(src), "-o", str(out), "--json", "--no-refine", "--family", "equisolid"
    )
    assert code == 0, err
    s = json.loads(text)
    assert (
        s["family"] == "equisolid" and s["layout"] == "side by side, rotated +90°" and abs(s["fov_deg"] - 198.0) < 1.0
    )
    prof = load_profile(out)
    assert prof.provenance.inputs[0].sha256 and prof.residuals["layout"] == s["layout"]
    code, text, err = cli(
        "capture",
        "unwarp",
        str(src),
        "-o",
        str(tmp_path / "p.png"),
        "--profile",
        str(out),
        "--size",
        "256x128",
        "--json",
        "--no-disk-cache",
    )
    assert code == 0, err
    u = json.loads(text)
    assert u["profile_fit"]["ok"] and u["seam_error"] < 0.2, u["warnings"]


def test_seam_error_is_scale_free(city):
    """The seam error does not depend on the scene's brightness or contrast (a threshold means the same everywhere)."""
    prof = truth_profile("equidistant", 97.0)
    frame = camera_frame(city, prof)
    a = seam_error(prepare_seam_image(frame, 150.0, None), prof)["seam_error"]
    b = seam_error(prepare_seam_image(0.1 * frame**1.5, 150.0, None), prof)["seam_error"]
    off = [
        seam_error(prepare_seam_image(frame, 150.0, None), truth_profile("equidistant", 97.0, offset=(o, 0.0)))[
            "seam_error"
        ]
        for o in (1.0, 2.0, 4.0, 8.0)
    ]  # back lens yawed by this many degrees (measured 0.21, 0.35, 0.59, 0.84)
    assert a < 0.15 and abs(a - b) < 0.05 and np.all(np.diff(off) > 0) and off[0] > a and off[-1] > 0.75


@pytest.mark.real
@pytest.mark.slow
def test_real_theta_s_frame_layout_and_circles(real_data, tmp_path):
    """The real Theta S live frame: both circles found, its ±90° layout detected (the shipped theta-s-video profile
    is upright only with the roll this detects); the seam error of the fit is reported, never made worse."""
    from solidkit.calibration.lensfit import fit_file

    src = real_data / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"
    fit, s = fit_file(src, tmp_path / "ts.json")
    shipped = load_profile("theta-s-video")
    print(
        json.dumps(
            {
                k: s[k]
                for k in (
                    "layout",
                    "family",
                    "fov_deg",
                    "centers",
                    "seam_error_start",
                    "seam_error_refined",
                    "seam_error",
                    "refusal",
                    "shipped_profiles_seam_error",
                )
            },
            default=str,
        )
    )
    assert s["arrangement"] == "side_by_side" and s["roll_deg"] == 90.0
    assert [round(a) for a in shipped.lenses[0].ypr_deg] == [0, 0, 90]
    for c, ref in zip(s["circles"], shipped.residuals["image_circles_px"]):
        assert math.hypot(c["cx"] - ref[0], c["cy"] - ref[1]) < 4.0 and abs(c["r"] - ref[2]) < 6.0
    assert s["seam_error"] <= s["seam_error_start"] + 1e-12
    assert (
        190.0 < s["fov_deg"] < 210.0
    )  # Ricoh's design table puts 100° on the circle (200°); measured 193.7 (equisolid)
    # the fit stays within the tilt bound (measured 0.79° median disparity at 3.0°); the shipped profile fits this
    # frame better (0.64°) with its back lens 9.6° off opposite: the user is told so, with its tilt
    assert s["back_tilt_deg"] <= s["max_back_tilt_deg"] + 1e-6
    assert s["shipped_profiles_back_tilt_deg"]["theta-s-video"] > s["max_back_tilt_deg"]
    better = [w for w in s["warnings"] if w.startswith("shipped_profile_fits_better")]
    assert len(better) == 1 and "'theta-s-video'" in better[0] and "off opposite, beyond the 3°" in better[0]


@pytest.mark.real
def test_real_theta_s_turned_circles_warn(real_data, tmp_path, cli):
    """The same real frame with each circle turned back by 90° (content upright in the file): the theta-s-video
    profile no longer fits and capture unwarp says so (exit 0)."""
    import cv2

    im = cv2.imread(str(real_data / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"))
    for (cx, cy), turn in (((461, 481), cv2.ROTATE_90_CLOCKWISE), ((1456, 470), cv2.ROTATE_90_COUNTERCLOCKWISE)):
        r = 460
        im[cy - r : cy + r, cx - r : cx + r] = cv2.rotate(im[cy - r : cy + r, cx - r : cx + r].copy(), turn)
    src = tmp_path / "turned.png"
    cv2.imwrite(str(src), im)
    code, out, err = cli(
        "capture",
        "unwarp",
        str(src),
        "-o",
        str(tmp_path / "p.png"),
        "--profile",
        "theta-s-video",
        "--size",
        "512x256",
        "--json",
        "--no-disk-cache",
    )
    assert code == 0, err
    s = json.loads(out)
    print(s["seam_error"], s["profile_fit"], s["warnings"])
    assert not s["profile_fit"]["ok"] and any(
        w.startswith(("seam_disparity", "seam_mismatch", "layout_mismatch")) for w in s["warnings"]
    )


@pytest.mark.real
def test_real_theta_s_wrong_profile_warns_by_seam_disparity(real_data, tmp_path, cli):
    """capture unwarp judges a profile by the seam disparity in degrees, as calibrate fisheye does: on the real Theta S
    frame the shipped profile passes, the same profile with its back lens yawed 1° or 2° off its aim warns (their
    seam errors, 0.68 and 0.66, stayed under the old threshold of 0.7: no warning before)."""
    src = real_data / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"
    shipped = load_profile("theta-s-video")
    back = shipped.lenses[1]
    figures = {}
    for name, yaw in (("shipped", 0.0), ("yaw1", 1.0), ("yaw2", 2.0)):
        prof = shipped.model_copy(
            update={
                "lenses": [
                    shipped.lenses[0],
                    back.model_copy(update={"ypr_deg": (back.ypr_deg[0] + yaw, *back.ypr_deg[1:])}),
                ]
            }
        )
        out_png, prof_json = str(tmp_path / f"{name}.png"), str(tmp_path / f"{name}.json")
        prof.save(prof_json)
        code, out, err = cli(
            "capture", "unwarp", str(src), "-o", out_png, "--profile", prof_json,
            "--size", "256x128", "--level", "off", "--json", "--no-disk-cache",
        )  # fmt: skip
        assert code == 0, err
        s = json.loads(out)
        figures[name] = (s["profile_fit"]["seam_disparity"]["median_deg"], s["seam_error"], s["warnings"])
    print(figures)
    # measured: median disparity 0.70° (parallax indoors), 1.55°, 2.12°; seam error 0.60, 0.68, 0.66
    d, e, warns = figures["shipped"]
    assert d < 1.0 and not any(w.startswith(("seam_disparity", "seam_mismatch")) for w in warns)
    for name in ("yaw1", "yaw2"):
        d, e, warns = figures[name]
        assert d > 1.0 and e < SEAM_ERROR_WARN
        assert any(w.startswith("seam_disparity: the two lenses put") for w in warns)


def test_cli_unwarp_table_with_a_one_lens_profile(city, tmp_path, cli):
    """A profile with one lens has no seam to judge: the table says so instead of failing on the missing figures."""
    theta = load_profile("theta-v")
    one = theta.model_copy(update={"lenses": theta.lenses[:1]})
    one.save(tmp_path / "one.json")
    src = tmp_path / "frame.png"
    write_ldr(src, camera_frame(city, truth_profile("equidistant", 95.0)), encode_srgb=True)
    code, out, err = cli(
        "capture", "unwarp", str(src), "-o", str(tmp_path / "p.png"), "--profile", str(tmp_path / "one.json"),
        "--size", "128x64", "--no-disk-cache",
    )  # fmt: skip
    assert code == 0, err
    assert "seam disparity unmeasured" in out
