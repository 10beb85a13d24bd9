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
