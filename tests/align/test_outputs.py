"""align's outputs on a small analytic campaign (tests/support/testset_campaign.py): report files, labels in the
store."""

from __future__ import annotations

import cv2

from solidkit.align.pipeline import _write_labels
from solidkit.align.report import write_report
from solidkit.align.schema import load_alignment
from solidkit.capture.manifest import load_manifest
from solidkit.labeling.store import LabelStore
from tests.support.testset_campaign import make_campaign


def test_report_and_labels(tmp_path) -> None:
    camp = tmp_path / "c"
    make_campaign(camp)
    al = load_alignment(camp)
    html = write_report(camp, load_manifest(camp), al)
    text = html.read_text()
    for sa in al.scenes:
        png = camp / "align" / "report" / f"{sa.id}.png"
        img = cv2.imread(str(png))
        # the photo on top, then one 512x256 panel per capture (4 px gaps)
        assert img is not None and img.shape[1] == 512 and img.shape[0] > 256 * len(sa.probes)
        assert f"report/{sa.id}.png" in text and sa.id in (camp / "align" / "report.md").read_text()

    store = LabelStore(camp)
    sa = al.scenes[0]
    _write_labels(store, sa)
    versions = {(lab.kind, lab.key): lab.version for lab in store.list()}
    assert {k for k, _ in versions} >= {"heading", "sun_scene"}
    heading = store.get("heading", f"{sa.id}/{sa.probes[1].id}")
    assert heading.source == "auto" and abs(heading.value["yaw_deg"] - sa.probes[1].yaw_deg) < 1e-9
    _write_labels(store, sa)  # idempotent: nothing new
    assert {(lab.kind, lab.key): lab.version for lab in store.list()} == versions
    key = f"{sa.id}/{sa.probes[1].id}"
    store.put("heading", key, {"yaw_deg": 12.0}, source="annotator", annotator="ann")
    _write_labels(store, sa)  # an automatic re-run never replaces the human label
    assert store.get("heading", key).source == "annotator" and store.get("heading", key).value["yaw_deg"] == 12.0


def _report_scene(tmp_path):
    """A scene with a 640x480 photo, a camera position (aligned product, its sun flagged, no alignment flag) and a
    probe whose geometric pixel lies 60 px left of the photo."""
    import numpy as np

    from solidkit.align.schema import (
        CaptureSun,
        Levelling,
        PhotoInfo,
        ProbeAlignment,
        ProbeProducts,
        SceneAlignment,
        SceneSun,
    )
    from solidkit.envmap.io import write_ldr
    from solidkit.envmap.perspective import intrinsics_from_fov

    write_ldr(tmp_path / "photo.png", np.full((480, 640, 3), 60, np.uint8))
    write_ldr(tmp_path / "cam.png", np.full((256, 512, 3), 60, np.uint8))
    lev = Levelling(pitch_deg=0.0, roll_deg=0.0, source="none")
    K = intrinsics_from_fov(1.0, 640, 480).tolist()
    photo = PhotoInfo(path="photo.png", sha256="0", size=[640, 480], K_full=K, pitch_deg=0.0, roll_deg=0.0)
    cam = ProbeAlignment(
        id="cam", role="camera", levelling=lev, rotation=np.eye(3).tolist(), yaw_deg=0.0,
        products=ProbeProducts(ldr_full="cam.png"),
    )  # fmt: skip
    p01 = ProbeAlignment(
        id="p01", role="probe", levelling=lev, rotation=np.eye(3).tolist(), yaw_deg=10.0,
        pixel_full=[300.0, 200.0], pixel_source="field_notes", pixel_geometry=[-60.0, 200.0],
    )  # fmt: skip
    sun = SceneSun(
        found=False,
        captures=[
            CaptureSun(probe="cam", found=True, azimuth_deg=0.0, elevation_deg=30.0, flags=["sun_off_ephemeris"])
        ],
    )
    return SceneAlignment(id="s1", photo=photo, camera_probe="cam", sun=sun, probes=[cam, p01])


def test_report_picture_draws_what_its_legend_promises(tmp_path) -> None:
    """The geometric pixel outside the photo is drawn on its border (yellow), not dropped; a capture whose only
    flag is on its sun (a glint chosen as the sun) has a flagged (orange) title, and its table row lists it."""
    import numpy as np

    from solidkit.align.report import _scene_rows, capture_flag_codes, scene_picture

    sa = _report_scene(tmp_path)
    pic = scene_picture(tmp_path, sa)
    photo = pic[:384]  # 640x480 drawn 512 wide
    yellow = np.all(np.abs(photo.astype(int) - (255, 220, 0)) < 40, axis=-1)
    assert yellow[130:190, :30].sum() > 10  # on the left border, at the row of y = 200 (160 at this scale)
    title = pic[388 : 388 + 18].astype(int)  # the camera position's panel below the photo (4 px gap)
    orange = (title[..., 0] > 200) & (np.abs(title[..., 1] - 180) < 40) & (title[..., 2] < 140)
    assert orange.sum() > 20
    assert capture_flag_codes(sa.probes[0], sa.sun.captures[0]) == ["sun_off_ephemeris"]
    assert _scene_rows(sa)[0][-1] == "sun_off_ephemeris"
