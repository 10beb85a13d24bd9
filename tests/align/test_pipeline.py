"""align_campaign end to end on a small analytic campaign (tests/support/testset_campaign.py): a photo without
EXIF intrinsics, and one scene whose alignment fails while the others are kept."""

from __future__ import annotations

import json

from solidkit.align.pipeline import AlignSettings, align_campaign
from solidkit.align.schema import load_alignment
from solidkit.flags import FlagCode, flag_codes
from tests.support.testset_campaign import PHOTO, make_campaign

FAST = AlignSettings(products=False, feature_pitches_deg=(0.0,), refine_levelling=False, manhattan=False, links=False)


def test_a_photo_without_exif_and_a_failing_scene(tmp_path) -> None:
    """Scene sA's photo has no focal length in its EXIF (a 60 deg view assumed, flagged, the scene aligned); scene
    sB's sun frame is unreadable: sB is reported (``align_failed`` with the error) and sA is kept, in the
    returned alignment and in ``alignment.json`` (it was lost with the whole campaign)."""
    camp = tmp_path / "c"
    make_campaign(camp)
    (camp / "align" / "alignment.json").unlink()
    manifest = json.loads((camp / "manifest.json").read_text())
    for shot in manifest["shots"]:  # what ingest reads from a file: its size; no focal length, no sensor size
        size = PHOTO if shot["kind"] == "photo" else (512, 256)
        shot["metadata"].update(path=shot["original"], width=size[0], height=size[1])
        shot["metadata"].pop("focal_length_mm", None)
    (camp / "manifest.json").write_text(json.dumps(manifest))
    (camp / "products" / "sB" / "cam" / "sun.png").write_bytes(b"not a png")
    logged: list[str] = []
    al = align_campaign(camp, settings=FAST, labels=False, report=False, log=logged.append)
    on_disk = load_alignment(camp)
    for a in (al, on_disk):
        sa, sb = a.scene("sA"), a.scene("sB")
        assert sa.photo is not None and sa.photo.K_source == "assumed-hfov-60"
        assert FlagCode.NO_INTRINSICS.value in flag_codes(sa.flags) and len(sa.probes) == 3
        assert flag_codes(sb.flags) == [FlagCode.ALIGN_FAILED.value] and sb.photo is None and not sb.probes
        assert "sun.png: not a readable image" in sb.flags[0]
    assert any(m.startswith("sB: alignment failed, the other scenes are kept") for m in logged)
