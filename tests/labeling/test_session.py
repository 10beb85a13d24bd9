"""A scripted labeling session on a virtual campaign with a known truth (tests/support/testset_campaign.py):
two annotators label every probe pixel and heading blind (two per item), a reviewer settles the
disagreements, a rejected value goes back to its annotator with the comment, the agreement summary
matches the errors against the truth, no acknowledged label is lost, and the test set built
afterwards takes the reviewed labels."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from solidkit.labeling.app import create_app
from solidkit.labeling.review import THRESHOLDS
from solidkit.labeling.store import LabelStore
from solidkit.testset.build import build_testset, load_testset
from tests.support.testset_campaign import make_campaign

W = {"X-Solidkit": "1"}
# each annotator's error per item, in queue order (px along x for pixels, degrees of yaw for headings);
# bob's third pixel and third heading are wrong (a neighbour's post, the wrong building)
ERRORS = {
    "ann": {"probe_pixel": [0.0, -2.0, 1.5], "heading": [0.3, -0.2, 0.5, 0.0, 0.1]},
    "bob": {"probe_pixel": [3.0, 2.0, 45.0], "heading": [0.6, 0.4, 9.0, -0.3, 0.2]},
}
REDO = {"probe_pixel": 4.0, "heading": 0.8}  # bob's error when he labels a rejected item again


def _truth(truth: dict, kind: str, key: str) -> dict:
    scene, probe = key.split("/")
    if kind == "probe_pixel":
        x, y = truth[scene]["pixels"][probe]
        return {"x": x, "y": y}
    return {"yaw_deg": truth[scene]["yaws"][probe]}


def _off(kind: str, value: dict, err: float) -> dict:
    return {"x": value["x"] + err, "y": value["y"]} if kind == "probe_pixel" else {"yaw_deg": value["yaw_deg"] + err}


@pytest.mark.slow  # about 20 s on a shared machine: the campaign and the test set are built
def test_two_annotators_and_a_reviewer(tmp_path, cli):
    camp = tmp_path / "camp"
    truth = make_campaign(camp)
    for name, role in (("ann", "annotator"), ("bob", "annotator"), ("rev", "reviewer")):
        assert cli("label", "users", "add", name, "--role", role, "-c", camp)[0] == 0
    code, out, err = cli("label", "assign", camp, "--to", "ann", "--to", "bob", "--per-item", "2")
    assert code == 0 and "blind mode for annotators: on" in err
    alignment = json.loads((camp / "align" / "alignment.json").read_text())
    app = create_app(camp, alignment=alignment, allowed_hosts=["testserver"])
    clients = {}
    for name in ("ann", "bob", "rev"):
        clients[name] = TestClient(app)
        assert clients[name].post("/api/session", json={"name": name}, headers=W).status_code == 200
    acked: list[tuple[str, str, str, dict]] = []  # every save the server acknowledged

    def save(who, kind, key, value, source="annotator"):
        c = clients[who]
        it = c.get("/api/item", params={"kind": kind, "key": key, "blind": True}).json()
        r = c.put("/api/label", json={"kind": kind, "key": key, "value": value, "expected_version": it["version"],
                                      "source": source, "blind": True}, headers=W)  # fmt: skip
        assert r.status_code == 200, r.text
        acked.append((who, kind, key, value))

    def queue(who, kind):
        return {q["key"]: q for q in clients[who].get(f"/api/queue/{kind}").json()["items"]}

    # 1. blind double labeling: each annotator's own queue, nobody else's values in sight
    final: dict[tuple[str, str], dict[str, dict]] = {}
    for kind in ("probe_pixel", "heading"):
        keys = list(queue("ann", kind))
        assert keys == list(queue("bob", kind)) and len(keys) == len(ERRORS["ann"][kind])  # two per item
        for who in ("ann", "bob"):
            for key, err in zip(keys, ERRORS[who][kind], strict=True):
                if who == "bob":  # ann saved first: nothing of hers reaches bob, and his queue is still his
                    assert queue("bob", kind)[key]["status"] in ("left", "flagged")
                    seen = json.dumps(clients["bob"].get("/api/item", params={"kind": kind, "key": key}).json())
                    assert '"ann"' not in seen
                value = _off(kind, _truth(truth, kind, key), err)
                save(who, kind, key, value)
                final.setdefault((kind, key), {})[who] = value
            assert all(q["status"] == "done" for q in queue(who, kind).values())
    # 2. the disagreements are flagged, exactly where the two are further apart than the threshold
    review = {(r["kind"], r["key"]): r for r in clients["rev"].get("/api/queue/review").json()["items"]}
    for kind, key in final:
        apart = abs(
            ERRORS["ann"][kind][list(queue("ann", kind)).index(key)]
            - ERRORS["bob"][kind][list(queue("ann", kind)).index(key)]
        )
        assert review[(kind, key)]["open_disagreement"] == (apart > THRESHOLDS[kind]), (kind, key)
    bad = [(k, key) for (k, key), r in review.items() if r["open_disagreement"]]
    assert len(bad) == 2
    # 3. the reviewer rejects bob's value with a comment: back in bob's queue with it; bob labels again
    for kind, key in bad:
        r = clients["rev"].post("/api/verdict", json={"kind": kind, "key": key, "annotator": "bob", "verdict": "reject",
                                "comment": "you marked the neighbour's post; look again"}, headers=W)  # fmt: skip
        assert r.status_code == 200
        row = queue("bob", kind)[key]
        assert row["status"] == "returned" and "neighbour" in row["comment"]
        assert queue("ann", kind)[key]["status"] == "done"  # ann's value was not rejected
        value = _off(kind, _truth(truth, kind, key), REDO[kind])
        save("bob", kind, key, value)
        final[(kind, key)]["bob"] = value
        assert queue("bob", kind)[key]["status"] == "done"
    # 4. the reviewer settles every item: accepts ann's value where it is exact, else stores the truth
    for (kind, key), vals in final.items():
        t = _truth(truth, kind, key)
        if vals["ann"] == t:
            it = clients["rev"].get("/api/item", params={"kind": kind, "key": key}).json()
            body = {
                "kind": kind,
                "key": key,
                "annotator": "ann",
                "verdict": "accept",
                "expected_version": it["version"],
            }
            r = clients["rev"].post("/api/verdict", json=body, headers=W)
            assert r.status_code == 200 and r.json()["label"]["source"] == "reviewed"
        else:
            save("rev", kind, key, t, source="reviewed")
    # 5. agreement: against the reviewed label it is each annotator's error against the truth
    agree = clients["rev"].get("/api/agreement").json()
    for kind in ("probe_pixel", "heading"):
        for who in ("ann", "bob"):
            errs = [abs(v[who]["x"] - _truth(truth, kind, key)["x"]) if kind == "probe_pixel"
                    else abs(v[who]["yaw_deg"] - _truth(truth, kind, key)["yaw_deg"])
                    for (k, key), v in final.items() if k == kind]  # fmt: skip
            st = agree[kind]["annotators"][who]
            assert st["vs_reviewed"]["median"] == pytest.approx(np.median(errs), abs=1e-3)
            assert st["vs_reviewed"]["p95"] == pytest.approx(np.percentile(errs, 95), abs=1e-3)
        field = "x" if kind == "probe_pixel" else "yaw_deg"
        apart = [abs(v["ann"][field] - v["bob"][field]) for (k, _), v in final.items() if k == kind]
        assert agree[kind]["task"]["vs_others"]["median"] == pytest.approx(np.median(apart), abs=1e-3)
        assert agree[kind]["annotators"]["bob"]["rejected"] == 1
    code, out, _ = cli("label", "export", camp, "--json")
    assert code == 0 and json.loads(out)["agreement"] == agree
    # 6. nothing lost: every acknowledged save is in the history, the store is consistent
    store = LabelStore(camp)
    assert store.check() == []
    for who, kind, key, value in acked:
        assert any(
            c.annotator == who and c.applied and c.value == pytest.approx(value) for c in store.history(kind, key)
        )
    # 7. the test set takes the reviewed labels
    build_testset(camp, tmp_path / "ts")
    ts = load_testset(tmp_path / "ts")
    pixels = {f"{s.id}/{p.id}": p for s in ts.scenes for p in s.probes}
    for (kind, key), _ in final.items():
        t = _truth(truth, kind, key)
        if kind == "probe_pixel":
            assert pixels[key].pixel_source == "reviewed" and pixels[key].pixel_full == pytest.approx((t["x"], t["y"]))
        elif key in pixels:
            assert pixels[key].alignment.source == "reviewed"
            assert pixels[key].alignment.yaw_deg == pytest.approx(t["yaw_deg"])
