"""Photo camera: analytic K updates, resize/crop keeps projections, EXIF routes, checkerboard K."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from PIL import Image

from solidkit.calibration.boards import BoardView, board_points, detect_views, render_board
from solidkit.calibration.camera import (
    CameraProfile,
    IntrinsicsError,
    calibrate_camera_from_board,
    calibrate_camera_from_photo,
    calibrate_checkerboard,
    center_crop_box,
    crop_intrinsics,
    intrinsics_from_exif,
    resize_crop,
)
from solidkit.calibration.profile import load_calibration_profile
from solidkit.camera.metadata import CaptureMetadata, read_metadata
from solidkit.envmap.perspective import ideal_intrinsics, intrinsics_from_fov, scale_intrinsics
from solidkit.errors import InputError


def test_scale_keeps_ideal_centre_and_composes():
    K = ideal_intrinsics(1000, 600, 800.0)
    for s in (0.5, 0.32, 1.7):
        W2, H2 = 1000 * s, 600 * s
        K2 = scale_intrinsics(K, s)
        assert K2[0, 2] == pytest.approx((W2 - 1) / 2) and K2[1, 2] == pytest.approx((H2 - 1) / 2)
        assert K2[0, 0] == pytest.approx(800 * s)
    np.testing.assert_allclose(scale_intrinsics(scale_intrinsics(K, 0.5), 4.0), scale_intrinsics(K, 2.0))
    np.testing.assert_allclose(crop_intrinsics(K, 10, 20)[:2, 2], [499.5 - 10, 299.5 - 20])


def test_center_crop_box():
    assert center_crop_box(1000, 600, 4 / 3) == (100, 0, 800, 600)
    assert center_crop_box(600, 1000, 4 / 3) == (0, 275, 600, 450)
    assert center_crop_box(640, 480, 4 / 3) == (0, 0, 640, 480)


def _blob(w, h, x, y, sigma):
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * sigma**2)).astype(np.float32)


def _centroid(img):
    ys, xs = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    m = img * (img > 0.02 * img.max())
    return (m * xs).sum() / m.sum(), (m * ys).sum() / m.sum()


@pytest.mark.parametrize("size", [(1000, 600), (600, 1000), (217, 161)])
def test_projected_point_stays_on_same_pixel_after_resize_crop(size):
    w, h = size
    K = np.array([[0.9 * w, 0, 0.52 * w], [0, 0.9 * w, 0.47 * h], [0, 0, 1]])
    X = np.array([0.05, -0.03, 1.0])
    p = K @ X
    x, y = p[0] / p[2], p[1] / p[2]
    sigma = max(w, h) / 60
    img = _blob(w, h, x, y, sigma)
    out, K2, box = resize_crop(img, K)
    assert out.shape == (240, 320)
    p2 = K2 @ X
    cx, cy = _centroid(out)
    # the blob (sub-pixel position) lands where K' projects the same 3D point
    assert abs(cx - p2[0] / p2[2]) < 0.03 and abs(cy - p2[1] / p2[2]) < 0.03
    _, K3, box3 = resize_crop(None, K, image_size=(w, h))
    np.testing.assert_allclose(K3, K2)
    assert box3 == box


def _meta(**fields) -> CaptureMetadata:
    return CaptureMetadata(path="photo.jpg", **fields)


def test_fov_and_exif_routes(tmp_path):
    K = intrinsics_from_fov(math.radians(90), 640, 480)
    assert K[0, 0] == pytest.approx(320) and K[0, 2] == pytest.approx(319.5)
    with pytest.raises(InputError):
        intrinsics_from_fov(math.radians(180), 640, 480)
    # focal-plane resolution (px/inch) recorded for a 4000-px-wide image, file resized to 2000
    info = _meta(width=2000, height=1500, focal_length_mm=4.0, focal_plane_px_per_mm=(800.0, 800.0), exif_width=4000)
    K, src = intrinsics_from_exif(info)
    assert src == "exif-focal-plane" and K[0, 0] == pytest.approx(4.0 * 800 / 2)
    info = _meta(model="Canon EOS 5D Mark II", width=640, height=426, focal_length_mm=16.0)
    K, src = intrinsics_from_exif(info)
    assert src == "exif-sensor-table" and K[0, 0] == pytest.approx(16 * 640 / 36)
    info = _meta(model="unknown phone", width=4000, height=3000, focal_length_mm=4.0, focal_length_35mm=26.0)
    K, src = intrinsics_from_exif(info)
    assert src == "exif-35mm" and K[0, 0] == pytest.approx(26 * 5000 / math.hypot(36, 24))
    with pytest.raises(IntrinsicsError, match="sensor size"):
        intrinsics_from_exif(_meta(model="unknown", width=10, height=10, focal_length_mm=4.0))


def test_exif_photo_profile_written_by_pillow(tmp_path):
    p = tmp_path / "photo.jpg"
    exif = Image.Exif()
    exif[0x0110] = "Test Cam"  # Model
    sub = exif.get_ifd(0x8769)
    sub[0x920A] = 5.0  # FocalLength
    sub[0xA20E] = 2540.0  # FocalPlaneXResolution (px per inch -> 100 px/mm)
    sub[0xA20F] = 2540.0
    sub[0xA210] = 2  # inches
    Image.new("RGB", (400, 300)).save(p, exif=exif)
    info = read_metadata(p)
    assert info.model == "Test Cam" and info.focal_plane_px_per_mm == pytest.approx((100.0, 100.0))
    assert info.focal_length_mm == pytest.approx(5.0) and not any("focal" in w for w in info.warnings)
    prof = calibrate_camera_from_photo(p)
    assert prof.source == "exif-focal-plane" and prof.matrix()[0, 0] == pytest.approx(500.0)
    assert prof.model_input_size == (320, 240) and prof.matrix(True)[0, 0] == pytest.approx(400.0)
    assert prof.hfov_deg == pytest.approx(2 * math.degrees(math.atan(200 / 500)))
    back = load_calibration_profile(prof.save(tmp_path / "camera.json"))
    assert isinstance(back, CameraProfile) and back.K == prof.K
    assert calibrate_camera_from_photo(p, fov_deg=60).source == "fov"
    png = tmp_path / "crop.png"  # no EXIF container: only the FOV route applies
    Image.new("RGB", (320, 240)).save(png)
    prof = calibrate_camera_from_photo(png, fov_deg=90)
    assert prof.image_size == (320, 240) and prof.matrix()[0, 0] == pytest.approx(160.0)
    with pytest.raises(InputError, match="not a JPEG"):
        calibrate_camera_from_photo(png)


def _pinhole_rays(K):
    Ki = np.linalg.inv(K)
    return lambda x, y: np.stack([x, y, np.ones_like(x)], -1) @ Ki.T


def _poses(n, pattern, seed=0, dist=11.0, shift=1.5, tilt=0.5):
    """Board poses looking at the board centre from ``dist`` squares, tilted and shifted."""
    rng = np.random.default_rng(seed)
    centre = np.array([(pattern[0] - 1) / 2, (pattern[1] - 1) / 2, 0.0])
    out = []
    for _ in range(n):
        R, _ = cv2.Rodrigues(rng.uniform(-tilt, tilt, 3))
        t = -R @ centre + np.array([0, 0, dist]) + rng.uniform(-shift, shift, 3) * [1, 1, 0.3]
        out.append((R, t))
    return out


def test_checkerboard_recovers_pinhole_K():
    K = np.array([[520.0, 0, 318.3], [0, 520.0, 241.6], [0, 0, 1]])
    pattern = (7, 5)
    imgs = [render_board(_pinhole_rays(K), (640, 480), R, t, pattern) for R, t in _poses(6, pattern)]
    imgs.append(np.full((480, 640), 128, np.uint8))  # no board
    imgs.append(cv2.GaussianBlur(imgs[0], (0, 0), 4.0))  # heavily blurred
    views = detect_views(imgs, pattern)
    assert "no 7x5 board" in views[-2].reason
    # measured edge widths: sharp renders 1.6-1.8 px, this blur 10.2 px
    assert views[-1].reason.startswith("blurred: edge width")
    Kf, dist, res = calibrate_checkerboard(views, pattern)
    assert abs(Kf[0, 0] / 520 - 1) < 0.005 and abs(Kf[1, 1] / 520 - 1) < 0.005
    assert abs(Kf[0, 2] - 318.3) < 0.5 and abs(Kf[1, 2] - 241.6) < 0.5
    # measured: fx 520.08, fy 520.05 (+0.02 %), centre off by (-0.34, +0.10) px, RMS 0.027 px
    assert res["rms_px"] < 0.1 and set(res["rejected_views"]) == {"view6", "view7"}


def test_board_files_profile(tmp_path):
    K = np.array([[480.0, 0, 319.5], [0, 480.0, 239.5], [0, 0, 1]])
    paths = []
    for i, (R, t) in enumerate(_poses(5, (7, 5), seed=4)):
        cv2.imwrite(str(tmp_path / f"b{i}.png"), render_board(_pinhole_rays(K), (640, 480), R, t, (7, 5)))
        paths.append(tmp_path / f"b{i}.png")
    prof = calibrate_camera_from_board(paths, (7, 5))
    assert prof.source == "checkerboard" and len(prof.dist) == 5 and prof.residuals["views_used"] == 5
    assert abs(prof.matrix()[0, 0] / 480 - 1) < 0.005 and len(prof.provenance.inputs) == 5
    # the 320x240 K is the native K scaled by 0.5 (640x480 needs no crop)
    np.testing.assert_allclose(prof.matrix(True), scale_intrinsics(prof.matrix(), 0.5))


def test_too_few_views_says_which_and_why():
    views = [
        BoardView("a.jpg", (10, 10), reason="no 7x5 board found"),
        BoardView("b.jpg", (10, 10), reason="blurred: edge width 6 px"),
    ]
    with pytest.raises(IntrinsicsError, match="a.jpg: no 7x5 board found; b.jpg: blurred"):
        calibrate_checkerboard(views, (7, 5))
    assert board_points((3, 2), 2.0)[4].tolist() == [2.0, 2.0, 0.0]


@pytest.mark.real
def test_real_frobisher_exif(real_data):
    prof = calibrate_camera_from_photo(real_data / "brackets_frobisher" / "IMG_2601.jpg")
    assert prof.source == "exif-sensor-table"  # Canon EOS 5D Mark II, 16 mm, full frame
    assert prof.matrix()[0, 0] == pytest.approx(16 * 640 / 36)
    assert prof.hfov_deg == pytest.approx(2 * math.degrees(math.atan(18 / 16)))


@pytest.mark.real
def test_real_theta_equirect_has_no_pinhole_K(real_data):
    photo = real_data / "theta_s_equirect" / "Jobsite1.JPG"
    with pytest.raises(IntrinsicsError, match="equirectangular panorama has no pinhole K"):
        calibrate_camera_from_photo(photo)
    prof = calibrate_camera_from_photo(photo, fov_deg=60)  # a perspective crop of it, rendered at 60° HFOV
    assert prof.hfov_deg == pytest.approx(60)
