"""Capture metadata: EXIF/GPano/Ricoh maker note on the real Theta S still, odd files, fuzzing."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from solidkit.camera.metadata import (
    RICOH_TO_OURS,
    CaptureMetadata,
    _read_metadata_bytes,
    gravity_from_pitch_roll,
    level_rotation,
    pitch_roll_from_gravity,
    read_metadata,
)
from solidkit.envmap.coords import rotation_from_ypr
from solidkit.errors import InputError

JOBSITE = "theta_s_equirect/Jobsite1.JPG"


def _header(real_data, n: int = 70000) -> bytes:
    """The first ``n`` bytes of Jobsite1.JPG: SOI, the EXIF APP1 (61.5 kB), the XMP APP1, DQT, SOF."""
    return (real_data / JOBSITE).read_bytes()[:n]


@pytest.mark.real
def test_jobsite_theta_fields(real_data):
    m = read_metadata(real_data / JOBSITE)
    assert (m.width, m.height) == (5376, 2688)
    assert m.make == "RICOH" and m.model == "RICOH THETA S"
    assert m.exposure_time == pytest.approx(1 / 500) and m.f_number == 2.0 and m.iso == 100
    assert m.datetime_original.isoformat() == "2015-01-01T00:01:28"
    assert m.image_type == "equirect" and m.zenith_corrected is False
    # maker-note zenith angles agree with the GPano pose written by the same camera
    assert m.pitch_deg == pytest.approx(m.gpano["PosePitchDegrees"]) == pytest.approx(-0.5)
    assert m.roll_deg == pytest.approx(m.gpano["PoseRollDegrees"]) == pytest.approx(0.7)
    assert m.heading_deg == pytest.approx(90.0)
    assert m.gpano["ProjectionType"] == "equirectangular" and m.gpano["FullPanoWidthPixels"] == 5376
    assert any(w.startswith("clock_unset") for w in m.warnings)
    g = np.array(m.gravity)
    assert np.linalg.norm(g) == pytest.approx(1.0) and g[2] < -0.999  # nearly upright: gravity ~ -Z (Ricoh)


def test_gravity_frames_round_trip():
    for pitch, roll in [(0.0, 0.0), (0.3, -0.2), (-1.0, 2.0), (0.01, 0.02)]:
        g = gravity_from_pitch_roll(pitch, roll)
        assert np.allclose(pitch_roll_from_gravity(g), (pitch, roll))
        # the level frame maps the camera's gravity to +y (down) in ours
        R = np.asarray(rotation_from_ypr(0.0, pitch, roll))
        assert np.allclose(R @ (RICOH_TO_OURS @ g), [0, 1, 0])
    # tilting the front lens up: gravity gets a component toward the rear lens (-Y in Ricoh axes)
    assert gravity_from_pitch_roll(0.2, 0.0)[1] < 0
    # roll > 0 = right side down: gravity toward +X (right)
    assert gravity_from_pitch_roll(0.0, 0.2)[0] > 0
    m = CaptureMetadata(
        path="x", width=2, height=1, pitch_deg=10.0, roll_deg=5.0, image_type="equirect", zenith_corrected=True
    )
    assert np.allclose(level_rotation(m), np.eye(3))
    m.zenith_corrected = False
    assert np.allclose(level_rotation(m), rotation_from_ypr(0.0, math.radians(10), math.radians(5)))


def test_bad_files(tmp_path, real_data):
    empty = tmp_path / "empty.jpg"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_metadata(empty)
    with pytest.raises(InputError, match="no such file"):
        read_metadata(tmp_path / "missing.jpg")
    text = tmp_path / "notes.jpg"
    text.write_text("hello")
    with pytest.raises(InputError, match="not a JPEG"):
        read_metadata(text)
    trunc = tmp_path / "trunc.jpg"
    trunc.write_bytes(_header(real_data, 30000))  # cut inside the EXIF segment: no frame header
    with pytest.raises(InputError, match="truncated"):
        read_metadata(trunc)


def _pillow_jpeg(path, **sub_tags) -> None:
    from PIL import Image

    exif = Image.Exif()
    exif[0x0110] = "Test Cam"  # Model
    sub = exif.get_ifd(0x8769)
    for tag, val in sub_tags.items():
        sub[int(tag[1:], 16)] = val
    Image.new("RGB", (400, 300)).save(path, exif=exif)


def test_focal_geometry(tmp_path):
    """FocalLength, FocalLengthIn35mmFilm, FocalPlaneX/YResolution (per unit) and PixelX/YDimension."""
    p = tmp_path / "a.jpg"
    # 5 mm lens; 2540 px/inch = 100 px/mm; (floats are written by Pillow as DOUBLE: exifread 1-tuples)
    _pillow_jpeg(p, x920A=5.0, xA405=26, xA20E=2540.0, xA20F=1270.0, xA210=2, xA002=4000, xA003=3000, x829A=0.01)
    m = read_metadata(p)
    assert m.focal_length_mm == pytest.approx(5.0) and m.focal_length_35mm == pytest.approx(26.0)
    assert m.focal_plane_px_per_mm == pytest.approx((100.0, 50.0))
    assert (m.exif_width, m.exif_height) == (4000, 3000) and m.exposure_time == pytest.approx(0.01)
    assert m.warnings == []
    _pillow_jpeg(p, x920A=5.0, xA20E=300.0, xA210=3)  # px per cm; Y resolution absent -> X
    assert read_metadata(p).focal_plane_px_per_mm == pytest.approx((30.0, 30.0))
    _pillow_jpeg(p, x920A=0.0, xA20E=300.0, xA210=1)  # zero focal length; unit "none"
    m = read_metadata(p)
    assert m.focal_length_mm is None and m.focal_plane_px_per_mm is None
    assert any(w.startswith("bad_focal_length") for w in m.warnings)
    assert any(w.startswith("bad_focal_plane_unit") for w in m.warnings)


@pytest.mark.real
def test_dng_renamed_jpg_and_non_ricoh(tmp_path, real_data):
    dng = tmp_path / "shot.jpg"
    dng.write_bytes((real_data / "raw_dng/colorchart.dng").read_bytes())
    m = read_metadata(dng)
    assert m.file_format == "dng" and (m.width, m.height) == (1734, 1156)  # rawpy's crop size
    assert m.image_type == "perspective"
    assert any(w.startswith("bad_exposure_time") for w in m.warnings)  # the DNG's EXIF exposure is 0
    m = read_metadata(real_data / "theta_s_dualfisheye/thetaS_dualfisheye_raw_1920x1080.jpg")
    assert (m.width, m.height) == (1920, 1080) and m.image_type == "unknown" and m.warnings[0].startswith("no_exif")


@pytest.mark.real
def test_makernote_edits_change_fields(real_data):
    """Editing the RICOH THETA IFD bytes changes exactly the decoded fields (the parser reads the bytes)."""
    data = bytearray(_header(real_data))
    tiff = 12  # after SOI, APP1 marker+length, "Exif\0\0"
    theta_ifd = tiff + 1398  # measured: maker note 0x4001 -> 1398 (TIFF-relative)
    n = struct.unpack(">H", data[theta_ifd : theta_ifd + 2])[0]
    for i in range(n):
        p = theta_ifd + 2 + 12 * i
        tag = struct.unpack(">H", data[p : p + 2])[0]
        if tag == 0x0001:
            data[p + 8 : p + 10] = struct.pack(">H", 2)  # image type -> dual-fisheye
        if tag == 0x0007:
            data[p + 8 : p + 10] = struct.pack(">H", 1)  # zenith correction applied
        if tag == 0x0003:
            off = tiff + struct.unpack(">I", data[p + 8 : p + 12])[0]
            data[off : off + 16] = struct.pack(">iiii", -30, 10, 25, 10)  # roll -3.0, pitch 2.5
    m = _read_metadata_bytes(bytes(data), "edited")
    assert m.image_type == "dual_fisheye" and m.zenith_corrected is True
    assert (m.roll_deg, m.pitch_deg) == (pytest.approx(-3.0), pytest.approx(2.5))


def _mutate(data: bytes, edits: list[tuple[int, int]], cut: int | None) -> bytes:
    buf = bytearray(data)
    for pos, val in edits:
        buf[pos % len(buf)] = val
    return bytes(buf[:cut] if cut else buf)


@pytest.mark.real
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    edits=st.lists(st.tuples(st.integers(2, 63300), st.integers(0, 255)), min_size=1, max_size=12),
    cut=st.one_of(st.none(), st.integers(1, 63300)),
    hot=st.booleans(),
)
@example(edits=[(157, 5)], cut=None, hot=False)  # found by this test: the EXIF pointer's type mangled to RATIONAL
def test_fuzz_mutated_real_header(real_data, edits, cut, hot):
    """Bytes flipped in (and cuts through) the real APP1 segments: warnings or InputError, nothing else."""
    data = _header(real_data)
    if hot:  # aim at the EXIF IFDs and the Ricoh maker note (TIFF offsets 0..2200)
        edits = [(12 + p % 2200, v) for p, v in edits]
    mutated = _mutate(data, edits, cut)
    try:
        m = _read_metadata_bytes(mutated, "fuzz")
    except InputError:
        return
    assert isinstance(m, CaptureMetadata) and m.width > 0 and m.height > 0
    for v in (m.exposure_time, m.f_number, m.iso, m.focal_length_mm, m.focal_length_35mm, m.exif_width, m.exif_height):
        assert v is None or (math.isfinite(v) and v > 0)
    assert m.focal_plane_px_per_mm is None or all(math.isfinite(v) and v > 0 for v in m.focal_plane_px_per_mm)
    assert m.gravity is None or abs(np.linalg.norm(m.gravity) - 1) < 1e-6
    assert all(isinstance(w, str) and ":" in w for w in m.warnings)


@pytest.mark.real
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    edits=st.lists(st.tuples(st.integers(0, 4095), st.integers(0, 255)), min_size=1, max_size=12),
    cut=st.one_of(st.none(), st.integers(1, 8192)),
)
def test_fuzz_mutated_dng_header(real_data, edits, cut):
    """Bytes flipped in the real DNG's TIFF header and IFDs (first 4 KiB), or the file cut short."""
    data = (real_data / "raw_dng/colorchart.dng").read_bytes()
    mutated = _mutate(data, edits, cut)
    try:
        m = _read_metadata_bytes(mutated, "fuzz.dng")
    except InputError:
        return
    assert m.width > 0 and m.height > 0
    assert all(isinstance(w, str) and ":" in w for w in m.warnings)


