"""testset show: what the contact sheets draw, checked on the sheet's pixels and the flags it lists."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from solidkit.testset.build import build_testset, load_testset
from solidkit.testset.show import FLAG_COLOUR, FONT, PHOTO_W, PROBE_COLOURS, flag_owners, probe_title, scene_sheet
from tests.support.testset_campaign import edit_alignment, make_campaign


@pytest.fixture(scope="module")
def flagged(tmp_path_factory):
    """The analytic campaign's test set with a flag on the camera position of sA and one on its probe p02."""
    root = tmp_path_factory.mktemp("show")
    make_campaign(root / "campaign")

    def edit(data):
        sa = next(s for s in data["scenes"] if s["id"] == "sA")
        for p in sa["probes"]:
            if p["id"] == "cam":
                p["flags"] = ["yaw_doubtful: may be more than 2 deg off: its yaw uses the scene's sun"]
            if p["id"] == "p02":
                p["flags"] = ["pixel_disagrees: 9 deg"]

    edit_alignment(root / "campaign", edit)
    build_testset(root / "campaign", root / "testset")
    return root / "testset"


def test_flags_name_their_owner_and_include_the_camera_position(flagged) -> None:
    scene = next(s for s in load_testset(flagged).scenes if s.id == "sA")
    owners = dict(flag_owners(scene))
    assert owners["camera cam"] == ["yaw_doubtful: may be more than 2 deg off: its yaw uses the scene's sun"]
    k = next(i for i, p in enumerate(scene.probes) if p.id == "p02")
    assert owners[f"{k + 1} p02"] == ["pixel_disagrees: 9 deg"]
    assert not any(o.endswith(" p01") for o in owners)
    sheet = scene_sheet(flagged, scene)
    red = np.all(np.abs(sheet[..., :3].astype(int) - FLAG_COLOUR) < 30, axis=-1)
    assert red[:, :PHOTO_W].sum() > 100  # the flag lines are drawn under the photo


def test_probe_colours_are_not_the_flag_red_and_titles_fit(flagged) -> None:
    """Probe 1's circle on the photo is drawn in its colour, which is not the flags' red; every panel title fits
    its 512-px panel and names the 320x240 pixel as such."""
    for col in PROBE_COLOURS:
        assert np.abs(np.asarray(col) - FLAG_COLOUR).sum() > 150, col
    scene = next(s for s in load_testset(flagged).scenes if s.id == "sA")
    sheet = scene_sheet(flagged, scene)
    W, H = scene.photo_full_size
    s = PHOTO_W / W
    x, y = (int(round((v + 0.5) * s - 0.5)) for v in scene.probes[0].pixel_full)
    ring = sheet[44 + y - 9 : 44 + y + 10, x - 9 : x + 10].reshape(-1, 3).astype(int)  # under the 44-px header
    assert (np.abs(ring - PROBE_COLOURS[0]).sum(axis=1) < 60).sum() > 10
    assert (np.abs(ring - FLAG_COLOUR).sum(axis=1) < 60).sum() == 0
    for k, p in enumerate(scene.probes):
        title = probe_title(scene, k)
        assert f"({p.pixel[0]:.0f},{p.pixel[1]:.0f}) of 320x240" in title
        (w, _), _ = cv2.getTextSize(title.replace(f"{p.alignment.yaw_deg:.1f}", "-179.9"), FONT, 0.5, 1)
        assert w < 512 - 8, title
