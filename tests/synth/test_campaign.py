"""The virtual campaign: fisheye geometry through the capture lens model, EXIF, sensor model, truth schema."""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from solidkit.camera.lens import load_profile, project  # noqa: E402
from solidkit.camera.metadata import read_metadata  # noqa: E402
from solidkit.capture.unwarp import render_fisheye  # noqa: E402
from solidkit.envmap import (
    angular_distance,
    coords_from_direction,
    direction_from_angles,  # noqa: E402
    direction_from_coords,
    rotation_from_ypr,
    rotation_y,
)
from solidkit.synth.cameras import Camera  # noqa: E402
from solidkit.synth.campaign import CampaignConfig, CampaignTruth, expose, generate_campaign, load_truth  # noqa: E402
from solidkit.synth.exif import exif_app1, insert_app1  # noqa: E402


@pytest.mark.parametrize("az,el", [(20.0, 30.0), (150.0, -10.0), (-100.0, 60.0)])
def test_fisheye_spot_lands_where_the_lens_model_says(az: float, el: float) -> None:
    h = 64
    # a direction at a pixel centre of the panorama, near (az, el)
    d = np.asarray(
        direction_from_coords(
            np.float64(np.floor((az + 180) / 360 * 2 * h) + 0.5), np.float64(np.floor((90 - el) / 180 * h) + 0.5), h
        )
    )
    pano = np.zeros((h, 2 * h, 3), np.float32)
    px, py = coords_from_direction(d, h)
    pano[int(py), int(px)] = 100.0
    profile = load_profile("theta-v").scaled(256, 128)
    Rb = np.asarray(rotation_from_ypr(math.radians(33.0), math.radians(4.0), math.radians(-3.0)))
    img = render_fisheye(pano, profile, profile.reference_size, R_level=Rb)
    d_body = Rb.T @ d
    # the lens that sees it best (smallest incidence angle)
    best = min(profile.lenses, key=lambda L: project(L, d_body)[2])
    ex, ey, theta = project(best, d_body)
    assert theta < math.radians(best.max_angle_deg)
    gy, gx = np.unravel_index(np.argmax(img.sum(-1)), img.shape[:2])
    assert abs(gx - ex) <= 2.0 and abs(gy - ey) <= 2.0, (gx, gy, ex, ey)


def test_exif_reads_back_through_capture_metadata(tmp_path: Path) -> None:
    import cv2

    ok, buf = cv2.imencode(".jpg", np.zeros((32, 64, 3), np.uint8))
    when = dt.datetime(2024, 6, 1, 12, 0, 7)
    app = exif_app1(
        make="RICOH",
        model="RICOH THETA V",
        when=when,
        exposure_time=1 / 25000,
        f_number=2.0,
        iso=64,
        gps=(48.85, -2.35, 35.0),
        theta={"image_type": 2, "roll_deg": -1.25, "pitch_deg": 3.5, "heading_deg": 271.0},
    )
    (tmp_path / "a.jpg").write_bytes(insert_app1(buf.tobytes(), app))
    m = read_metadata(tmp_path / "a.jpg")
    assert m.image_type == "dual_fisheye" and m.model == "RICOH THETA V" and not m.warnings
    assert m.exposure_time == pytest.approx(1 / 25000) and m.f_number == 2.0 and m.iso == 64
    assert (
        m.pitch_deg == pytest.approx(3.5)
        and m.roll_deg == pytest.approx(-1.25)
        and m.heading_deg == pytest.approx(271.0)
    )
    assert m.datetime_original == when
    assert m.gps["lat_deg"] == pytest.approx(48.85, abs=1e-6) and m.gps["lon_deg"] == pytest.approx(-2.35, abs=1e-6)
    app = exif_app1(
        make="SOLIDKIT",
        model="Virtual Photo Camera",
        when=when,
        exposure_time=1 / 500,
        f_number=2.8,
        iso=100,
        focal_length_mm=5.3,
        focal_35mm=31,
    )
    (tmp_path / "b.jpg").write_bytes(insert_app1(buf.tobytes(), app))
    m = read_metadata(tmp_path / "b.jpg")
    assert m.image_type == "perspective" and m.exposure_time == pytest.approx(1 / 500)
    assert m.utc_offset is None
    # an aware time: local clock + OffsetTime + UTC GPS stamps; the true heading in GPSImgDirection
    local = dt.datetime(2024, 12, 31, 19, 30, 5, tzinfo=dt.timezone(dt.timedelta(hours=-5, minutes=-30)))
    app = exif_app1(
        make="SOLIDKIT",
        model="Virtual Photo Camera",
        when=local,
        exposure_time=1 / 500,
        f_number=2.8,
        iso=100,
        gps=(-33.5, 151.25, 12.0),
        img_direction_deg=359.123456,
    )
    (tmp_path / "c.jpg").write_bytes(insert_app1(buf.tobytes(), app))
    m = read_metadata(tmp_path / "c.jpg")
    assert m.datetime_original == local.replace(tzinfo=None) and m.utc_offset == "-05:30" and not m.warnings
    tags = _exif_tags(tmp_path / "c.jpg")
    assert str(tags["GPS GPSDate"]) == "2025:01:01" and str(tags["GPS GPSImgDirectionRef"]) == "T"
    assert [float(v) for v in tags["GPS GPSTimeStamp"].values] == [1.0, 0.0, 5.0]
    assert float(tags["GPS GPSImgDirection"].values[0]) == pytest.approx(359.123456, abs=1e-6)


