"""align.manhattan: the street's horizontal vanishing azimuth from a drawn level panorama (known answer)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from solidkit.align.manhattan import line_normals, photo_line_normals, vanishing_azimuth
from solidkit.envmap.coords import coords_from_direction, direction_from_angles


def _street(az0_deg: float, h: int = 256, seed: int = 0, n_lines: int = 14) -> np.ndarray:
    """A level panorama (linear, grey) of two facades' horizontal lines along ``az0`` and ``az0 + 90`` deg,
    some vertical edges, and noise: the lines are drawn as dense polylines of their projections."""
    rng = np.random.default_rng(seed)
    img = np.full((h, 2 * h), 0.2, np.float32)
    for fam in (0.0, 90.0):
        d = np.asarray(direction_from_angles(math.radians(az0_deg + fam), 0.0))
        side = np.cross(d, [0.0, 1.0, 0.0])
        for _ in range(n_lines):
            off = side * rng.choice([-1.0, 1.0]) * rng.uniform(4.0, 12.0) + np.array([0.0, rng.uniform(-6.0, 1.2), 0.0])
            t = np.linspace(-40.0, 40.0, 4000)
            pts = off[None] + t[:, None] * d[None]
            x, y = coords_from_direction(pts / np.linalg.norm(pts, axis=1, keepdims=True), h)
            xy = np.c_[x, y] - 0.5  # continuous coordinates (pixel centres at +0.5) -> OpenCV (centres at integers)
            jump = np.abs(np.diff(xy[:, 0])) > h  # split at the seam
            for part in np.split(xy, np.nonzero(jump)[0] + 1):
                cv2.polylines(img, [np.round(part * 4).astype(np.int32)], False, 0.9, 1, cv2.LINE_AA, shift=2)
    for az in rng.uniform(0, 360, 10):  # vertical edges: carry no azimuth
        x = int((az / 360.0) * 2 * h)
        cv2.line(img, (x, h // 3), (x, h // 2), 0.6, 1)
    img += rng.normal(0.0, 0.01, img.shape).astype(np.float32)
    return np.repeat(np.clip(img, 0.0, 1.0)[..., None], 3, axis=2)


@pytest.mark.parametrize("az0", [17.3, 71.0])
def test_vanishing_azimuth_of_a_drawn_street(az0: float) -> None:
    n, length = line_normals(_street(az0), linear=False)
    fit = vanishing_azimuth(n, length)
    assert fit is not None and fit.n_segments >= 20
    err = abs(((fit.azimuth_deg - az0) + 45.0) % 90.0 - 45.0)
    assert err < 0.3, (fit, az0)
    assert fit.sigma_deg < 0.5


def test_rotating_the_panorama_moves_the_azimuth_by_the_yaw() -> None:
    """The relative yaw of two captures modulo 90 deg is the difference of their vanishing azimuths."""
    a = vanishing_azimuth(*line_normals(_street(30.0, seed=1), linear=False))
    b = vanishing_azimuth(*line_normals(_street(30.0 + 12.5, seed=2), linear=False))
    assert a is not None and b is not None
    assert abs(((b.azimuth_deg - a.azimuth_deg - 12.5) + 45.0) % 90.0 - 45.0) < 0.4


def test_no_lines_no_answer() -> None:
    rng = np.random.default_rng(3)
    flat = np.clip(0.4 + rng.normal(0.0, 0.01, (128, 256, 3)), 0, 1).astype(np.float32)
    assert vanishing_azimuth(*line_normals(flat, linear=False)) is None


def test_the_photo_gives_the_street_direction_in_its_panorama_frame() -> None:
    """A pinhole view (pitched 8 deg down, yawed 20 deg) of the drawn street: its lines, levelled by its pitch,
    give the street's vanishing azimuth in the panorama frame (mod 90 deg), the reference of the manhattan cue."""
    from solidkit.envmap.coords import rotation_from_ypr
    from solidkit.envmap.perspective import intrinsics_from_fov, perspective_crop

    pano = _street(33.0, h=1024, seed=4, n_lines=40)
    R = np.asarray(rotation_from_ypr(math.radians(20.0), math.radians(-8.0), 0.0))
    K = intrinsics_from_fov(math.radians(70.0), 640, 480)
    photo = np.clip(perspective_crop(pano, R, (640, 480), K=K), 0, 1)
    photo8 = np.round(photo * 255).astype(np.uint8)
    # the photo's rays -> its level panorama frame: the pitch/roll part of R only (its yaw is the frame's 0)
    R_level = np.asarray(rotation_from_ypr(0.0, math.radians(-8.0), 0.0))
    fit = vanishing_azimuth(*photo_line_normals(photo8, K, R_level))
    assert fit is not None
    assert abs(((fit.azimuth_deg - (33.0 - 20.0)) + 45.0) % 90.0 - 45.0) < 0.5, fit
