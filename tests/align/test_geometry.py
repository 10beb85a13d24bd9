"""align.geometry and align.heading on synthetic rays with a known answer (and outliers)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit.align.features import rays_from_pixels
from solidkit.align.geometry import estimate_level_pose, estimate_rotation
from solidkit.align.heading import fuse_cues, refine_focal
from solidkit.align.schema import Cue, body_to_pano, level_to_pano, wrap_deg
from solidkit.envmap.coords import angles_from_direction, direction_from_angles, rotation_from_ypr, rotation_y


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _angle_deg(R1: np.ndarray, R2: np.ndarray) -> float:
    c = (np.trace(R1.T @ R2) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def test_rotation_with_outliers() -> None:
    rng = np.random.default_rng(1)
    R = np.asarray(rotation_from_ypr(math.radians(123.0), math.radians(-7.0), math.radians(2.0)))
    a = _unit(rng.normal(size=(60, 3)))
    b = a @ R.T + rng.normal(scale=math.radians(0.05), size=(60, 3))
    b[:25] = _unit(rng.normal(size=(25, 3)))  # 40 % outliers
    fit = estimate_rotation(a, _unit(b))
    assert fit is not None
    assert _angle_deg(fit.R, R) < 0.05
    assert fit.inliers[25:].all() and fit.inliers[:25].sum() <= 1


def test_rotation_refuses_noise() -> None:
    rng = np.random.default_rng(2)
    assert estimate_rotation(_unit(rng.normal(size=(30, 3))), _unit(rng.normal(size=(30, 3)))) is None


@pytest.mark.parametrize("yaw_deg", [37.0, -150.0])
def test_level_pose_recovers_yaw_and_direction(yaw_deg: float) -> None:
    """Two level panoramas 6 m apart see 80 points (30 % outliers): yaw to 0.05 deg, baseline direction, its sign."""
    rng = np.random.default_rng(3)
    pts = np.c_[rng.uniform(-20, 20, 80), rng.uniform(-8, 2, 80), rng.uniform(-20, 20, 80)]
    c1, c2 = np.zeros(3), np.array([4.0, 0.3, 4.5])
    R2 = np.asarray(rotation_y(math.radians(yaw_deg)))  # view 2's frame: x_2 = R2 (x_world - c2)
    a = _unit(pts - c1)
    b = _unit((pts - c2) @ R2.T)
    b = _unit(b + rng.normal(scale=math.radians(0.03), size=b.shape))
    b[:24] = _unit(rng.normal(size=(24, 3)))
    fit = estimate_level_pose(a, b)
    assert fit is not None
    assert abs(math.degrees(fit.yaw) - yaw_deg) < 0.05
    assert np.degrees(np.arccos(np.clip(fit.centre2_in_1 @ _unit(c2), -1, 1))) < 1.0
    assert fit.inliers[24:].mean() > 0.95


def test_level_pose_needs_matches() -> None:
    rng = np.random.default_rng(4)
    assert estimate_level_pose(_unit(rng.normal(size=(5, 3))), _unit(rng.normal(size=(5, 3)))) is None


def test_focal_refinement() -> None:
    """Pixels made with f = 560 px, rays computed with a 3 % too long focal length: the scale comes back."""
    rng = np.random.default_rng(5)
    K_true = np.array([[560.0, 0, 319.5], [0, 560.0, 239.5], [0, 0, 1]])
    px = np.c_[rng.uniform(0, 640, 50), rng.uniform(0, 480, 50)]
    R = np.asarray(rotation_from_ypr(0.4, -0.1, 0.02))
    targets = rays_from_pixels(px, K_true) @ R.T
    K_exif = K_true.copy()
    K_exif[0, 0] *= 1.03
    K_exif[1, 1] *= 1.03
    s, rms = refine_focal(px, targets, K_exif)
    assert abs(s * 1.03 - 1.0) < 1e-3
    assert rms < 1e-4


def test_heading_convention() -> None:
    """conventions §8: a feature at azimuth a in the level frame is at a + yaw in the photo frame."""
    d = direction_from_angles(math.radians(10.0), math.radians(20.0))
    az, el = (math.degrees(float(v)) for v in angles_from_direction(level_to_pano(30.0) @ d))
    assert az == pytest.approx(40.0) and el == pytest.approx(20.0)
    R = body_to_pano(30.0, 2.0, -1.0)
    assert np.allclose(R, np.asarray(rotation_from_ypr(*np.radians([30.0, 2.0, -1.0]))))


def test_fuse_cues_flags_the_odd_one() -> None:
    cues = {
        "features": Cue(yaw_deg=10.1, sigma_deg=0.2, ok=True),
        "sun": Cue(yaw_deg=9.8, sigma_deg=0.3, ok=True),
        "compass": Cue(yaw_deg=100.0, sigma_deg=8.0, ok=True),
    }  # a probe rotated 90 deg by mistake
    f = fuse_cues(cues)
    assert abs(f.yaw_deg - 10.0) < 0.15
    assert not cues["compass"].ok and cues["features"].ok and cues["sun"].ok
    assert any(fl.startswith("compass_disagrees") for fl in f.flags)
    assert cues["compass"].residual_deg == pytest.approx(wrap_deg(100.0 - f.yaw_deg))


def test_fuse_cues_single_and_none() -> None:
    f = fuse_cues({"compass": Cue(yaw_deg=-170.0, sigma_deg=8.0, ok=True), "features": Cue(yaw_deg=None, ok=False)})
    assert f.yaw_deg == pytest.approx(-170.0) and any(x.startswith("single_cue") for x in f.flags)
    assert fuse_cues({"features": Cue(yaw_deg=None, ok=False)}).yaw_deg is None
    # across the seam
    f = fuse_cues({"a": Cue(yaw_deg=179.9, sigma_deg=0.2, ok=True), "b": Cue(yaw_deg=-179.9, sigma_deg=0.2, ok=True)})
    assert abs(wrap_deg(f.yaw_deg - 180.0)) < 0.01


def test_level_pose_ignores_the_vertical_baseline_degeneracy() -> None:
    """Mismatches with equal azimuths at the wrong yaw (repeated facades) fit a vertical baseline at any elevation.

    A camera 1.5 m above the ground and a probe 6 m away: 14 true matches at yaw 170 deg; 18 mismatches whose
    azimuths agree at yaw -10 deg, elevations random (seen in mini4 seed 3 scene04/p01: 180 deg off, t 82 deg
    steep). The baseline's elevation is bounded (60 deg by default), so the true pose wins.
    """
    rng = np.random.default_rng(11)
    yaw_true = math.radians(170.0)
    pts = np.c_[rng.uniform(-15, 15, 14), rng.uniform(-6, 0.5, 14), rng.uniform(-15, 15, 14)]
    c1, c2 = np.array([0.0, -1.5, 0.0]), np.array([5.7, -0.1, 0.4])
    R2 = np.asarray(rotation_y(yaw_true))
    a_true = _unit(pts - c1)
    b_true = _unit((pts - c2) @ R2.T)
    a_bad = _unit(np.c_[rng.normal(size=18), rng.uniform(-0.3, 0.3, 18), rng.normal(size=18)])
    az, _ = angles_from_direction(a_bad @ np.asarray(rotation_y(yaw_true - math.pi)).T)
    b_bad = direction_from_angles(az, np.radians(rng.uniform(-20, 30, 18)))
    a, b = np.r_[a_true, a_bad], np.r_[b_true, b_bad]
    free = estimate_level_pose(a, b, max_baseline_elevation=None)
    assert free is not None and abs(wrap_deg(math.degrees(free.yaw) - 170.0)) > 90.0  # the degenerate answer
    fit = estimate_level_pose(a, b)
    assert fit is not None
    assert abs(wrap_deg(math.degrees(fit.yaw) - 170.0)) < 0.1
    assert np.degrees(np.arccos(np.clip(fit.centre2_in_1 @ _unit(c2 - c1), -1, 1))) < 10.0  # (not 82 deg steep)


def test_level_pose_baseline_sigma_is_calibrated() -> None:
    """The baseline direction's sigma (``t_sigma``) covers its actual error: street-like points, 0.05 deg noise."""
    rng = np.random.default_rng(12)
    z = []
    for _ in range(6):
        pts = np.c_[rng.uniform(-15, 15, 60), rng.uniform(-6, 0.5, 60), rng.uniform(-15, 15, 60)]
        c2 = np.array([rng.uniform(3, 8), 1.4, rng.uniform(-3, 3)])
        R2 = np.asarray(rotation_y(rng.uniform(-math.pi, math.pi)))
        a = _unit(
            pts + rng.normal(scale=math.radians(0.05), size=pts.shape) * np.linalg.norm(pts, axis=1, keepdims=True)
        )
        b = _unit((pts - c2) @ R2.T)
        fit = estimate_level_pose(a, b)
        assert fit is not None and fit.t_support >= 20 and math.isfinite(fit.t_sigma)
        err = float(np.arccos(np.clip(fit.centre2_in_1 @ _unit(c2), -1.0, 1.0)))
        z.append(err / fit.t_sigma)
        assert math.degrees(fit.t_sigma) < 2.0
    assert np.median(z) < 2.0 and max(z) < 5.0