@pytest.mark.real
def test_cli_capture_info(real_data, tmp_path, cli):
    import json

    run = cli
    code, out, _ = run("capture", "info", str(real_data / JOBSITE), "--json")
    assert code == 0
    data = json.loads(out.strip().splitlines()[-1])
    assert data["image_type"] == "equirect" and data["pitch_deg"] == -0.5 and data["roll_deg"] == 0.7
    code, out, _ = run("capture", "info", str(real_data / JOBSITE))
    assert code == 0 and "RICOH THETA S" in out and "[roll, pitch]" in out
    bad = tmp_path / "zero.jpg"
    bad.write_bytes(b"")
    code, _, err = run("capture", "info", str(bad))
    assert code == 2 and "empty file" in err and "Traceback" not in err


def _gps_jpeg(path, local: str, offset: str | None, gps_date: str, gps_time: tuple[float, float, float]) -> None:
    """A Pillow JPEG with DateTimeOriginal (+ OffsetTimeOriginal) and a GPS IFD with its UTC time."""
    from PIL import Image

    exif = Image.Exif()
    exif[0x0110] = "Phone"
    sub = exif.get_ifd(0x8769)
    sub[0x9003], sub[0x829A] = local, 0.01
    if offset is not None:
        sub[0x9011] = offset
    gps = exif.get_ifd(0x8825)
    gps.update({1: "N", 2: (48.0, 12.0, 0.0), 3: "E", 4: (16.0, 24.0, 0.0), 7: gps_time, 29: gps_date})
    Image.new("RGB", (64, 48)).save(path, exif=exif)