def _exif_tags(path: Path) -> dict:
    import exifread

    with open(path, "rb") as f:
        return exifread.process_file(f, details=False)


def _photo_sun_from_exif(path: Path) -> tuple[np.ndarray, float]:
    """The sun a user recomputes from the photo's EXIF (time + offset, GPS) with pvlib, and the EXIF true heading."""
    import pandas as pd
    import pvlib

    m = read_metadata(path)
    sign = -1 if m.utc_offset.startswith("-") else 1
    hh, mm = m.utc_offset[1:].split(":")
    tz = dt.timezone(sign * dt.timedelta(hours=int(hh), minutes=int(mm)))
    when = m.datetime_original.replace(tzinfo=tz)
    sp = pvlib.solarposition.get_solarposition(
        pd.DatetimeIndex([when]), m.gps["lat_deg"], m.gps["lon_deg"], altitude=m.gps["alt_m"]
    )
    heading = float(_exif_tags(path)["GPS GPSImgDirection"].values[0])
    az, el = float(sp["azimuth"].iloc[0]), float(sp["apparent_elevation"].iloc[0])
    return np.array([az, el]), heading


def test_sensor_model_saturates_the_sun_and_scales_with_exposure() -> None:
    rng = np.random.default_rng(0)
    rad = np.array([[[1.0, 1.0, 1.0], [0.01, 0.01, 0.01], [1e5, 1e5, 1e5]]], np.float32)
    img, jpg = expose(rad, 1 / 2500, 2.0, 100, rng)
    assert jpg[:2] == b"\xff\xd8"
    assert img[0, 2].min() == 255  # the sun saturates at 1/2500 s ...
    low, _ = expose(rad, 1 / 25000, 2.0, 64, rng)
    assert low[0, 2].min() == 255  # ... and still at 1/25000 s
    assert low[0, 0].mean() < img[0, 0].mean()  # everything else darkens
    assert 120 < img[0, 0].mean() < 180  # radiance 1 at 1/2500 s, f/2, ISO 100 -> 0.35 linear