@pytest.mark.parametrize("n_points, weak", [(14, True), (40, False)])
def test_feature_cue_from_few_inliers_is_weak(n_points: int, weak: bool) -> None:
    """A level pose from fewer than 18 inliers gets a sigma of at least 2 deg (measured: 2.0-2.8 deg errors in
    4 of 5 such fits on virtual campaigns), so that the sun outweighs it; 18+ inliers keep the fit's own."""
    from solidkit.align.features import Features
    from solidkit.align.heading import feature_cue

    rng = np.random.default_rng(13)
    pts = np.c_[rng.uniform(-15, 15, n_points), rng.uniform(-6, 0.5, n_points), rng.uniform(-15, 15, n_points)]
    c2 = np.array([5.0, 1.4, 2.0])
    R2 = np.asarray(rotation_y(math.radians(25.0)))
    a, b = _unit(pts), _unit((pts - c2) @ R2.T)
    desc = rng.normal(size=(n_points, 128)).astype(np.float32)
    cam = Features(a, desc, np.zeros((n_points, 2)), np.full(n_points, 0.01))
    other = Features(b, desc, np.zeros((n_points, 2)), np.full(n_points, 0.01))
    cue, fit = feature_cue(cam, other, 0.0, 0.0)
    assert fit is not None and fit.n_inliers == n_points
    assert abs(wrap_deg(cue.yaw_deg + 25.0)) < 0.05
    assert (cue.sigma_deg >= 2.0) == weak
