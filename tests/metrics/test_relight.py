"""The re-rendering error (solidkit.metrics.relight): scale-invariant RMSE, SSIM of renders, shading direction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit import metrics as M
from solidkit.envmap.coords import coords_from_direction, direction_from_angles, rotation_from_ypr
from solidkit.envmap.resample import rotate

H = 64


def _spot(azimuth_deg: float, elevation_deg: float, ambient: float = 0.0) -> np.ndarray:
    """A dim constant sky plus one bright pixel (a sun) at the given direction, (H, 2H, 3)."""
    pano = np.full((H, 2 * H, 3), ambient, np.float32)
    d = direction_from_angles(math.radians(azimuth_deg), math.radians(elevation_deg))
    x, y = coords_from_direction(np.asarray(d), H)
    pano[int(y), int(x)] = 5000.0
    return pano


def test_a_spot_rotated_by_90_degrees_gives_a_90_degree_shading_error() -> None:
    """A sun up-left (azimuth -90°, elevation 45°), the map turned by 90° about the forward axis (so the sun is
    up-right): the shading directions are 90° apart, within 2° (the sun's pixel centre, 2.8° pixels)."""
    a = _spot(-90.0, 45.0, ambient=1e-4)
    R = np.asarray(rotation_from_ypr(0.0, 0.0, math.radians(90.0)))  # roll: turns the right axis downward
    b = rotate(a, R, interp="nearest")
    sa, sb = M.shading_direction(a), M.shading_direction(b)
    assert sa[0] < -0.6 and sb[0] > 0.6  # left, then right (x right)
    assert sa[1] < -0.6 and sb[1] < -0.6  # both up (y down)
    assert M.shading_angle_deg(a, b) == pytest.approx(90.0, abs=2.0)


def test_a_spot_turned_about_the_vertical_gives_the_angle_between_the_two_suns() -> None:
    """Turning the map by 90° in azimuth moves a sun at 30° elevation by acos(sin² 30°) = 75.5°."""
    a = _spot(0.0, 30.0)
    b = rotate(a, np.asarray(rotation_from_ypr(math.radians(90.0), 0.0, 0.0)), interp="nearest")
    assert M.shading_angle_deg(a, b) == pytest.approx(math.degrees(math.acos(0.25)), abs=2.0)


def test_identical_lighting_gives_zero_error() -> None:
    rng = np.random.default_rng(0)
    probe = rng.uniform(0, 3, (H, 2 * H, 3)).astype(np.float32)
    render = rng.uniform(0, 2, (32, 32, 3)).astype(np.float32)
    mask = np.zeros((32, 32), bool)
    mask[4:28, 6:30] = True
    assert M.shading_angle_deg(probe, probe) == pytest.approx(0.0, abs=1e-5)
    assert M.si_rmse(render, render, mask) == pytest.approx(0.0, abs=1e-7)
    assert M.render_ssim(render, render, mask) == pytest.approx(1.0, abs=1e-6)


def test_the_render_scores_ignore_the_overall_scale_and_the_pixels_outside_the_mask() -> None:
    rng = np.random.default_rng(1)
    truth = rng.uniform(0.1, 1, (32, 32, 3)).astype(np.float32)
    mask = np.zeros((32, 32), bool)
    mask[8:24, 8:24] = True
    other = truth.copy()
    other[~mask] = 0.0  # outside the mask: anything
    assert M.si_rmse(7.5 * other, truth, mask) == pytest.approx(0.0, abs=1e-6)
    assert M.render_ssim(7.5 * other, truth, mask) == pytest.approx(1.0, abs=1e-5)
    assert M.si_scale(7.5 * truth, truth, mask) == pytest.approx(1 / 7.5)
    assert M.si_rmse(np.zeros_like(truth), truth, mask) == pytest.approx(1.0)  # black: no better than nothing
    noisy = truth * rng.uniform(0.5, 1.5, truth.shape).astype(np.float32)
    assert 0.05 < M.si_rmse(noisy, truth, mask) < 1.0 and M.render_ssim(noisy, truth, mask) < 0.95


def test_shading_direction_sees_only_the_hemisphere_above_the_ground() -> None:
    """A uniform sky points up; a bright ground under it changes nothing (the plane hides it); no light: NaN."""
    sky = np.ones((H, 2 * H, 3), np.float32)
    ground = sky.copy()
    ground[H // 2 :] = 50.0
    np.testing.assert_allclose(M.shading_direction(sky), [0.0, -1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(M.shading_direction(ground), [0.0, -1.0, 0.0], atol=1e-6)
    dark = np.zeros_like(sky)
    assert np.isnan(M.shading_direction(dark)).all() and math.isnan(M.shading_angle_deg(dark, sky))
