"""``solidkit align`` end to end on a rendered mini campaign, held against its truth (slow).

synth campaign (mini preset, 1 scene: the camera position + 3 probes, seed 7) -> ingest -> align;
then: idempotent re-run, a human heading label that wins, and injected faults (tests/support/align_faults.py).
The truth is read here only, after align ran.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import tests.support.align_faults as align_faults
from solidkit.align.evaluate import evaluate, summary
from solidkit.align.pipeline import align_campaign
from solidkit.align.schema import load_alignment, wrap_deg

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> tuple[Path, Path]:
    """synth campaign -> ingest -> align, each through the ``solidkit`` entry point (in-process)."""
    import os
    import sys

    from solidkit.cli import main

    root = tmp_path_factory.mktemp("align_mini")
    synth, camp = root / "virtual", root / "campaign"
    steps = [
        ["synth", "campaign", "--scenes", "1", "--probes", "3", "--out", str(synth), "--seed", "7", "--preset", "mini"]
    ]
    if os.environ.get(
        "SOLIDKIT_ALIGN_SYNTH"
    ):  # an already rendered virtual campaign (card/ + truth/), to save the render
        synth, steps = Path(os.environ["SOLIDKIT_ALIGN_SYNTH"]), []
    steps += [["ingest", str(synth / "card"), "-o", str(camp)], ["align", str(camp), "--json"]]
    argv = sys.argv
    try:
        for args in steps:
            sys.argv = ["solidkit", *args]
            try:
                main()
                code = 0
            except SystemExit as exc:
                code = int(exc.code or 0)
            assert code == 0, args
    finally:
        sys.argv = argv
    return camp, synth / "truth" / "truth.json"


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("labels"))
    for p in dst.rglob("*"):
        if p.is_file():
            p.chmod(0o644)
    return dst


def test_against_truth(campaign) -> None:
    camp, truth = campaign
    s = summary(evaluate(camp, truth))
    assert s["sun_false"] == 0 and s["sun_missed"] == 0, s
    assert s["sun_median_deg"] < 0.3, s  # 640-px fisheyes: 0.56 deg pixels
    assert s["yaw_all_median_deg"] < 0.5, s
    assert s["psnr_median_db"] >= 30.0, s
    assert s["psnr_median_db"] > s["psnr_compass_median_db"], s
    al = load_alignment(camp)
    sa = al.scenes[0]
    assert sa.photo.pitch_roll_source == "features" and "+features" in sa.photo.K_source
    for p in sa.probes:
        if p.role == "probe":
            assert p.pixel_source == "field_notes" and p.pixel_full is not None
            for key in ("ldr_full", "ldr_256", "hdr_256", "saturation_256"):
                assert (camp / getattr(p.products, key)).is_file()
    assert (camp / "align" / "report.html").is_file() and (camp / "align" / "report" / f"{sa.id}.png").is_file()
    from solidkit.labeling.store import LabelStore

    store = LabelStore(camp)
    assert {lab.key for lab in store.list("heading")} == {f"{sa.id}/{p.id}" for p in sa.probes if p.yaw_deg is not None}
    assert store.get("sun_scene", sa.id).source == "auto"


def test_rerun_is_idempotent_and_a_human_heading_wins(campaign, tmp_path) -> None:
    camp = _copy(campaign[0], tmp_path / "c")
    before = (camp / "align" / "alignment.json").read_text()
    products = {p: p.stat().st_mtime_ns for p in (camp / "align").rglob("ldr_full.png")}
    align_campaign(camp)
    assert (camp / "align" / "alignment.json").read_text() == before
    assert {p: p.stat().st_mtime_ns for p in (camp / "align").rglob("ldr_full.png")} == products

    from solidkit.labeling.store import LabelStore

    sa = load_alignment(camp).scenes[0]
    probe = next(p for p in sa.probes if p.role == "probe")
    store = LabelStore(camp)
    store.put("heading", f"{sa.id}/{probe.id}", {"yaw_deg": probe.yaw_deg + 5.0}, source="annotator", annotator="ann")
    sa2 = load_alignment(align_campaign(camp) and camp).scenes[0]
    p2 = sa2.probe(probe.id)
    assert p2.yaw_source == "annotator" and abs(wrap_deg(p2.yaw_deg - probe.yaw_deg - 5.0)) < 1e-9
    assert any(f.startswith("label_differs") for f in p2.flags)
    assert store.get("heading", f"{sa.id}/{probe.id}").source == "annotator"  # the auto re-run did not replace it
    recipe = json.loads((camp / "align" / sa.id / probe.id / "recipe.json").read_text())
    assert abs(recipe["recipe"]["yaw_deg"] - p2.yaw_deg) < 1e-5  # products re-made with the human yaw


def test_faults_are_flagged(campaign, tmp_path) -> None:
    camp0, truth = campaign
    sa = load_alignment(camp0).scenes[0]
    true_yaw = {r["probe"]: r["yaw_true"] for r in evaluate(camp0, truth, peers=False)["captures"]}
    seen = [c.probe for c in sa.sun.captures if c.found and c.probe != sa.camera_probe]
    assert seen, "the mini campaign's probes see the sun"
    probe = seen[0]

    camp = _copy(camp0, tmp_path / "clock")
    align_faults.shift_clock(camp, sa.id, 3.0)
    s = align_campaign(camp).scene(sa.id)
    assert any(f.startswith("ephemeris_disagrees") for f in s.sun.flags)

    camp = _copy(camp0, tmp_path / "heading")
    align_faults.rotate_heading(camp, sa.id, probe, 90.0)
    p = align_campaign(camp).scene(sa.id).probe(probe)
    assert any(f.startswith("compass_disagrees") for f in p.flags)
    assert abs(wrap_deg(p.yaw_deg - true_yaw[probe])) < 1.0

    camp = _copy(camp0, tmp_path / "occluded")
    align_faults.occlude_sun(camp, sa.id, probe)
    s = align_campaign(camp).scene(sa.id)
    cs = next(c for c in s.sun.captures if c.probe == probe)
    assert not cs.found and s.sun.found

    camp = _copy(camp0, tmp_path / "flat")
    align_faults.remove_texture(camp, sa.id, probe)
    p = align_campaign(camp).scene(sa.id).probe(probe)
    assert any(f.startswith("features_failed") for f in p.flags) and p.cues["sun"].ok
    assert abs(wrap_deg(p.yaw_deg - true_yaw[probe])) < 1.5


def test_two_fresh_runs_give_identical_alignments(campaign, tmp_path) -> None:
    """Features recomputed (no cache), RANSACs seeded: two runs write byte-identical alignment.json."""
    texts = []
    for k in range(2):
        camp = _copy(campaign[0], tmp_path / f"run{k}")
        shutil.rmtree(camp / "align")
        align_campaign(camp, labels=False, report=False)
        texts.append((camp / "align" / "alignment.json").read_text())
    assert texts[0] == texts[1]


def test_a_probe_pixel_marked_a_tenth_of_the_photo_off_is_flagged(campaign, tmp_path) -> None:
    """The field notes' pixel of a probe moved by 10 % of the photo width: the geometry check flags it."""
    camp0, _ = campaign
    sa = load_alignment(camp0).scenes[0]
    checked = [
        p for p in sa.probes if p.role == "probe" and p.pixel_geometry is not None and p.pixel_source == "field_notes"
    ]
    assert checked, "no probe with a geometric pixel check"
    assert not any(f.startswith("pixel_disagrees") for p in checked for f in p.flags)
    probe = checked[0]
    w = sa.photo.size[0]
    # move the mark away from the geometry's pixel (the check's worst case is a move towards it)
    dx = 0.1 * w * (1.0 if probe.pixel_geometry[0] <= probe.pixel_full[0] else -1.0)
    camp = _copy(camp0, tmp_path / "moved")
    align_faults.move_probe_pixel(camp, sa.id, probe.id, dx, 0.0)
    p = align_campaign(camp, report=False).scene(sa.id).probe(probe.id)
    assert any(f.startswith("pixel_disagrees") for f in p.flags), (p.pixel_error_deg, p.pixel_geometry_sigma_deg)
