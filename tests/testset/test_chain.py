"""The chain on a virtual campaign held against its truth: synth campaign -> ingest -> label sun -> align -> testset
build.

Truth is read only here, after the test set is built. Measured: probe pixels equal the field
notes' (the team's marks, read from the card's ``fieldnotes.toml``) exactly, and their distance to
the true pixel is reported; the sun within the labeling tolerance; every aligned LDR probe
against the truth probe (exposed like the LDR, unsaturated pixels) above :data:`PSNR_MIN_DB`;
rotations against the truth's ``R_pano_from_body`` (median). Rendering takes minutes: ``slow``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import tomllib

from solidkit.envmap.coords import angular_distance
from solidkit.envmap.io import read_exr, read_ldr
from solidkit.envmap.resample import resize
from solidkit.testset.build import load_testset
from solidkit.testset.validate import validate_testset
from tests.testset.test_testset import psnr_ldr

PSNR_MIN_DB = 30.0  # align's target for aligned LDR probes
SUN_TOL_DEG = 2.0  # labeling tolerance of the sun in the photo's panorama frame
ROTATION_MEDIAN_TOL_DEG = 1.0  # rotations are reported per probe; PSNR is the per-probe criterion


def rotation_angle_deg(A, B) -> float:
    R = np.asarray(A) @ np.asarray(B).T
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def field_note_pixels(card: Path, scene: str) -> dict[str, list[float]]:
    """``{probe: [x, y]}`` marked in ``CARD/<scene>/fieldnotes.toml`` (empty without notes)."""
    path = card / scene / "fieldnotes.toml"
    if not path.is_file():
        return {}
    notes = tomllib.loads(path.read_text())
    return {pid: list(map(float, p["pixel"])) for pid, p in notes.get("probes", {}).items() if "pixel" in p}


def compare_with_truth(out: Path, truth_dir: Path, card: Path | None = None) -> dict:
    """Numbers of a built test set against a virtual campaign's truth (used by the test and for reports)."""
    ts = load_testset(out)
    res = {
        "pixel_err_px": [],
        "pixel_vs_notes_px": [],
        "sun_err_deg": [],
        "psnr_db": [],
        "rotation_err_deg": [],
        "sun_found": [],
        "probe": [],
        "flagged": [],
    }
    for s in ts.scenes:
        t = json.loads((truth_dir / s.id / "scene.json").read_text())
        notes = field_note_pixels(card, s.id) if card is not None else {}
        caps = {c["id"]: c for c in t["captures"]}
        # "no sun" is the right label when the sun was hidden from every capture (the truth's sun_visible)
        visible = t["sun_found"] and any(c.get("sun_visible", True) for c in t["captures"])
        res["sun_found"].append((s.sun.found, visible))
        if s.sun.found and t["sun_found"]:
            a = np.radians([s.sun.azimuth_deg, s.sun.elevation_deg])
            b = np.radians([t["sun_azimuth_deg"], t["sun_elevation_deg"]])
            res["sun_err_deg"].append(
                math.degrees(
                    float(
                        angular_distance(
                            *(
                                np.array([math.cos(e) * math.sin(z), -math.sin(e), math.cos(e) * math.cos(z)])
                                for z, e in (a, b)
                            )
                        )
                    )
                )
            )
        for p in s.probes:
            c = caps[p.id]
            res["probe"].append(f"{s.id}/{p.id}")
            res["flagged"].append(bool(p.flags))
            res["pixel_err_px"].append(float(np.hypot(*(np.asarray(p.pixel_full) - c["probe"]["pixel"]))))
            if p.id in notes:
                res["pixel_vs_notes_px"].append(float(np.hypot(*(np.asarray(p.pixel_full) - notes[p.id]))))
            res["rotation_err_deg"].append(rotation_angle_deg(p.rotation, c["R_pano_from_body"]))
            truth = read_exr(truth_dir.parent / c["probe"]["hdr_file"])[0][..., :3]
            truth = truth if truth.shape[0] == 128 else resize(truth, 128)
            sat = read_ldr(out / p.images.saturation)[..., 0] > 0.5
            res["psnr_db"].append(psnr_ldr(read_ldr(out / p.ldr), truth, sat))
    return res


@pytest.mark.slow
def test_chain_on_a_virtual_campaign(tmp_path, cli):
    card_root = tmp_path / "virtual"
    code, _, err = cli(
        "synth", "campaign", "--scenes", "2", "--probes", "4", "--out", card_root, "--seed", "7", "--preset", "mini"
    )
    assert code == 0, err
    camp = tmp_path / "campaign"
    code, _, err = cli("ingest", card_root / "card", "-o", camp)
    assert code == 0, err
    code, _, err = cli("label", "sun", camp)  # the automatic sun labels an annotator would review
    assert code == 0, err
    code, _, err = cli("align", camp)
    assert code == 0, err
    out = tmp_path / "testset"
    code, report, err = cli("testset", "build", camp, "-o", out, "--json")
    assert code == 0, err
    assert json.loads(report)["probes"] >= 3
    check_chain(out, card_root)


def check_chain(out: Path, virtual: Path) -> dict:
    """The chain's promises for a test set built from the virtual campaign at ``virtual`` (card/ + truth/).

    A probe below the alignment target must have been flagged for review, so that ``validate``
    (without ``--allow-flagged``) refuses the test set until a human looked at it; most probes
    must reach the target unflagged, so that this is not satisfied by flagging everything.
    """
    assert validate_testset(out, allow_flagged=True) == []
    res = compare_with_truth(out, virtual / "truth", virtual / "card")
    summary = json.dumps({k: [round(x, 3) if isinstance(x, float) else x for x in v] for k, v in res.items()})
    assert len(res["pixel_vs_notes_px"]) == len(res["pixel_err_px"]) > 0, summary
    assert max(res["pixel_vs_notes_px"]) == 0.0, summary  # the field notes' marks, exactly
    assert all(a == b for a, b in res["sun_found"]), summary
    assert all(e < SUN_TOL_DEG for e in res["sun_err_deg"]), summary
    assert float(np.median(res["rotation_err_deg"])) < ROTATION_MEDIAN_TOL_DEG, summary
    below = [
        pid
        for pid, db, flagged in zip(res["probe"], res["psnr_db"], res["flagged"])
        if db < PSNR_MIN_DB and not flagged
    ]
    assert not below, f"probes below {PSNR_MIN_DB} dB and not flagged: {below}; {summary}"
    assert float(np.median(res["psnr_db"])) > PSNR_MIN_DB, summary
    flagged = {pid for pid, f in zip(res["probe"], res["flagged"]) if f}
    strict = {f"{p.scene}/{p.message.split()[1]}" for p in validate_testset(out) if p.message.startswith("probe ")}
    assert strict == flagged, (strict, flagged)
    return res


@pytest.mark.slow
def test_chain_on_the_shipped_mini_campaign(tmp_path, cli):
    """The same chain on CAPTURE's shipped campaign (solidkit/assets/campaign_mini): no rendering, ~1 min of CPU."""
    from tests.conftest import ASSETS

    virtual = ASSETS / "campaign_mini"
    camp, out = tmp_path / "campaign", tmp_path / "testset"
    for argv in (
        ("ingest", virtual / "card", "-o", camp),
        ("label", "sun", camp),
        ("align", camp),
        ("testset", "build", camp, "-o", out),
    ):
        code, _, err = cli(*argv)
        assert code == 0, (argv, err)
    check_chain(out, virtual)