def test_campaign_truth_round_trips(tmp_path: Path) -> None:
    cfg = CampaignConfig(
        photo_width=32,
        photo_height=24,
        photo_spp=1,
        pano_height=16,
        pano_spp=1,
        probe_height=8,
        probe_spp=1,
        fisheye_width=128,
        candidates=2,
        block_length=25.0,
        brackets_s=[1 / 640],
    )
    truth = generate_campaign(tmp_path, 1, 2, seed=3, config=cfg)
    again = load_truth(tmp_path / "truth" / "truth.json")
    assert again == truth
    assert CampaignTruth.model_validate_json(truth.model_dump_json()) == truth
    sc = truth.scenes[0]
    assert [c.id for c in sc.captures] == ["cam", "p01", "p02"]
    cam = Camera.from_json(sc.photo.camera)
    for c in sc.captures:
        Rb = np.asarray(c.R_scene_from_body)
        assert np.allclose(Rb, rotation_from_ypr(*(math.radians(a) for a in (c.yaw_deg, c.pitch_deg, c.roll_deg))))
        assert np.allclose(np.asarray(c.R_pano_from_body), np.asarray(rotation_y(cam.yaw)).T @ Rb)
        assert [s.role for s in c.shots] == ["low_exposure", "normal", "bracket"]
        for s in c.shots:
            m = read_metadata(tmp_path / s.file)
            assert m.image_type == "dual_fisheye" and (m.width, m.height) == (128, 64)
            assert m.exposure_time == pytest.approx(s.exposure_time, rel=1e-6)
            assert m.pitch_deg == pytest.approx(c.recorded_pitch_deg, abs=1e-4)
            assert m.roll_deg == pytest.approx(c.recorded_roll_deg, abs=1e-4)
            assert abs(c.recorded_pitch_deg - c.pitch_deg) < 2.0  # gravity noise 0.3° rms
        if c.probe is not None:
            assert np.allclose(cam.project(np.asarray(c.probe.point_scene)), c.probe.pixel, atol=1e-3)
            assert np.allclose(
                np.asarray(c.position) - c.probe.point_scene, 0.1 * np.asarray(c.probe.normal_scene), atol=1e-6
            )
            assert (tmp_path / c.probe.hdr_file).is_file()
    photo = read_metadata(tmp_path / sc.photo.shot.file)
    assert photo.image_type == "perspective" and photo.gps is not None
    assert sc.heading_deg == pytest.approx(math.degrees(cam.yaw) % 360.0)
    (az, el), heading = _photo_sun_from_exif(tmp_path / sc.photo.shot.file)
    assert heading == pytest.approx(sc.heading_deg, abs=1e-5)
    assert az == pytest.approx(sc.solar.azimuth_deg, abs=0.1) and el == pytest.approx(sc.solar.elevation_deg, abs=0.1)
    # the schema refuses a damaged file with a one-line error
    bad = json.loads((tmp_path / "truth" / "truth.json").read_text())
    del bad["scenes"][0]["photo"]
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    from solidkit.errors import InputError

    with pytest.raises(InputError):
        load_truth(tmp_path / "bad.json")


def _tiny(**kw: object) -> CampaignConfig:
    base = dict(
        photo_width=32,
        photo_height=24,
        photo_spp=1,
        pano_height=16,
        pano_spp=1,
        probe_height=8,
        probe_spp=1,
        fisheye_width=64,
        candidates=2,
        block_length=25.0,
        p_sunsky=1.0,
    )
    return CampaignConfig(**{**base, **kw})


