"""testset export --format croissant: Croissant 1.1 metadata that mlcroissant validates and loads, card, datasheet."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from solidkit.envmap.io import read_ldr
from solidkit.fsutil import sha256_file
from solidkit.labeling.store import LabelStore
from solidkit.testset.build import build_testset, load_testset
from solidkit.testset.validate import validate_testset
from tests.support.testset_campaign import make_campaign

CLIPPED = {"sA/cam": 0.004, "sA/p01": 0.001, "sA/p02": 0.0, "sB/cam": 0.02, "sB/p01": 0.003}


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """The analytic campaign with HDR clipping in its products' stats and two annotators on one pixel."""
    root = tmp_path_factory.mktemp("campaign") / "camp"
    make_campaign(root)
    m = json.loads((root / "manifest.json").read_text())
    for p in m["products"]:
        if p["kind"] == "hdr":
            p["stats"]["saturated_in_all_frames_fraction"] = CLIPPED[f"{p['scene']}/{p['probe']}"]
    (root / "manifest.json").write_text(json.dumps(m))
    a = json.loads((root / "align" / "alignment.json").read_text())  # align read this manifest
    a["manifest_sha256"] = sha256_file(root / "manifest.json")
    (root / "align" / "alignment.json").write_text(json.dumps(a))
    store = LabelStore(root)
    store.put("probe_pixel", "sA/p01", {"x": 210.0, "y": 430.0}, source="annotator", annotator="ann")
    store.put("probe_pixel", "sA/p01", {"x": 213.0, "y": 434.0}, source="annotator", annotator="bob")
    return root


