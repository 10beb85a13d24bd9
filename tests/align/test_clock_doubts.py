"""A scene's clock doubt reaches what it touched: the photo's own clock off its GPS time flags every capture of
its scene and the scene's sun, in the alignment and in the test set (small analytic campaign,
tests/support/testset_campaign.py)."""

from __future__ import annotations

import json

from PIL import Image

from solidkit.align.captures import photo_shot_of
from solidkit.align.pipeline import AlignSettings, align_campaign, clock_doubts, photo_clock_mismatch
from solidkit.align.schema import load_alignment, save_alignment
from solidkit.camera.metadata import read_metadata
from solidkit.capture.manifest import load_manifest
from solidkit.flags import Flag, FlagCode, flag_codes
from solidkit.testset.build import build_testset
from solidkit.testset.schema import TestSet
from tests.support.testset_campaign import PHOTO, make_campaign

FAST = AlignSettings(products=False, feature_pitches_deg=(0.0,), refine_levelling=False, manhattan=False, links=False)
CLOCK = FlagCode.CLOCK_MISMATCH.value


def _photo_an_hour_off_its_gps_time(tmp_path) -> list[str]:
    """The metadata warnings of a photo taken at 12:00 (+02:00) whose GPS says 09:00 UTC (an hour apart)."""
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = "Canon", "EOS R"
    exif.get_ifd(0x8769).update({0x9003: "2024:06:01 12:00:00", 0x9011: "+02:00", 0x829A: 1 / 200})
    gps = {1: "N", 2: (48.0, 6.0, 0.0), 3: "E", 4: (11.0, 30.0, 0.0), 7: (9.0, 0.0, 0.0), 29: "2024:06:01"}
    exif.get_ifd(0x8825).update(gps)
    Image.new("RGB", (64, 48)).save(tmp_path / "IMG_0001.JPG", exif=exif)
    warnings = read_metadata(tmp_path / "IMG_0001.JPG").warnings
    assert [Flag.parse(w).code for w in warnings] == [CLOCK], warnings
    return warnings


def test_the_photo_clock_off_its_gps_time_flags_every_capture_and_the_sun(tmp_path) -> None:
    """Scene sA's photo clock is an hour off its own GPS time (ingest's metadata warning): align's scene flag
    names the photo, and each of sA's captures and its sun (here the ephemeris' at the photo's time) carry
    ``clock_mismatch`` too, where it used to stop at the scene."""
    camp = tmp_path / "c"
    make_campaign(camp)
    (camp / "align" / "alignment.json").unlink()
    manifest = json.loads((camp / "manifest.json").read_text())
    for shot in manifest["shots"]:  # what ingest reads from a file: its size
        size = PHOTO if shot["kind"] == "photo" else (512, 256)
        shot["metadata"].update(path=shot["original"], width=size[0], height=size[1])
        if shot["kind"] == "photo" and shot["scene"] == "sA":
            shot["metadata"]["warnings"] = _photo_an_hour_off_its_gps_time(tmp_path)
    (camp / "manifest.json").write_text(json.dumps(manifest))
    sa = align_campaign(camp, settings=FAST, labels=False, report=False).scene("sA")
    (scene_clock,) = [f for f in sa.flags if Flag.parse(f).code == CLOCK]
    assert scene_clock.startswith("clock_mismatch: photo ") and "+3600 s from the photo's GPS time" in scene_clock
    assert sa.sun.world_azimuth_deg is not None and CLOCK in flag_codes(sa.sun.flags)
    assert {p.id for p in sa.probes} == {"cam", "p01", "p02"}
    for p in sa.probes:
        (f,) = [f for f in p.flags if Flag.parse(f).code == CLOCK]
        assert "the photo's clock is off its GPS time" in f, f


def test_the_test_set_carries_clock_doubts_to_its_probes_camera_and_sun(tmp_path) -> None:
    """The alignment as align's clock step leaves it (the photo's clock an hour off in sA; capture p02 there and p01
    of sB an hour from their photos) -> the test set: every probe, camera capture and sun they touched is
    flagged, a scene with both doubts keeps both in its one ``clock_mismatch`` flag, and untouched captures are
    not flagged."""
    camp = tmp_path / "c"
    make_campaign(camp)
    manifest = load_manifest(camp)
    al = load_alignment(camp)
    for sa in al.scenes:
        shot = photo_shot_of(manifest, manifest.scene(sa.id))
        assert shot is not None
        far = ["p02"] if sa.id == "sA" else ["p01"]
        sa.flags = [*sa.flags, f"clock_mismatch: {far[0]} taken more than an hour from the photo"]
        if sa.id == "sA":
            warnings = _photo_an_hour_off_its_gps_time(tmp_path)
            shot = shot.model_copy(update={"metadata": {**shot.metadata, "warnings": warnings}})
        photo = photo_clock_mismatch(shot)
        sa.flags = clock_doubts([*sa.flags, *photo], [Flag.parse(f).detail for f in photo], far, sa.sun, sa.probes)
    save_alignment(al, camp)
    build_testset(camp, tmp_path / "ts")
    doc = TestSet.model_validate_json((tmp_path / "ts" / "testset.json").read_text())
    ts = {s.id: s for s in doc.scenes}
    a, b = ts["sA"], ts["sB"]
    assert CLOCK in flag_codes(a.flags) and CLOCK in flag_codes(a.sun.flags)
    assert a.camera is not None and CLOCK in flag_codes(a.camera.alignment.flags)
    assert [CLOCK in flag_codes(p.flags) for p in a.probes] == [True, True]
    (scene_clock,) = [f for f in a.flags if Flag.parse(f).code == CLOCK]
    assert "photo " in scene_clock and "p02 taken more than an hour" in scene_clock
    (p02_clock,) = [f for f in a.probes[1].flags if Flag.parse(f).code == CLOCK]
    assert "the photo's clock is off its GPS time" in p02_clock and "no sun drift correction here" in p02_clock
    assert [CLOCK in flag_codes(p.flags) for p in b.probes] == [p.id == "p01" for p in b.probes]
    assert b.camera is not None and CLOCK not in flag_codes(b.camera.alignment.flags)
    assert CLOCK not in flag_codes(b.sun.flags)
