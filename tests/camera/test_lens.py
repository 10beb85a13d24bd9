"""Lens profiles: format, Ricoh tables, projection round trips, cv2.fisheye equivalence, scaling."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from solidkit.camera.lens import (
    LensModel,
    LensProfile,
    LensProfileError,
    list_profiles,
    load_profile,
    profile_for_metadata,
    project,
    unproject,
)


def _random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def test_shipped_profiles_load_and_cite():
    names = list_profiles()
    assert {"theta-v", "theta-z1", "theta-s", "theta-s-video"} <= set(names)
    for name in names:
        p = load_profile(name)
        assert p.format_version == 1 and p.kind == "lens" and p.model == name and p.source
        assert len(p.lenses) == 2 and p.lenses[0].ypr_deg[0] == 0 and abs(p.lenses[1].ypr_deg[0]) > 170


@pytest.mark.parametrize("name", ["theta-v", "theta-z1"])
def test_polynomial_reproduces_ricoh_table(name):
    """The odd polynomial matches Ricoh's published design table (0.1-px rounding) at every degree."""
    lens = load_profile(name).lenses[0]
    t = np.radians(lens.table.theta_deg)
    err = np.abs(lens.radius(t) - np.asarray(lens.table.r_px))
    assert err.max() < 0.2
    # spot values straight from the published tables
    known = {"theta-v": {90: 1262.9, 100: 1349.3}, "theta-z1": {90: 1708.8, 100: 1823.7}}[name]
    for deg, px in known.items():
        assert lens.radius(math.radians(deg)) == pytest.approx(px, abs=0.2)


@pytest.mark.parametrize("name", ["theta-v", "theta-z1", "theta-s-video"])
def test_project_unproject_round_trip(name):
    prof = load_profile(name)
    d = _random_dirs(5000)
    for lens in prof.lenses:
        x, y, theta = project(lens, d)
        inside = theta <= math.radians(lens.max_angle_deg)
        d2, theta2 = unproject(lens, x[inside], y[inside])
        assert np.abs(d2 - d[inside]).max() < 1e-9
        assert np.abs(theta2 - theta[inside]).max() < 1e-9
    # the lens axis lands on the centre; a direction at 90 deg lands at r(90 deg)
    front = prof.lenses[0]
    x, y, _ = project(front, np.array([0.0, 0.0, 1.0]))
    assert (float(x), float(y)) == pytest.approx(front.center)
    x, y, _ = project(
        front, np.array([1.0, 0.0, 0.0])
    )  # camera right -> image right of centre (turned by the lens roll)
    ux, uy = (front.rotation.T @ np.array([1.0, 0.0, 0.0]))[:2]
    assert float(x) - front.center[0] == pytest.approx(front.radius(math.pi / 2) * ux, abs=1e-6)
    assert float(y) - front.center[1] == pytest.approx(front.radius(math.pi / 2) * uy, abs=1e-6)


def test_cv2_fisheye_equivalence():
    """A cv2.fisheye calibration (f, k1..k4) is the odd polynomial [f, f k1, f k2, f k3, f k4]."""
    f, cx, cy = 300.0, 500.0, 400.0
    D = np.array([0.01, -0.002, 0.0005, -0.0001])
    lens = LensModel(name="front", center=(cx, cy), poly=[f, *(f * D)], max_angle_deg=85.0)
    d = _random_dirs(400, 1)
    d = d[d[:, 2] > 0.15]
    x, y, _ = project(lens, d)
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    ref, _ = cv2.fisheye.projectPoints(d[None].astype(np.float64), np.zeros(3), np.zeros(3), K, D)
    assert np.abs(np.stack([x, y], -1) - ref[0]).max() < 1e-6


