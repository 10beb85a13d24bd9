"""``solidkit calibrate ...``: each command writes its profile and prints a summary; errors are one line."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from solidkit.calibration.profile import load_calibration_profile
from solidkit.cli import app
from solidkit.envmap.io import write_exr

runner = CliRunner()


def _ok(args):
    r = runner.invoke(app, ["calibrate", *map(str, args)])
    assert r.exit_code == 0, r.output + repr(r.exception)
    return r.output


def test_response_command(tmp_path):
    rng = np.random.default_rng(0)
    radiance = 2.0 ** rng.uniform(-8, 2, (60, 80, 1)) * np.ones(3)
    paths = []
    for i, t in enumerate([1 / 16, 1 / 4, 1, 4]):
        z = np.clip(np.round(255 * np.clip(radiance * t, 0, 1) ** (1 / 2.2)), 0, 255).astype(np.uint8)
        cv2.imwrite(str(tmp_path / f"f{i}.png"), z)
        paths.append(tmp_path / f"f{i}.png")
    out = _ok(["response", *paths, "-o", tmp_path / "resp.json", "--times", "0.0625,0.25,1,4"])
    assert "monotonic" in out and (tmp_path / "resp.png").is_file()
    prof = load_calibration_profile(tmp_path / "resp.json")
    assert prof.kind == "response" and prof.array().shape == (256, 3)
    # the HDR merge reads this profile as its response curve
    from solidkit.capture.frame_merge import load_response

    np.testing.assert_allclose(load_response(tmp_path / "resp.json"), prof.array(), rtol=1e-6)


def test_colour_command_with_corners(tmp_path):
    from tests.calibration.test_colour import CORNERS, render_chart

    img, _, _ = render_chart()
    write_exr(tmp_path / "chart.exr", img)
    corners = ",".join(f"{v:g}" for v in CORNERS.ravel())
    out = _ok(["colour", tmp_path / "chart.exr", "-o", tmp_path / "colour.json", "--corners", corners])
    assert "CIEDE2000 ccm" in out
    prof = load_calibration_profile(tmp_path / "colour.json")
    assert prof.residuals["ciede2000_mean"]["ccm"] < 2 and prof.detection == "corners"


def test_camera_command(tmp_path):
    p = tmp_path / "photo.jpg"
    exif = Image.Exif()
    exif[0x0110] = "iPhone 12"
    exif.get_ifd(0x8769)[0x920A] = 4.2
    Image.new("RGB", (4032, 3024)).save(p, exif=exif)
    out = _ok(["camera", p, "-o", tmp_path / "cam.json"])
    assert "exif-sensor-table" in out
    prof = load_calibration_profile(tmp_path / "cam.json")
    assert prof.matrix()[0, 0] == pytest.approx(4.2 * 4032 / 5.6)
    assert prof.model_input_size == (320, 240)


def test_lens_command_writes_lens_profile(tmp_path):
    from solidkit.calibration.boards import render_board, subpixel_rays
    from solidkit.camera.lens import LensModel, unproject
    from solidkit.camera.lens import load_profile as load_lens

    truth = LensModel(name="t", center=(161.2, 158.7), poly=[110.0, -2.0, 1.0], max_angle_deg=95)
    rays = subpixel_rays(lambda x, y: unproject(truth, x, y)[0], (320, 320))
    rng = np.random.default_rng(5)
    paths = []
    for i in range(6):
        R, _ = cv2.Rodrigues(rng.uniform(-0.4, 0.4, 3))
        az, ang = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(0, 35))
        look = np.array([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)])
        img = render_board(rays, (320, 320), R, -R @ np.array([2.5, 1.5, 0]) + look * 6.5, (6, 4))
        cv2.imwrite(str(tmp_path / f"v{i}.png"), img)
        paths.append(tmp_path / f"v{i}.png")
    out = _ok(
        ["lens", *paths, "--pattern", "6x4", "-o", tmp_path / "lens.json", "--model", "kb", "--profile-name", "unit"]
    )
    assert "held-out" in out
    lp = load_lens(tmp_path / "lens.json")
    assert lp.model == "unit" and lp.reference_size == (320, 320)
    assert abs(lp.lenses[0].poly[0] / 110 - 1) < 0.01 and abs(lp.lenses[0].center[0] - 161.2) < 1
    rec = load_calibration_profile(tmp_path / "lens.front.calibration.json")
    assert rec.kind == "fisheye" and len(rec.provenance.inputs) == 6
    # a dual-fisheye layout: the same view in both halves of 640x320 frames -> front and back lenses
    wide = []
    for p in paths:
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(p.with_name("w" + p.name)), np.hstack([g, g]))
        wide.append(p.with_name("w" + p.name))
    common = ["--pattern", "6x4", "--model", "kb"]
    _ok(["lens", *wide, *common, "-o", tmp_path / "dual.json", "--crop", "0,0,320,320", "--profile-name", "dual"])
    _ok(
        [
            "lens",
            *wide,
            *common,
            "-o",
            tmp_path / "dual.json",
            "--crop",
            "320,0,320,320",
            "--name",
            "back",
            "--ypr",
            "180,0,0",
            "--add-to",
            tmp_path / "dual.json",
            "--profile-name",
            "dual",
        ]
    )
    dual = load_lens(tmp_path / "dual.json")
    assert dual.reference_size == (640, 320) and [l.name for l in dual.lenses] == ["front", "back"]
    front, back = dual.lenses
    assert back.ypr_deg == (180.0, 0.0, 0.0) and back.poly == front.poly
    assert abs(back.center[0] - front.center[0] - 320) < 1e-6 and abs(back.center[1] - front.center[1]) < 1e-6
    assert abs(front.center[0] - lp.lenses[0].center[0]) < 1e-6  # same fit as the single-lens run
    r = runner.invoke(
        app,
        [
            "calibrate",
            "lens",
            *map(str, paths),
            *common,
            "-o",
            str(tmp_path / "x.json"),
            "--add-to",
            str(tmp_path / "dual.json"),
        ],
    )
    assert r.exit_code != 0 and "640x320" in str(r.exception)  # other image size than the profile


def test_vignetting_command_flat(tmp_path):
    from solidkit.calibration.vignetting import falloff
    from solidkit.camera.lens import load_profile as load_lens

    lp = load_lens("theta-s").scaled(512, 256)
    yy, xx = np.mgrid[0:256, 0:512].astype(np.float64)
    flat = np.zeros((256, 512))
    for l in lp.lenses:
        rho = np.hypot(xx - l.center[0], yy - l.center[1]) / l.max_radius()
        flat = np.where(rho <= 1, 0.6 * falloff([-0.25], rho), flat)
    write_exr(tmp_path / "flat.exr", np.repeat(flat[..., None], 3, 2).astype(np.float32))
    out = _ok(
        [
            "vignetting",
            tmp_path / "flat.exr",
            "--lens-profile",
            "theta-s",
            "--method",
            "flat",
            "--degree",
            "1",
            "-o",
            tmp_path / "v.json",
        ]
    )
    assert "front" in out and "back" in out
    prof = load_calibration_profile(tmp_path / "v.json")
    assert all(abs(l.coeffs[0] + 0.25) < 0.005 for l in prof.lenses)


def test_errors_are_one_line(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "solidkit.cli",
            "calibrate",
            "camera",
            str(tmp_path / "missing.jpg"),
            "-o",
            str(tmp_path / "x.json"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and r.stderr.strip().startswith("error:") and len(r.stderr.strip().splitlines()) == 1
    r = runner.invoke(
        app, ["calibrate", "lens", str(tmp_path / "a.png"), "--pattern", "6by4", "-o", str(tmp_path / "l.json")]
    )
    assert r.exit_code != 0 and "COLSxROWS" in str(r.exception)
    assert not (tmp_path / "x.json").exists()


def test_camera_command_charuco(tmp_path):
    from solidkit.calibration.boards import CharucoTarget, render_board

    K = np.array([[400.0, 0, 321.0], [0, 400.0, 238.5], [0, 0, 1]])
    Ki = np.linalg.inv(K)
    target = CharucoTarget((7, 5))
    rng = np.random.default_rng(2)
    paths = []
    for i in range(6):
        R, _ = cv2.Rodrigues(rng.uniform(-0.45, 0.45, 3))
        t = -R @ np.array([3.5, 2.5, 0.0]) + np.array([*rng.uniform(-1, 1, 2), 9.0])
        img = render_board(
            lambda x, y: np.stack([x, y, np.ones_like(x)], -1) @ Ki.T,
            (640, 480),
            R,
            t,
            target.pattern,
            texture=target.texture(48),
        )
        cv2.imwrite(str(tmp_path / f"c{i}.png"), img)
        paths.append(tmp_path / f"c{i}.png")
    out = _ok(["camera", *paths, "--charuco", "7x5", "-o", tmp_path / "cam.json"])
    assert "charuco" in out
    prof = load_calibration_profile(tmp_path / "cam.json")
    Kf = prof.matrix()
    # measured: f +0.3 %, centre off by (-0.63, +0.87) px, RMS 0.11 px (small board, 48 px/square texture)
    assert abs(Kf[0, 0] / 400 - 1) < 0.01 and abs(Kf[0, 2] - 321.0) < 1.5 and abs(Kf[1, 2] - 238.5) < 1.5
    r = runner.invoke(
        app,
        [
            "calibrate",
            "camera",
            *map(str, paths),
            "--charuco",
            "7x5",
            "--pattern",
            "6x4",
            "-o",
            str(tmp_path / "x.json"),
        ],
    )
    assert r.exit_code != 0 and "exactly one of --pattern" in str(r.exception)
