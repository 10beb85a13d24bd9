"""A team on one campaign: users and roles, strict edits, own queues, assignment, review verdicts,
notes and skips, agreement, the login rate limit, the Host check of a wildcard bind, old stores."""

from __future__ import annotations

import json
import shutil
import sqlite3

import numpy as np
import pytest
from fastapi.testclient import TestClient

from solidkit.labeling.app import LOGIN_LIMIT, create_app
from solidkit.labeling.store import LabelStore, store_path
from tests.support.labeling_campaign import make_campaign

W = {"X-Solidkit": "1"}
SUN = {"found": True, "azimuth_deg": 40.0, "elevation_deg": 25.0, "uncertainty_deg": 0.3}


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    return make_campaign(tmp_path_factory.mktemp("team") / "camp", with_city=False)


@pytest.fixture
def app(campaign):
    root, alignment = campaign
    shutil.rmtree(root / "labels", ignore_errors=True)
    store = LabelStore(root)
    for name, role in (("ann", "annotator"), ("bob", "annotator"), ("rev", "reviewer")):
        store.add_user(name, role)
    return create_app(root, alignment=alignment, allowed_hosts=["testserver"])


def user(app, name):
    c = TestClient(app)
    r = c.post("/api/session", json={"name": name}, headers=W)
    assert r.status_code == 200, r.text
    return c


def put(c, kind, key, value, version=0, **kw):
    return c.put("/api/label", json={"kind": kind, "key": key, "value": value, "expected_version": version, **kw},
                 headers=W)  # fmt: skip


def queue(c, kind):
    return {q["key"]: q for q in c.get(f"/api/queue/{kind}").json()["items"]}


def test_login_needs_a_registered_user_and_identity_comes_from_the_session(app, campaign):
    c = TestClient(app)
    assert c.post("/api/session", json={"name": "mallory"}, headers=W).status_code == 403
    assert c.get("/api/campaign").status_code == 401
    ann = user(app, "ann")
    assert ann.get("/api/session").json()["user"] == {"name": "ann", "role": "annotator"}
    assert put(ann, "sun", "s1/p1", SUN).status_code == 200
    assert LabelStore(campaign[0]).get("sun", "s1/p1").annotator == "ann"
    assert put(ann, "sun", "s1/p1", SUN, 1, annotator="rev").status_code == 422  # no name in the body
    ann.post("/api/logout", json={}, headers=W)
    assert ann.get("/api/campaign").status_code == 401


