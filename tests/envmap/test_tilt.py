"""Residual tilt of panoramas (envmap.tilt): rendered level streets tilted by known rotations."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.envmap.coords import angular_distance, rotation_from_ypr
from solidkit.envmap.resample import rotate
from solidkit.envmap.tilt import correction_from_gravity, residual_tilt

DATA = Path(__file__).parents[1] / "data"
E_Y = np.array([0.0, 1.0, 0.0])


def _street(k: int | str) -> np.ndarray:
    """A rendered level street panorama (1024x512 sRGB, or 2048x1024 for ``"3_1024"``; the synth scene
    frame is level by construction; tests/data/make_tilt_fixtures.py)."""
    return cv2.imread(str(DATA / f"level_street_{k}.jpg"))[..., ::-1].copy()


@pytest.mark.parametrize("pitch,roll", [(0.02, -0.03), (-0.1, 0.05), (0.0, 0.0), (0.3, 1.2)])
def test_correction_levels_the_gravity(pitch, roll):
    g = np.asarray(rotation_from_ypr(0.0, pitch, roll)).T @ E_Y
    p, r = correction_from_gravity(g)
    assert np.allclose(np.asarray(rotation_from_ypr(0.0, p, r)) @ g, E_Y, atol=1e-12)
    assert (p, r) == pytest.approx((pitch, roll), abs=1e-12)


def _errors(k: int | str, tilts: list[tuple[float, float, float]]) -> list[float]:
    """Angle (deg) between the estimated and the true gravity of fixture ``k`` rotated by each (yaw, pitch, roll)."""
    level = _street(k)
    out = []
    for ypr in tilts:
        Rt = np.asarray(rotation_from_ypr(*np.radians(ypr)))
        img = level if not any(ypr) else np.clip(rotate(level.astype(np.float32), Rt, "cubic"), 0, 255).astype(np.uint8)
        est = residual_tilt(img)
        assert est.reliable, (k, ypr, est)
        true_tilt = math.degrees(math.acos(float((Rt @ E_Y) @ E_Y)))
        assert (
            abs(est.tilt_deg - true_tilt)
            <= math.degrees(float(angular_distance(np.asarray(est.gravity), Rt @ E_Y))) + 1e-9
        )
        out.append(math.degrees(float(angular_distance(np.asarray(est.gravity), Rt @ E_Y))))
    return out


def test_tilt_of_a_rendered_panorama_within_0p2_deg():
    """A level rendered street (512 px high), as is and tilted by known rotations: gravity within 0.2°
    (the goal; measured 0.08°, 0.10°, 0.07°; 0.12°, 0.24°, 0.02° with the earlier end-point
    noise model), and the reported correction levels it."""
    errors = _errors(0, [(0.0, 0.0, 0.0), (40.0, -3.2, 0.5), (75.0, 0.0, -4.0)])
    assert max(errors) < 0.2, errors
    tilted = rotate(
        _street(0).astype(np.float32),
        np.asarray(rotation_from_ypr(0.0, math.radians(2.0), math.radians(-1.0))),
        "cubic",
    )
    est = residual_tilt(np.clip(tilted, 0, 255).astype(np.uint8))
    fixed = rotate(tilted, np.asarray(rotation_from_ypr(0.0, math.radians(est.pitch_deg), math.radians(est.roll_deg))))
    assert residual_tilt(np.clip(fixed, 0, 255).astype(np.uint8)).tilt_deg < 0.25


def test_tilt_of_a_1024px_render_has_no_offset():
    """Street 3 rendered 1024 px high (tests/data/level_street_3_1024.jpg): the end-point noise model was
    0.34° off on it, level or tilted (short segments outweighed the long edges, which are vertical to
    0.01°); with the line-fit noise model every case is within 0.2° (measured 0.06-0.11°)."""
    errors = _errors("3_1024", [(0.0, 0.0, 0.0), (-60.0, 2.5, -1.5)])
    assert max(errors) < 0.2, errors


@pytest.mark.slow
def test_tilt_error_over_three_rendered_streets():
    """27 cases (3 streets x level + 8 random tilts up to 4°) at 512 px: median < 0.1°, all < 0.2° (measured:
    median 0.056°, max 0.152°; the end-point noise model: median 0.07°, max 0.28°)."""
    rng = np.random.default_rng(5)
    tilts = [(0.0, 0.0, 0.0)] + [(rng.uniform(-180, 180), rng.uniform(-4, 4), rng.uniform(-4, 4)) for _ in range(8)]
    errors = [e for k in (0, 1, 2) for e in _errors(k, tilts)]
    print(f"tilt error over {len(errors)} cases: median {np.median(errors):.3f}°, max {max(errors):.3f}°")
    assert np.median(errors) < 0.1 and max(errors) < 0.2


def test_no_structure_is_not_reliable():
    h = 256
    sky = np.linspace(0, 1, h)[:, None, None] * np.ones((h, 2 * h, 3))
    est = residual_tilt((sky * 255).astype(np.uint8))
    assert not est.reliable
    with pytest.raises(ValueError):
        residual_tilt(np.zeros((10, 10)))


def test_ricoh_roll_of_359p6_is_minus_0p4(tmp_path):
    """The maker note's [roll, pitch] in [0, 360): 359.6 means -0.4, not a bad_gravity warning."""
    import datetime as dt

    from solidkit.camera.metadata import read_metadata
    from solidkit.synth.exif import exif_app1, insert_app1

    ok, buf = cv2.imencode(".jpg", np.zeros((32, 64, 3), np.uint8))
    app = exif_app1(
        make="RICOH",
        model="RICOH THETA S",
        when=dt.datetime(2024, 6, 1, 12),
        exposure_time=1 / 500,
        f_number=2.0,
        iso=100,
        theta={"image_type": 1, "roll_deg": 359.6, "pitch_deg": 2.5},
    )
    (tmp_path / "a.jpg").write_bytes(insert_app1(buf.tobytes(), app))
    m = read_metadata(tmp_path / "a.jpg")
    assert m.roll_deg == pytest.approx(-0.4, abs=1e-6) and m.pitch_deg == pytest.approx(2.5)
    assert not [w for w in m.warnings if w.startswith("bad_gravity")]


@pytest.mark.real
def test_ricoh_stitched_still_is_not_relevelled_by_its_pose(real_data):
    """The evidence behind camera.metadata.level_rotation for Ricoh stitched stills:
    the Theta S still is measurably off level as stored, and its recorded pose makes it worse."""
    from solidkit.camera.metadata import level_rotation, read_metadata

    path = real_data / "theta_s_equirect" / "Jobsite1.JPG"
    meta = read_metadata(path)
    small = cv2.resize(cv2.imread(str(path))[..., ::-1], (2048, 1024), interpolation=cv2.INTER_AREA)
    stored = residual_tilt(small, max_height=1024)
    assert stored.reliable and stored.uncertainty_deg < 0.1 and 1.2 < stored.tilt_deg < 2.3, stored
    R_pose = np.asarray(rotation_from_ypr(0.0, math.radians(meta.pitch_deg), math.radians(meta.roll_deg)))
    posed = residual_tilt(
        np.clip(rotate(small.astype(np.float32), R_pose, "cubic"), 0, 255).astype(np.uint8), max_height=1024
    )
    assert posed.tilt_deg > stored.tilt_deg + 0.2  # applying the recorded pose makes it worse
    assert np.allclose(level_rotation(meta), np.eye(3))  # so solidkit does not apply it