@pytest.fixture(scope="module")
def built(campaign, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ts") / "testset"
    build_testset(campaign, out)
    return out


def test_croissant_validates_and_loads(campaign, built, tmp_path, cli):
    mlc = pytest.importorskip("mlcroissant")
    out = tmp_path / "pub"
    args = ["--license", "CC-BY-4.0", "--creator", "A. Team", "--url", "https://example.org/ts"]
    args += ["--version", "1.0.0", "--cite-as", "@misc{ts}", "--date-published", "2026-12-02"]
    code, stdout, err = cli(
        "testset", "export", built, "--format", "croissant", "-o", out, "--campaign", campaign, *args
    )
    assert code == 0, err
    ts = load_testset(built)
    ds = mlc.Dataset(out / "croissant.json")  # raises on any validation error
    assert ds.metadata.ctx.issues.warnings == set()  # every recommended property given
    scenes = list(ds.records("scenes"))
    assert [r["scenes/scene_id"].decode() for r in scenes] == [s.id for s in ts.scenes]
    for r, s in zip(scenes, ts.scenes):
        assert r["scenes/sun_found"] == s.sun.found and r["scenes/probes"] == len(s.probes)
        if s.sun.found:
            assert r["scenes/sun_azimuth_deg"] == s.sun.azimuth_deg
            assert r["scenes/sun_uncertainty_deg"] == s.sun.uncertainty_deg
        assert r["scenes/fx"] == s.K[0][0] and r["scenes/pitch_deg"] == s.pitch_deg
    probes = list(ds.records("probes"))
    want = [(s.id, p.id, p.pixel) for s in ts.scenes for p in s.probes]
    got = [
        (r["probes/scene_id"].decode(), r["probes/probe_id"].decode(), (r["probes/x"], r["probes/y"])) for r in probes
    ]
    assert got == want
    assert probes[0]["probes/pixel_source"] == b"annotator"  # the label store's pixel won
    for r in probes:  # the paths resolve inside the export
        assert (out / r["probes/ldr"].decode()).is_file()
    photos = {Path(r["photos/path"].decode()).parent.name: np.asarray(r["photos/image"]) for r in ds.records("photos")}
    for s in ts.scenes:
        assert np.array_equal(photos[s.id], np.round(read_ldr(built / s.photo) * 255).astype(np.uint8))
    # per-file HDR radiometry as extension properties
    doc = json.loads((out / "croissant.json").read_text())
    assert doc["@context"]["solidkit"] == "https://solidkit/ns/dataset#"
    hdr = {o["solidkit:capture"]: o for o in doc["distribution"] if o.get("encodingFormat") == "image/x-exr"}
    assert len([o for o in doc["distribution"] if o.get("encodingFormat") == "image/x-exr"]) == 2 * len(CLIPPED)
    assert {k: o["solidkit:clippedFraction"] for k, o in hdr.items()} == CLIPPED
    for o in hdr.values():
        assert o["solidkit:radianceUnit"].startswith("relative radiance") and o["solidkit:bracketExposureTimes"]
        assert o["sha256"] == ts.files[o["contentUrl"].removeprefix("data/")].sha256
    # the test set itself, byte for byte
    assert {p.check for p in validate_testset(out / "data")} <= {"flags"}
    assert (out / "data" / "testset.json").read_bytes() == (built / "testset.json").read_bytes()
    # datasheet: Gebru et al.'s sections, the agreement of the two annotators (5 px apart)
    sheet = (out / "datasheet.md").read_text()
    for section in ("Motivation", "Composition", "Collection process", "Preprocessing, cleaning, labeling"):
        assert f"## {section}" in sheet
    for section in ("Uses", "Distribution", "Maintenance"):
        assert f"## {section}" in sheet
    assert "probe_pixel vs others: n = 1, median 5.00 px" in sheet
    assert "human annotators: ann (1), bob (1)" in sheet
    assert "HDR clipping" in sheet and "max 0.020000" in sheet
    assert "TODO(team): who captured the scenes" in sheet  # the field notes do not say: asked, not invented
    card = (out / "README.md").read_text()
    assert card.startswith("---\nlicense: CC-BY-4.0\n") and "- n<1K" in card and "- machine-generated" in card


def test_without_campaign_questions_not_inventions(built, tmp_path, cli):
    mlc = pytest.importorskip("mlcroissant")
    out = tmp_path / "pub"
    code, stdout, err = cli("testset", "export", built, "--format", "croissant", "-o", out, "--json")
    assert code == 0, err
    res = json.loads(stdout)
    assert any("licence" in q for q in res["open_questions"]) and "open: TODO(team)" in err
    ds = mlc.Dataset(out / "croissant.json")
    assert len(list(ds.records("probes"))) == sum(len(s.probes) for s in load_testset(built).scenes)
    doc = json.loads((out / "croissant.json").read_text())
    assert "license" not in doc and "creator" not in doc and doc["solidkit:openQuestions"] == res["open_questions"]
    assert not any("solidkit:clippedFraction" in o for o in doc["distribution"])  # unknown without the campaign
    sheet = (out / "datasheet.md").read_text()
    assert "TODO(team): export with --campaign for each HDR file's clipping" in sheet
    assert "license: unknown  # TODO(team)" in (out / "README.md").read_text()
    # an earlier export is replaced; anything else, or a folder inside the test set, is refused
    assert cli("testset", "export", built, "--format", "croissant", "-o", out)[0] == 0
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.txt").write_text("keep")
    code, _, err = cli("testset", "export", built, "--format", "croissant", "-o", tmp_path / "other")
    assert code == 2 and "not an earlier export" in err and (tmp_path / "other" / "x.txt").read_text() == "keep"
    code, _, err = cli("testset", "export", built, "--format", "croissant", "-o", built / "pub")
    assert code == 2 and "outside the test set" in err
    code, _, err = cli("testset", "export", built, "--format", "sold-net", "-o", tmp_path / "s", "--license", "MIT")
    assert code == 2 and "only for --format croissant" in err


def test_refuses_a_campaign_the_set_was_not_built_from(built, tmp_path, cli):
    other = tmp_path / "camp"
    make_campaign(other)
    m = json.loads((other / "manifest.json").read_text())
    m["grouping"]["scene_gap_s"] = 601.0
    (other / "manifest.json").write_text(json.dumps(m))
    code, _, err = cli("testset", "export", built, "--format", "croissant", "-o", tmp_path / "p", "--campaign", other)
    assert code == 2 and "not the manifest this test set was built from" in err and not (tmp_path / "p").exists()