def test_scaled_and_inverse_scale():
    p = load_profile("theta-v")
    s = p.scaled(2896, 1448)
    assert s.lenses[0].center == pytest.approx(((1447.5 + 0.5) / 2 - 0.5, (1447.5 + 0.5) / 2 - 0.5))
    assert s.lenses[0].radius(1.0) == pytest.approx(p.lenses[0].radius(1.0) / 2)
    back = s.scaled(5792, 2896)
    for a, b in zip(back.lenses, p.lenses):
        assert a.center == pytest.approx(b.center) and np.allclose(a.poly, b.poly)
    with pytest.raises(LensProfileError, match="aspect"):
        p.scaled(1920, 1080)


def test_profile_files_and_errors(tmp_path):
    p = load_profile("theta-z1")
    path = p.save(tmp_path / "unit.json")
    assert load_profile(path) == p
    data = json.loads(path.read_text())
    assert data["kind"] == "lens" and data["format_version"] == 1
    legacy = {
        ("schema_version" if k == "format_version" else k): v for k, v in data.items()
    }  # before the document base
    (tmp_path / "legacy.json").write_text(json.dumps(legacy))
    assert load_profile(tmp_path / "legacy.json") == p
    data["format_version"] = 99
    (tmp_path / "v99.json").write_text(json.dumps(data))
    with pytest.raises(LensProfileError, match="lens profile format version 99; this solidkit reads version 1"):
        load_profile(tmp_path / "v99.json")
    (tmp_path / "colour.json").write_text(json.dumps({**data, "kind": "colour"}))
    with pytest.raises(LensProfileError, match="is a 'colour' profile, expected 'lens'"):
        load_profile(tmp_path / "colour.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(LensProfileError, match="not a JSON profile"):
        load_profile(tmp_path / "bad.json")
    data = json.loads(path.read_text())
    data["lenses"][0]["poly"] = [100.0, -200.0]  # r(theta) decreasing before 100 deg
    (tmp_path / "nonmono.json").write_text(json.dumps(data))
    with pytest.raises(LensProfileError, match="not increasing"):
        load_profile(tmp_path / "nonmono.json")
    with pytest.raises(LensProfileError, match="unknown lens profile"):
        load_profile("theta-q9")
    with pytest.raises(LensProfileError, match="no such"):
        load_profile(tmp_path / "missing.json")


def test_profile_for_metadata():
    assert profile_for_metadata("RICOH THETA V", 5792, 2896).model == "theta-v"
    assert profile_for_metadata("RICOH THETA Z1", 7296, 3648).model == "theta-z1"
    with pytest.raises(LensProfileError, match="no shipped lens profile"):
        profile_for_metadata("Canon EOS 5D", 6000, 4000)
    with pytest.raises(LensProfileError):
        profile_for_metadata(None, 1920, 1080)


def test_from_table_fits_equisolid():
    """Fitting an analytic projection table (equisolid 2 f sin(theta/2)) reproduces it."""
    t = np.arange(0, 101)
    r = 2 * 600 * np.sin(np.radians(t) / 2)
    lens = LensModel.from_table("front", (0.0, 0.0), t, r)
    tt = np.radians(np.linspace(0, 100, 777))
    assert np.abs(lens.radius(tt) - 2 * 600 * np.sin(tt / 2)).max() < 1e-3
    assert isinstance(LensProfile(model="x", source="analytic", reference_size=(10, 5), lenses=[lens]), LensProfile)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_a_profile_with_a_non_finite_number_is_refused(tmp_path, literal: str) -> None:
    from solidkit.camera.lens import LensProfileError, _builtin_dir, load_profile

    doc = json.loads(_builtin_dir().joinpath("theta-v.json").read_text())
    text = json.dumps(doc).replace(json.dumps(doc["lenses"][0]["center"][0]), literal, 1)
    (tmp_path / "unit.json").write_text(text)
    with pytest.raises(LensProfileError, match=r"lenses\.0\.center\.0: Input should be a finite number"):
        load_profile(tmp_path / "unit.json")  # was accepted: a NaN centre unwarped to a blank panorama
