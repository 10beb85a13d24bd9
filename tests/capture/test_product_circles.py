"""The lens-circle check of an HDR product (``profile_mismatch``) judges the bracket's frames, not the merge."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from solidkit.camera.lens import profile_for_metadata
from solidkit.capture.campaign import ingest
from solidkit.capture.manifest import load_manifest
from solidkit.capture.products import make_product, planned_products, record_profile

MINI_CAM = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "campaign_mini" / "card" / "scene01"


@pytest.mark.parametrize(("shift", "flagged"), [(0.03, False), (0.10, True)])
def test_an_hdr_product_is_judged_on_its_lit_frame(tmp_path: Path, shift: float, flagged: bool) -> None:
    """A per-unit profile whose back lens sits ``shift`` x its radius right of the frames' circle: within the
    check's 5 % it is the right unit and the product says nothing (on the merged HDR the fit landed 20 px left of
    the circle, where the merge's dark surround holds the estimated curve's reading of noise codes, and 3 % was
    flagged); at 10 % it is flagged, naming the lens."""
    card = tmp_path / "card" / "scene01"
    for sub in ("cam", "photo"):
        shutil.copytree(MINI_CAM / sub, card / sub)
    shutil.copy(MINI_CAM / "fieldnotes.toml", card)
    camp = tmp_path / "campaign"
    ingest(tmp_path / "card", camp, products=False)
    manifest = load_manifest(camp)
    product = next(p for p in planned_products(manifest) if p.kind == "hdr" and p.probe == "cam")
    shots = [manifest.shot(s).model_dump(mode="json") for s in product.inputs]
    md = shots[0]["metadata"]
    prof = profile_for_metadata(md["model"], md["width"], md["height"])
    back = prof.lenses[1]
    moved = prof.model_copy(
        update={
            "lenses": [
                prof.lenses[0],
                back.model_copy(update={"center": (back.center[0] + shift * back.max_radius(), back.center[1])}),
            ]
        }
    )
    (tmp_path / "unit.json").write_text(moved.model_dump_json())
    rec = dict(product.recipe, lens_profile=record_profile(camp, tmp_path / "unit.json", "lens"))
    unit = product.model_copy(update={"recipe": rec}).model_dump(mode="json")
    built = make_product(unit, shots, str(camp), manifest.response)
    assert built["error"] is None
    warnings = [w for w in built["stats"]["warnings"] if w.startswith("profile_mismatch")]
    assert [w.split(":")[1].strip() for w in warnings] == (["lens 1"] if flagged else []), warnings