def test_campaign_resumes_idempotently_and_ties_time_gps_heading_to_the_sun(tmp_path: Path, caplog) -> None:
    import logging

    from solidkit.errors import InputError

    out = tmp_path / "sim"
    truth = generate_campaign(out, 2, 2, seed=11, config=_tiny())
    # --- the sun a user recomputes from each photo's EXIF (pvlib) and heading equals the rendered sun
    for sc in truth.scenes:
        assert sc.sun_found and sc.solar.rendered
        (az, el), heading = _photo_sun_from_exif(out / sc.photo.shot.file)
        d_pano = np.asarray(direction_from_angles(np.float64(math.radians(az - heading)), np.float64(math.radians(el))))
        d_truth = np.asarray(
            direction_from_angles(
                np.float64(math.radians(sc.sun_azimuth_deg)), np.float64(math.radians(sc.sun_elevation_deg))
            )
        )
        assert math.degrees(float(angular_distance(d_pano, d_truth))) < 0.1
        # ... and in the world frame (scene frame x east, z north), from pvlib's azimuth alone
        d_world = np.array(
            [
                math.cos(math.radians(el)) * math.sin(math.radians(az)),
                -math.sin(math.radians(el)),
                math.cos(math.radians(el)) * math.cos(math.radians(az)),
            ]
        )
        assert math.degrees(math.acos(min(1.0, float(d_world @ np.asarray(sc.sun_scene))))) < 0.1
        for c in sc.captures:  # Theta shots 1-2 min later: the real sun has moved a little, and the truth says how much
            assert c.sun_drift_deg is not None and c.sun_drift_deg < 0.25 * (1 + 2 * len(sc.captures)) + 0.1
    markers = sorted(out.glob("truth/*/scene.json"))
    assert [m.parent.name for m in markers] == ["scene01", "scene02"]
    first = (out / "truth" / "truth.json").read_bytes()
    files = sorted(p for p in out.rglob("*") if p.is_file() and p.name not in ("truth.json",))
    stamps = {p: p.stat().st_mtime_ns for p in files}
    # --- killed mid-scene: scene02's marker is gone (its files stay as leftovers)
    (out / "truth" / "scene02" / "scene.json").unlink()
    seen: list[tuple[str, str]] = []
    with caplog.at_level(logging.INFO, logger="solidkit.synth.campaign"):
        again = generate_campaign(out, 2, 2, seed=11, config=_tiny(), progress=lambda s, c: seen.append((s, c)))
    assert "scene01: complete" in caplog.text and "1 scene(s) rendered, 1 complete scene(s) skipped" in caplog.text
    assert [s for s, _ in seen].count("scene01") == len(truth.scenes[0].captures)  # progress counts skipped captures
    assert (out / "truth" / "truth.json").read_bytes() == first and again == truth
    for p, t in stamps.items():
        rerendered = "scene02" in p.parts
        assert p.is_file() and (p.stat().st_mtime_ns != t) == rerendered, p
    # --- a complete campaign re-runs to a no-op
    stamps = {p: p.stat().st_mtime_ns for p in files}
    generate_campaign(out, 2, 2, seed=11, config=_tiny())
    assert all(p.stat().st_mtime_ns == t for p, t in stamps.items())
    assert (out / "truth" / "truth.json").read_bytes() == first
    # --- other settings are refused, naming them
    with pytest.raises(InputError) as err:
        generate_campaign(out, 2, 3, seed=12, config=_tiny(photo_spp=2))
    msg = str(err.value)
    assert "config.photo_spp: 1 here, 2 asked" in msg and "seed: 11 here, 12 asked" in msg and "probes" in msg
    assert "scenes:" not in msg
    (tmp_path / "other" / "card").mkdir(parents=True)
    with pytest.raises(InputError, match="no campaign.json"):
        generate_campaign(tmp_path / "other", 1, 0, seed=11, config=_tiny())


@pytest.mark.slow
def test_campaign_through_ingest_finds_the_true_sun(tmp_path: Path) -> None:
    """End to end: virtual campaign -> ``solidkit ingest`` (unwarp + level from recorded gravity) -> sun detection."""
    from solidkit.capture.campaign import ingest
    from solidkit.envmap import angular_distance, direction_from_angles, read_ldr
    from solidkit.envmap.sun import detect_sun

    cfg = CampaignConfig(
        photo_width=64,
        photo_height=48,
        photo_spp=2,
        pano_height=256,
        pano_spp=8,
        probe_height=16,
        probe_spp=2,
        fisheye_width=1024,
        candidates=4,
        p_sunsky=1.0,
    )
    truth = generate_campaign(tmp_path / "sim", 2, 2, seed=5, config=cfg)
    ingest(tmp_path / "sim" / "card", tmp_path / "campaign")
    errors = []
    for sc in truth.scenes:
        for c in sc.captures:
            if not c.sun_visible:
                continue
            det = detect_sun(read_ldr(tmp_path / "campaign" / "products" / sc.id / c.id / "sun.png", linear=True))
            if not det.found:  # e.g. a hazy sky near a low sun: the detector's contrast test, not the geometry
                continue
            expected = np.asarray(rotation_y(math.radians(c.yaw_deg))).T @ np.asarray(sc.sun_scene)
            d = np.asarray(direction_from_angles(np.float64(det.azimuth), np.float64(det.elevation)))
            errors.append(math.degrees(float(angular_distance(d, expected))))
    assert errors and max(errors) < 2.0, errors  # 0.7° pixels, 0.3° gravity noise