@pytest.mark.parametrize(
    "local, offset, gps_time, flagged",
    [
        ("2024:06:01 12:00:00", "+02:00", (10.0, 0.0, 30.0), False),  # the fix 30 s later: within tolerance
        ("2024:06:01 13:00:00", "+02:00", (10.0, 0.0, 0.0), True),  # the clock an hour fast
        ("2024:06:01 12:03:00", "+02:00", (10.0, 0.0, 0.0), True),  # three minutes off
        ("2024:06:01 12:00:00", None, (10.0, 0.0, 40.0), False),  # no offset: two whole hours is a zone
        ("2024:06:01 12:20:00", None, (10.0, 0.0, 0.0), True),  # no offset: 2 h 20 min is no zone
    ],
)
def test_gps_time_checks_the_photo_clock(tmp_path, local, offset, gps_time, flagged):
    p = tmp_path / "photo.jpg"
    _gps_jpeg(p, local, offset, "2024:06:01", gps_time)
    m = read_metadata(p)
    assert m.gps is not None and m.gps["lat_deg"] == pytest.approx(48.2)
    clock = [w for w in m.warnings if w.startswith("clock_mismatch")]
    assert bool(clock) == flagged, m.warnings
    assert not [w for w in m.warnings if not w.startswith("clock_mismatch")]
    if flagged:
        assert "GPS time 2024-06-01 10:00:00 UTC" in clock[0]
