"""Field notes on the card: parsed, validated, recorded in the manifest; bad notes are a per-scene error."""

from __future__ import annotations

import stat
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from solidkit.capture.campaign import ingest
from solidkit.capture.fieldnotes import FieldNotes, PhotoPose, ProbeNote, notes_text, read_notes
from solidkit.capture.manifest import load_manifest
from solidkit.errors import InputError
from solidkit.synth.exif import exif_app1, insert_app1
from tests.capture.test_ingest import make_card, write_shot

T0 = datetime(2024, 6, 1, 12, 0, 0)

NOTES = """\
fieldnotes = 1
camera_position = "cam"
photo = "IMG_0001.JPG"
notes = "square north of the station"

[photo_pose]
pitch_deg = -4.5
roll_deg = 0.25

[probes.p01]
pixel = [412.5, 388.0]
note = "asphalt, in the sun"

[probes.p02]
pixel = [30, 40]
"""


def write_photo(path: Path, heading: float | None = 213.0) -> None:
    """A 64x48 JPEG from a phone-like camera with GPS and (optionally) GPSImgDirection."""
    import io

    buf = io.BytesIO()
    Image.fromarray(np.full((48, 64, 3), 120, np.uint8)).save(buf, "JPEG", quality=90)
    app = exif_app1(
        make="Canon",
        model="EOS R",
        when=T0.replace(tzinfo=timezone(timedelta(hours=2))),
        exposure_time=1 / 200,
        f_number=2.8,
        iso=100,
        gps=(48.2, 16.4, 180.0),
        img_direction_deg=heading,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(insert_app1(buf.getvalue(), app))


def make_scene_card(root: Path, notes: str | None = NOTES, name: str = "fieldnotes.toml") -> Path:
    """One scene in the explicit layout: photo, a camera position, two probes (p02: a single 1/500 s shot)."""
    sc = root / "scene01"
    write_photo(sc / "photo" / "IMG_0001.JPG")
    for i, (pos, dt) in enumerate((("cam", 60), ("p01", 180))):
        write_shot(sc / pos / f"R00100{2 * i + 1:02d}.JPG", T0 + timedelta(seconds=dt), (1, 2500))
        write_shot(sc / pos / f"R00100{2 * i + 2:02d}.JPG", T0 + timedelta(seconds=dt + 3), (1, 25000))
    write_shot(sc / "p02" / "R0010010.JPG", T0 + timedelta(seconds=300), (1, 500))
    if notes is not None:
        (sc / name).write_text(notes)
    return root


def test_notes_fill_the_manifest(tmp_path):
    card = make_scene_card(tmp_path / "card")
    camp = tmp_path / "camp"
    report = ingest(card, camp)
    assert report.notes_read == 1 and not report.notes_errors and not report.errors
    assert "scene01/fieldnotes.toml" not in report.unrelated  # notes are not "skipped unrelated files"
    m = load_manifest(camp)
    sc = m.scene("scene01")
    probes = {p.id: p for p in sc.probes}
    assert sc.camera_probe == "cam" and probes["cam"].role == "camera"
    assert probes["p01"].role == probes["p02"].role == "probe"
    assert probes["p01"].photo_pixel == [412.5, 388.0] and probes["p01"].note == "asphalt, in the sun"
    assert probes["p02"].photo_pixel == [30.0, 40.0] and probes["p02"].note is None
    assert probes["cam"].photo_pixel is None
    assert sc.notes == "square north of the station"
    assert sc.photo == sc.photos[0]
    # heading from the photo's EXIF, pitch/roll from the notes (the photo records none)
    assert sc.photo_heading_deg == pytest.approx(213.0) and sc.photo_heading_ref == "true"
    assert (sc.photo_pitch_deg, sc.photo_roll_deg) == (-4.5, 0.25)
    assert sc.photo_pose_source == {"heading": "exif:GPSImgDirection", "pitch": "fieldnotes", "roll": "fieldnotes"}
    # the notes file is kept read-only beside the originals and referenced by the scene
    rec = m.fieldnotes[0]
    assert rec.error is None and sc.fieldnotes == rec.sha256
    kept = camp / rec.original
    assert kept.read_text() == NOTES and not kept.stat().st_mode & stat.S_IWUSR
    # a position that cannot give an HDR product or a sun frame says so, and why
    w = " | ".join(probes["p02"].warnings)
    assert "no_hdr: a single shot (1/500 s)" in w and "no_sun_frame: the shortest exposure, 1/500 s" in w
    assert not any(x.startswith(("no_hdr", "no_sun")) for x in probes["p01"].warnings + probes["cam"].warnings)
    assert {p.probe for p in m.products if p.kind == "hdr"} == {"cam", "p01"}
    assert ingest(card, camp).nothing_done  # idempotent


def test_json_notes_and_an_edit_take_effect(tmp_path):
    card = make_scene_card(
        tmp_path / "card", notes='{"fieldnotes": 1, "camera_position": "p01"}', name="fieldnotes.json"
    )
    camp = tmp_path / "camp"
    ingest(card, camp)
    sc = load_manifest(camp).scene("scene01")
    assert sc.camera_probe == "p01"  # the notes win over the folder name
    assert {p.id: p.role for p in sc.probes} == {"cam": "probe", "p01": "camera", "p02": "probe"}
    assert any(w.startswith("no_photo_pixel") for w in sc.probes[0].warnings)
    (card / "scene01" / "fieldnotes.json").write_text('{"fieldnotes": 1, "camera_position": "cam"}')
    report = ingest(card, camp)
    assert report.regrouped and load_manifest(camp).scene("scene01").camera_probe == "cam"


@pytest.mark.parametrize(
    "text, expect",
    [
        ("fieldnotes = 1\n[probes.p01]\npixle = [1, 2]\n", "probes.p01.pixle: Extra inputs are not permitted"),
        ("fieldnotes = 1\n[probes.p01]\npixel = [1, -2]\n", "pixel coordinates must be finite and >= 0"),
        ("camera_position = cam\n", "not valid TOML"),
        ("fieldnotes = 2\n", "fieldnotes: Input should be 1"),
    ],
)
def test_bad_notes_are_a_scene_error_not_a_crash(tmp_path, cli, text, expect):
    card = make_scene_card(tmp_path / "card", notes=text)
    camp = tmp_path / "camp"
    report = ingest(card, camp)
    assert len(report.notes_errors) == 1
    msg = report.notes_errors[0]
    assert msg.startswith("scene01/fieldnotes.toml: ") and expect in msg and "\n" not in msg
    m = load_manifest(camp)
    sc = m.scene("scene01")
    assert sc.fieldnotes is None and any(w.startswith("fieldnotes_invalid") and expect in w for w in sc.warnings)
    assert sc.camera_probe == "cam"  # the rest still works: the folder name marks the camera position
    assert len(m.shots) == 6 and not m.errors
    code, out, err = cli("ingest", card, "-o", tmp_path / "camp2")
    assert code == 2 and expect in out.replace("\n", "") and "field notes file(s)" in err


def test_notes_that_do_not_match_the_card_are_warnings(tmp_path):
    notes = (
        'fieldnotes = 1\ncamera_position = "nope"\nphoto = "IMG_9.JPG"\n[probes.p07]\npixel = [1, 2]\n'
        "[probes.p01]\npixel = [900, 10]\n"
    )
    camp = tmp_path / "camp"
    ingest(make_scene_card(tmp_path / "card", notes=notes), camp)
    sc = load_manifest(camp).scene("scene01")
    w = " | ".join(sc.warnings)
    assert "camera_position 'nope' has no Theta shots" in w and "notes for 'p07'" in w and "'IMG_9.JPG'" in w
    assert sc.camera_probe is None
    p01 = next(p for p in sc.probes if p.id == "p01")
    assert any("photo_pixel_outside: [900, 10] lies outside the 64x48 photo" in x for x in p01.warnings)


def test_card_level_notes_for_a_camera_card(tmp_path):
    """A camera's own DCIM card: scenes and positions come from time; a card-level file names them."""
    card = make_card(tmp_path / "card", bad=False)
    (card / "fieldnotes.toml").write_text(
        'fieldnotes = 1\n[scenes."scene-20240601-120000"]\ncamera_position = "p02"\nnotes = "first square"\n'
        '[scenes."scene-20240601-120000".probes.p01]\npixel = [10, 20]\n'
    )
    camp = tmp_path / "camp"
    ingest(card, camp)
    m = load_manifest(camp)
    sc = m.scene("scene-20240601-120000")
    assert sc.camera_probe == "p02" and sc.notes == "first square" and sc.probes[0].photo_pixel == [10.0, 20.0]
    assert any(w.startswith("no_camera_position") for w in m.scene("scene-20240601-140000").warnings)


def test_notes_text_round_trips(tmp_path):
    notes = FieldNotes(
        camera_position="cam",
        notes='say "hi"\nsecond line',
        photo_pose=PhotoPose(pitch_deg=-3.0),
        probes={"p01": ProbeNote(pixel=(1.5, 2.0), note="grass")},
    )
    p = tmp_path / "fieldnotes.toml"
    p.write_text(notes_text(notes))
    assert read_notes(p) == notes
    with pytest.raises(InputError, match="fieldnotes.toml: expected|not valid"):
        p.write_text("[[x]]\n= 1")
        read_notes(p)


@pytest.mark.parametrize("name, text", [("fieldnotes.toml", "x = {}\n"), ("fieldnotes.json", '{"x": {}}')])
def test_notes_nested_too_deep_are_one_line(tmp_path: Path, name: str, text: str) -> None:
    deep = ("[" * 100_000 + "]" * 100_000) if name.endswith(".json") else ("[" * 1200 + "]" * 1200)
    (tmp_path / name).write_text(text.replace("{}", deep))
    with pytest.raises(InputError, match=rf"^{name}: not valid {name[-4:].upper()} \(nested too deep\)$"):
        read_notes(tmp_path / name)  # RecursionError before: it aborted the whole ingest


def test_ingest_without_notes_prints_the_card_file_to_write(tmp_path, cli):
    """Once per ingest: the card-level file's path and a snippet with the scene ids; filled in, it applies."""
    card = make_card(tmp_path / "card", bad=False)
    code, out, _ = cli("ingest", card, "-o", tmp_path / "camp", "--no-products")
    assert code == 0 and out.count("scene(s) have none: write") == 1
    assert str(card / "fieldnotes.toml") in out.replace("\n", "")
    snippet = out[out.index("  fieldnotes = 1") :].splitlines()
    snippet = [ln.strip() for ln in snippet[: next(i for i, ln in enumerate(snippet) if not ln.startswith("  "))]]
    m = load_manifest(tmp_path / "camp")
    assert [ln for ln in snippet if ln.startswith("[scenes.")] == [f'[scenes."{sc.id}"]' for sc in m.scenes]
    filled = [ln.lstrip("# ").replace("[x, y]", "[10, 20]") for ln in snippet]
    (card / "fieldnotes.toml").write_text("\n".join(filled) + "\n")
    code, out, _ = cli("ingest", card, "-o", tmp_path / "camp", "--no-products")
    assert code == 0 and "scene(s) have none" not in out
    m = load_manifest(tmp_path / "camp")
    for sc in m.scenes:
        assert sc.camera_probe == sc.probes[0].id and sc.fieldnotes is not None
        assert all(p.photo_pixel == [10.0, 20.0] for p in sc.probes[1:])
        assert not any(w.startswith(("no_camera_position", "no_fieldnotes")) for w in sc.warnings)


def test_a_photo_clock_an_hour_off_its_gps_time_is_a_scene_warning(tmp_path):
    card = make_scene_card(tmp_path / "card")
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = "Canon", "EOS R"
    exif.get_ifd(0x8769).update({0x9003: "2024:06:01 13:00:00", 0x9011: "+02:00", 0x829A: 1 / 200})
    gps = {1: "N", 2: (48.0, 12.0, 0.0), 3: "E", 4: (16.0, 24.0, 0.0), 7: (10.0, 0.0, 0.0), 29: "2024:06:01"}
    exif.get_ifd(0x8825).update(gps)
    Image.new("RGB", (64, 48)).save(card / "scene01" / "photo" / "IMG_0001.JPG", exif=exif)
    camp = tmp_path / "camp"
    ingest(card, camp, products=False)
    (w,) = [w for w in load_manifest(camp).scene("scene01").warnings if w.startswith("clock_mismatch")]
    assert "photo scene01/photo/IMG_0001.JPG" in w and "+3600 s from the photo's GPS time" in w