@pytest.mark.parametrize(
    "kind, key, value",
    [
        ("heading", "s1/p1", {"yaw_deg": "5"}),  # a string is no number
        ("probe_pixel", "s1/p1", {"x": True, "y": 2.0}),  # nor is true
        ("probe_pixel", "s1/p1", {"x": 1e12, "y": 2.0}),  # outside the 640x480 photo
        ("probe_pixel", "s1/p1", {"x": 10.0, "y": 479.6}),
        ("heading", "s1/p1", {"yaw_deg": 1e308}),  # was stored as 116.0
        ("heading", "s1/p1", {"yaw_deg": float("nan")}),
        ("sun", "s1/p1", {"found": 1, "azimuth_deg": 1.0, "elevation_deg": 2.0}),
        ("sun", "s1/p1", {"found": True, "azimuth_deg": 1.0, "elevation_deg": float("inf")}),
    ],
)
def test_loose_values_are_refused(app, campaign, kind, key, value):
    ann = user(app, "ann")
    body = json.dumps({"kind": kind, "key": key, "value": value, "expected_version": 0})  # NaN as JSON's NaN
    r = ann.put("/api/label", content=body, headers={**W, "Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert LabelStore(campaign[0]).get(kind, key) is None


def test_edge_values_are_kept(app, campaign):
    ann = user(app, "ann")
    assert put(ann, "probe_pixel", "s1/p1", {"x": 639.5, "y": -0.5}).status_code == 200  # the outer pixel edges
    assert put(ann, "heading", "s1/p1", {"yaw_deg": 5}).status_code == 200  # an integer is a number
    assert LabelStore(campaign[0]).get("heading", "s1/p1").value == {"yaw_deg": 5.0}


def test_only_reviewers_review(app, campaign):
    ann, rev = user(app, "ann"), user(app, "rev")
    put(ann, "sun", "s1/p1", SUN)
    assert put(ann, "sun", "s1/p1", SUN, 1, source="reviewed").status_code == 403
    body = {"kind": "sun", "key": "s1/p1", "annotator": "ann", "verdict": "accept"}
    assert ann.post("/api/verdict", json=body, headers=W).status_code == 403
    assert ann.get("/api/agreement").status_code == 403
    assert rev.post("/api/verdict", json=body, headers=W).status_code == 200
    lab = LabelStore(campaign[0]).get("sun", "s1/p1")
    assert (lab.source, lab.annotator, lab.value["azimuth_deg"]) == ("reviewed", "rev", 40.0)
    with pytest.raises(Exception, match="not a reviewer"):  # the store itself holds the rule
        LabelStore(campaign[0]).put("sun", "s1/p2", SUN, source="reviewed", annotator="ann")


def test_blind_queues_are_each_annotators_own(app, campaign):
    """Blind: ann's label neither makes bob's item done nor shows up anywhere in bob's view."""
    LabelStore(campaign[0]).set_setting("blind", "1")
    ann, bob, rev = user(app, "ann"), user(app, "bob"), user(app, "rev")
    assert put(ann, "probe_pixel", "s1/p1", {"x": 123.0, "y": 45.0}).status_code == 200
    assert queue(ann, "probe_pixel")["s1/p1"]["status"] == "done"
    assert queue(bob, "probe_pixel")["s1/p1"]["status"] == "left"
    it = bob.get("/api/item", params={"kind": "probe_pixel", "key": "s1/p2"}).json()
    text = json.dumps(bob.get("/api/item", params={"kind": "probe_pixel", "key": "s1/p1"}).json())
    assert "123" not in text and '"ann"' not in text and it["siblings"]["p1"] is None and it["proposal"] is None
    # bob saves on top of a version he never saw: no conflict dialog (it would show ann's value)
    r = put(bob, "probe_pixel", "s1/p1", {"x": 160.0, "y": 45.0}, 0)
    assert r.status_code == 200 and "123" not in r.text and "ann" not in r.text
    assert queue(bob, "probe_pixel")["s1/p1"]["status"] == "done"
    v = LabelStore(campaign[0]).version("probe_pixel", "s1/p1")
    r = ann.post("/api/undo", json={"kind": "probe_pixel", "key": "s1/p1", "expected_version": v}, headers=W)
    assert r.status_code == 403 and "bob" not in r.text and "160" not in r.text  # bob's change is not hers to undo
    r = ann.post("/api/undo", json={"kind": "probe_pixel", "key": "s1/p1", "expected_version": 0}, headers=W)
    assert "160" not in r.text
    assert rev.get("/api/item", params={"kind": "probe_pixel", "key": "s1/p1"}).json()["review"]["open_disagreement"]


def test_assign_splits_items_and_returns_rejections_with_the_comment(app, campaign, cli):
    root = campaign[0]
    code, out, err = cli("label", "assign", root, "--to", "ann", "--to", "bob", "--per-item", "1", "--task", "sun")
    assert code == 0, err
    ann, bob, rev = user(app, "ann"), user(app, "bob"), user(app, "rev")
    mine, theirs = set(queue(ann, "sun")), set(queue(bob, "sun"))
    assert mine and theirs and not mine & theirs and mine | theirs == set(queue(rev, "sun"))
    key = sorted(mine)[0]
    assert put(bob, "sun", key, SUN).status_code == 403  # not his item
    put(ann, "sun", key, SUN)
    body = {"kind": "sun", "key": key, "annotator": "ann", "verdict": "reject", "comment": ""}
    assert rev.post("/api/verdict", json=body, headers=W).status_code == 422  # a rejection says why
    body["comment"] = "that is a reflection on the window; the sun is higher"
    assert rev.post("/api/verdict", json=body, headers=W).status_code == 200
    row = queue(ann, "sun")[key]
    assert row["status"] == "returned" and "reflection" in row["comment"] and row["reviewer"] == "rev"
    put(ann, "sun", key, {**SUN, "elevation_deg": 30.0}, LabelStore(root).version("sun", key))
    assert queue(ann, "sun")[key]["status"] == "done"  # labelled again: back to done
    code, out, err = cli("label", "assign", root, "--to", "ann", "--to", "bob", "--per-item", "2")
    assert code == 0 and "blind mode for annotators: on" in err
    assert set(queue(bob, "sun")) == set(queue(rev, "sun"))


def test_notes_and_skip(app, campaign):
    ann, rev = user(app, "ann"), user(app, "rev")
    body = {"kind": "sun", "key": "s1/p2", "skip": True, "text": ""}
    assert ann.post("/api/note", json=body, headers=W).status_code == 422  # a skip says why
    body["text"] = "clouds everywhere"
    assert ann.post("/api/note", json=body, headers=W).status_code == 200
    assert queue(ann, "sun")["s1/p2"] == queue(ann, "sun")["s1/p2"] | {"status": "done", "skipped": "clouds everywhere"}
    row = next(r for r in rev.get("/api/queue/review").json()["items"] if r["key"] == "s1/p2")
    assert row["notes"]["ann"]["skip"] and row["notes"]["ann"]["text"] == "clouds everywhere"
    assert ann.get("/api/item", params={"kind": "sun", "key": "s1/p2"}).json()["note"]["text"] == "clouds everywhere"


def test_agreement_against_each_other_and_the_reviewed_label(app, campaign, cli):
    ann, bob, rev = user(app, "ann"), user(app, "bob"), user(app, "rev")
    offsets = {"s1/p1": (3.0, -5.0), "s1/p2": (0.0, 20.0)}  # px from the truth, x only
    truth = {"s1/p1": (400.0, 300.0), "s1/p2": (200.0, 100.0)}
    for key, (da, db) in offsets.items():
        x, y = truth[key]
        put(ann, "probe_pixel", key, {"x": x + da, "y": y})
        put(bob, "probe_pixel", key, {"x": x + db, "y": y}, LabelStore(campaign[0]).version("probe_pixel", key))
        put(rev, "probe_pixel", key, {"x": x, "y": y}, LabelStore(campaign[0]).version("probe_pixel", key),
            source="reviewed")  # fmt: skip
    a = rev.get("/api/agreement").json()["probe_pixel"]
    assert a["annotators"]["ann"]["vs_reviewed"]["median"] == pytest.approx(np.median([3.0, 0.0]))
    assert a["annotators"]["bob"]["vs_reviewed"]["p95"] == pytest.approx(np.percentile([5.0, 20.0], 95))
    assert a["task"]["vs_others"]["median"] == pytest.approx(np.median([8.0, 20.0]))
    assert a["annotators"]["ann"]["vs_others"]["n"] == 2 and a["unit"] == "px"
    code, out, err = cli("label", "export", campaign[0], "--json")
    assert code == 0 and json.loads(out)["agreement"]["probe_pixel"] == a


def test_wrong_tokens_are_rate_limited(campaign):
    root, alignment = campaign
    token = "a-token-of-some-length"
    c = TestClient(create_app(root, alignment=alignment, token=token, allowed_hosts=["testserver"]))
    for _ in range(LOGIN_LIMIT[0]):
        assert c.post("/api/session", json={"token": "guess", "name": "ann"}, headers=W).status_code == 401
    r = c.post("/api/session", json={"token": token, "name": "ann"}, headers=W)
    assert r.status_code == 429 and int(r.headers["retry-after"]) > 0


def test_a_wildcard_bind_still_checks_the_host():
    from solidkit.cli.label import allowed_hosts

    hosts = allowed_hosts("0.0.0.0", ["labels.example.org"])
    assert "*" not in hosts and "127.0.0.1" in hosts and "labels.example.org" in hosts
    assert "evil.example" not in hosts and "[::1]" in allowed_hosts("::")


def test_a_schema_1_store_is_read_and_migrated(tmp_path):
    store = LabelStore(tmp_path)
    store.put("sun", "s1/p1", SUN, source="annotator", annotator="ann")
    with sqlite3.connect(store_path(tmp_path)) as con:  # as written before the team tables
        for t in ("users", "assignments", "verdicts", "notes"):
            con.execute(f"DROP TABLE {t}")
        con.execute("UPDATE meta SET value = '1' WHERE name = 'schema_version'")
    ro = LabelStore(tmp_path, readonly=True)
    assert ro.schema_version == 1 and ro.users() == {} and ro.get("sun", "s1/p1").annotator == "ann"
    rw = LabelStore(tmp_path)
    assert rw.schema_version == 2 and rw.get("sun", "s1/p1").value["azimuth_deg"] == 40.0
    rw.add_user("rev", "reviewer")
    assert LabelStore(tmp_path, readonly=True).users() == {"rev": "reviewer"}
