"""The labeling web app's API (FastAPI TestClient): tasks, saving, conflicts, review, pixels, security."""

from __future__ import annotations

import math
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from solidkit.labeling.app import MAX_BODY_BYTES, create_app
from solidkit.labeling.images import tile_grid
from solidkit.labeling.store import LabelStore
from tests.support.labeling_campaign import PHOTO_DOT, SUN_DOTS, make_campaign

W = {"X-Solidkit": "1"}  # the page sends it with every write


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    return make_campaign(tmp_path_factory.mktemp("labcamp") / "camp")


@pytest.fixture
def client(campaign, tmp_path):
    root, alignment = campaign
    # a fresh label store per test: copy nothing, point the app at the shared images but its own labels dir
    shutil.rmtree(root / "labels", ignore_errors=True)
    return login(TestClient(create_app(root, alignment=alignment, allowed_hosts=["testserver"])), "ann")


def login(client, name, token=""):
    """Log ``client`` in as ``name`` (the session cookie stays in the client); returns it."""
    r = client.post("/api/session", json={"name": name, "token": token}, headers=W)
    assert r.status_code == 200, r.text
    return client


def as_user(client, name):
    """Another browser on the same app, logged in as ``name``."""
    return login(TestClient(client.app), name)


def item(client, kind, key):
    r = client.get("/api/item", params={"kind": kind, "key": key})
    assert r.status_code == 200, r.text
    return r.json()


def put(client, kind, key, value, version, **kw):
    body = {"kind": kind, "key": key, "value": value, "expected_version": version, **kw}
    return client.put("/api/label", json=body, headers=W)


def test_queues_follow_the_manifest_and_alignment(client):
    c = client.get("/api/campaign").json()
    assert c["progress"]["sun"] == {"done": 0, "flagged": 1, "left": 4, "returned": 0, "total": 5}  # p2: no sun
    assert [i["key"] for i in client.get("/api/queue/sun").json()["items"]] == [
        "city/cam",
        "city/p1",
        "s1/cam",
        "s1/p1",
        "s1/p2",
    ]
    assert [i["key"] for i in client.get("/api/queue/probe_pixel").json()["items"]] == [
        "city/p1",
        "s1/p1",
        "s1/p2",
    ]  # not the camera
    sun = item(client, "sun", "s1/p1")
    assert sun["proposal"]["azimuth_deg"] == SUN_DOTS["p1"][0]
    assert [c["chosen"] for c in sun["view"]["candidates"]] == [True, False]
    img = sun["view"]["image"]
    assert (img["width"], img["height"], img["tiles"]) == (1024, 512, {"cols": 2, "rows": 1})
    pix = item(client, "probe_pixel", "s1/p1")
    assert pix["proposal"] == {"x": 402.0, "y": 297.0} and pix["view"]["proposal_source"] == "field_notes"
    assert item(client, "probe_pixel", "s1/p2")["flags"] == [
        "pixel_disagrees: the marked pixel is 40 px from the geometry's"
    ]
    assert item(client, "heading", "s1/p2")["flags"] == ["low_confidence"]  # each task gets align's flags about it
    head = item(client, "heading", "s1/p1")
    assert head["proposal"] == {"yaw_deg": -30.0} and head["view"]["image"]["hdr"] is True
    outline = np.array(head["view"]["photo"]["outline"])
    hfov = 2 * math.degrees(math.atan(320 / 500))
    assert outline[:, 0].min() == pytest.approx(-hfov / 2, abs=0.01) and outline[:, 0].max() == pytest.approx(
        hfov / 2, abs=0.01
    )


def test_save_conflict_loses_nothing_and_review_compares(client, campaign):
    store = LabelStore(campaign[0])
    for name, role in (("ann", "annotator"), ("bob", "annotator"), ("rev", "reviewer")):
        store.add_user(name, role)
    bob, rv = as_user(client, "bob"), as_user(client, "rev")
    v = {"found": True, "azimuth_deg": 40.1, "elevation_deg": 25.2, "uncertainty_deg": 0.3}
    r = put(client, "sun", "s1/p1", v, 0)
    assert r.status_code == 200 and r.json()["version"] == 1
    mine = {"found": True, "azimuth_deg": 43.0, "elevation_deg": 25.0, "uncertainty_deg": 0.5}
    r = put(bob, "sun", "s1/p1", mine, 0)  # bob opened it before ann saved
    assert r.status_code == 409
    assert r.json()["current"]["annotator"] == "ann" and r.json()["version"] == 1
    assert item(client, "sun", "s1/p1")["label"]["value"]["azimuth_deg"] == 40.1
    r = put(bob, "sun", "s1/p1", mine, r.json()["version"])  # "save mine on top"
    assert r.status_code == 200 and r.json()["version"] == 2
    assert r.json()["label"]["flags"] == ["annotators_disagree: 2.6 deg (ann)"]  # travels to the test set
    rev = item(client, "sun", "s1/p1")["review"]
    assert set(rev["opinions"]) == {"ann", "bob"} and rev["open_disagreement"] and rev["status"] == "flagged"
    assert rev["disagreement"] == pytest.approx(2.6, abs=0.1)  # degrees of arc, not of azimuth
    assert client.get("/api/queue/review").status_code == 403  # the review queue is the reviewers'
    queue = rv.get("/api/queue/review").json()["items"]
    assert queue[0]["key"] == "s1/p1" and queue[0]["flags"] == [
        "annotators_disagree: 2.6 deg (ann)",
        "differs_from_auto",
    ]
    assert put(client, "sun", "s1/p1", v, 2, source="reviewed").status_code == 403  # ann is no reviewer
    r = put(rv, "sun", "s1/p1", v, 2, source="reviewed")
    assert item(client, "sun", "s1/p1")["review"]["status"] == "done" and r.json()["label"]["flags"] == []
    r = rv.post("/api/undo", json={"kind": "sun", "key": "s1/p1", "expected_version": 3}, headers=W)
    assert r.status_code == 200 and r.json()["label"]["annotator"] == "bob" and r.json()["version"] == 4
    exported = rv.get("/api/export").json()
    assert exported["labels"][0]["value"]["azimuth_deg"] == 43.0
    assert LabelStore(campaign[0]).get("sun", "s1/p1").version == 4


def test_bad_bodies(client):
    assert put(client, "sun", "s1/p1", {"found": True, "azimuth_deg": 1.0}, 0).status_code == 422  # no elevation
    assert (
        put(client, "sun", "s1/p1", {"found": True, "azimuth_deg": 1, "elevation_deg": 2, "x": 3}, 0).status_code == 422
    )
    assert put(client, "sun", "nope/p9", {"found": False}, 0).status_code == 404
    assert put(client, "heading", "s1/p1", {"yaw_deg": "east"}, 0).status_code == 422
    body = {"kind": "sun", "key": "s1/p1", "value": {"found": False}, "expected_version": 0, "admin": True}
    assert client.put("/api/label", json=body, headers=W).status_code == 422
    big = {"kind": "sun", "key": "s1/p1", "value": {"found": False, "x": "a" * MAX_BODY_BYTES}, "expected_version": 0}
    assert client.put("/api/label", json=big, headers=W).status_code == 413
    # who saves comes from the session, never from the body
    assert put(client, "sun", "s1/p1", {"found": False}, 0, annotator="mallory").status_code == 422
    assert client.get("/api/item", params={"kind": "sun", "key": "s1/zz"}).status_code == 404


def test_pixels_preview_tiles_crops(client):
    sun = item(client, "sun", "s1/p1")["view"]["image"]
    r = client.get(f"/api/img/{sun['id']}/tile/1/0.jpg")
    tile = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert r.headers["content-type"] == "image/jpeg" and tile.shape == (512, 512, 3)
    # the red disk at azimuth 40 deg lies in the right half: tile (1, 0), x = (40 + 180) / 360 * 1024 - 512
    ys, xs = np.nonzero((tile[..., 2] > 150) & (tile[..., 1] < 100))
    assert xs.mean() == pytest.approx((40 + 180) / 360 * 1024 - 512 - 0.5, abs=1.0)
    assert client.get(f"/api/img/{sun['id']}/tile/2/0.jpg").status_code == 404
    photo = item(client, "probe_pixel", "s1/p1")["view"]["photo"]["image"]
    r = client.get(f"/api/img/{photo['id']}/crop.jpg", params={"x": 380, "y": 280, "w": 40, "h": 40, "out": 40})
    crop = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert crop.shape == (40, 40, 3) and r.headers["x-crop-box"] == "380,280,420,320"
    ys, xs = np.nonzero((crop[..., 2] > 150) & (crop[..., 1] < 100))
    assert (xs.mean() + 380, ys.mean() + 280) == pytest.approx(PHOTO_DOT, abs=0.6)
    assert client.get(f"/api/img/{photo['id']}/crop.jpg", params={"x": 9000, "y": 0, "w": 5, "h": 5}).status_code == 404
    assert client.get(f"/api/img/{photo['id']}/crop.jpg", params={"x": 0, "y": 0, "w": -5, "h": 5}).status_code == 422
    assert tile_grid(7296) == (16, 8) and tile_grid(1920) == (4, 2)


@pytest.mark.parametrize(
    "url",
    [
        "/static/../manifest.json",
        "/static/%2e%2e/%2e%2e/manifest.json",
        "/static/..%2f..%2f..%2fmanifest.json",
        "/static/%2e%2e%2f%2e%2e%2fstore.py",
        "/static/js/..%2f..%2fapp.py",
        "/api/img/..%2f..%2fmanifest.json/preview.jpg",
        "/api/img/img-0123456789abcdef/preview.jpg",
        "/api/img/img-0123456789abcdef/../../manifest.json",
        "/manifest.json",
        "/products/s1/p1/sun.png",
        "/labels/labels.sqlite",
    ],
)
def test_traversal_is_404(client, url):
    assert client.get(url).status_code == 404


def test_symlink_escape_is_not_served(tmp_path):
    root, alignment = make_campaign(tmp_path / "camp", with_city=False)
    secret = tmp_path / "secret.png"
    cv2.imwrite(str(secret), np.zeros((8, 16, 3), np.uint8))
    target = root / "products/s1/p2/sun.png"
    target.unlink()
    os.symlink(secret, target)
    app = create_app(root, alignment=alignment, allowed_hosts=["testserver"])
    c = login(TestClient(app), "ann")
    assert "s1/p2" not in [i["key"] for i in c.get("/api/queue/sun").json()["items"]]
    assert any("outside the campaign" in p for p in c.get("/api/campaign").json()["problems"])
    assert all(ref.path.is_relative_to(root.resolve()) for ref in app.state.index.images.values())


def test_cross_site_writes_refused(client):
    v = {"kind": "sun", "key": "s1/p1", "value": {"found": False}, "expected_version": 0}
    assert client.put("/api/label", json=v).status_code == 403  # no X-Solidkit header (a form post cannot add it)
    assert client.put("/api/label", json=v, headers={**W, "Origin": "http://evil.example"}).status_code == 403
    assert client.put("/api/label", json=v, headers={**W, "Sec-Fetch-Site": "cross-site"}).status_code == 403
    assert client.get("/api/campaign", headers={"Host": "evil.example"}).status_code == 400  # DNS rebinding
    ok = client.put("/api/label", json=v, headers={**W, "Origin": "http://testserver", "Sec-Fetch-Site": "same-origin"})
    assert ok.status_code == 200
    page = client.get("/")
    assert (
        "frame-ancestors 'none'" in page.headers["content-security-policy"]
        and page.headers["x-frame-options"] == "DENY"
    )


def test_token_mode(campaign):
    root, alignment = campaign
    token = "s3cret-token-for-the-test"
    c = TestClient(create_app(root, alignment=alignment, token=token, allowed_hosts=["testserver"]))
    assert c.get("/").status_code == 200  # the page itself holds no data
    assert c.get("/api/campaign").status_code == 401
    state = c.get("/api/session").json()
    assert (state["token_required"], state["authenticated"], state["users"]) == (True, False, [])
    assert c.get("/api/campaign", params={"token": token}).status_code == 401  # never from a URL
    assert c.post("/api/session", json={"token": "wrong", "name": "ann"}, headers=W).status_code == 401
    bearer = {"Authorization": f"Bearer {token}", "X-Solidkit-User": "ann"}  # scripts: token + a user
    assert c.get("/api/campaign", headers=bearer).status_code == 200
    assert c.get("/api/campaign", headers={"X-Solidkit-User": "ann"}).status_code == 401  # a name is no token
    r = c.post("/api/session", json={"token": token, "name": "ann"}, headers=W)
    cookie = r.headers["set-cookie"].lower()
    assert r.status_code == 200 and "httponly" in cookie and "samesite=strict" in cookie and token not in cookie
    assert c.get("/api/campaign").status_code == 200  # the session cookie
    sun = c.get("/api/item", params={"kind": "sun", "key": "s1/p1"}).json()["view"]["image"]["id"]
    assert c.get(f"/api/img/{sun}/preview.jpg").status_code == 200
    c.cookies.clear()
    assert c.get(f"/api/img/{sun}/preview.jpg").status_code == 401


def test_cli_export(cli, campaign, tmp_path):
    root, _ = campaign
    LabelStore(root).put("sun", "s1/cam", {"found": False}, source="annotator", annotator="ann")
    code, out, err = cli("label", "export", root, "--json")
    assert code == 0 and any(lab["key"] == "s1/cam" for lab in __import__("json").loads(out)["labels"])
    code, out, err = cli("label", "export", root, "-o", tmp_path / "labels.json")
    assert code == 0 and (tmp_path / "labels.json").is_file()
    code, out, err = cli("label", "export", tmp_path)
    assert code == 2 and "no label store" in err
    code, out, err = cli("label", "serve", tmp_path)
    assert code == 2 and "manifest.json" in err
    code, out, err = cli("label", "serve", root, "--host", "0.0.0.0", "--token", "short")
    assert code == 2 and "16 characters" in err


def test_proposal_from_the_store_without_alignment(tmp_path):
    """`solidkit label sun` writes auto labels (with candidates) but no alignment.json: they are the proposal."""
    root, _ = make_campaign(tmp_path / "camp", with_alignment=False, with_city=False)
    cand = [
        {
            "azimuth_deg": -60.0,
            "elevation_deg": 10.0,
            "size_deg": 0.5,
            "chosen": False,
            "reasons": ["below the ephemeris"],
        }
    ]
    value = {"found": True, "azimuth_deg": 40.0, "elevation_deg": 25.0, "uncertainty_deg": 0.4, "candidates": cand}
    LabelStore(root).put("sun", "s1/p1", value, source="auto", annotator="align", flags=["glint"])
    c = login(TestClient(create_app(root, allowed_hosts=["testserver"])), "ann")
    it = item(c, "sun", "s1/p1")
    assert it["proposal"] == {"found": True, "azimuth_deg": 40.0, "elevation_deg": 25.0, "uncertainty_deg": 0.4}
    assert it["view"]["candidates"] == cand and "glint" in it["review"]["flags"]
    assert item(c, "sun", "s1/p2")["proposal"] is None


@pytest.mark.slow
def test_serve_beyond_loopback_prints_a_token_and_requires_it(campaign):
    """The real command in its own process: bound to all interfaces it makes up a token and
    answers 401 without it."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = "import sys; from solidkit.cli import main; sys.argv = ['solidkit'] + sys.argv[1:]; main()"
    argv = [sys.executable, "-c", code, "label", "serve", str(campaign[0]), "--host", "0.0.0.0", "--port", str(port)]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        token = proc.stderr.readline().strip().rsplit(" ", 1)[-1]
        assert "labeling" in proc.stderr.readline() and len(token) >= 16
        url = f"http://127.0.0.1:{port}/api/campaign"
        for _ in range(200):
            try:
                urllib.request.urlopen(url, timeout=5)
            except urllib.error.HTTPError as exc:
                assert exc.code == 401
                break
            except OSError:
                time.sleep(0.05)
        else:
            pytest.fail("server did not answer")
        req = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}", "X-Solidkit-User": "ann"})
        assert urllib.request.urlopen(req, timeout=5).status == 200
    finally:
        proc.terminate()
        proc.wait(10)


def test_hdr_shown_exposed_and_nothing_written_but_the_store(tmp_path):
    """An EXR product is served as an exposed sRGB preview (the red disk drawn at azimuth 30 deg is
    where conventions §3 puts it); a whole session writes nothing in the campaign but labels/."""
    root, alignment = make_campaign(tmp_path / "camp", with_city=False)
    before = {p: p.stat().st_mtime_ns for p in root.rglob("*")}
    c = login(TestClient(create_app(root, alignment=alignment, allowed_hosts=["testserver"])), "ann")
    img = item(c, "heading", "s1/p1")["view"]["image"]
    assert img["hdr"] is True
    prev = cv2.imdecode(np.frombuffer(c.get(f"/api/img/{img['id']}/preview.jpg").content, np.uint8), cv2.IMREAD_COLOR)
    ys, xs = np.nonzero((prev[..., 2] > 200) & (prev[..., 1] < 80))
    assert (xs.mean() + 0.5) / prev.shape[1] * 360 - 180 == pytest.approx(30.0, abs=0.5)
    assert np.median(prev[:256]) > 60  # the sky exposed to mid grey, not black
    for kind, key, value in (("heading", "s1/p1", {"yaw_deg": -29.5}), ("probe_pixel", "s1/p1", {"x": 1.0, "y": 2.0})):
        assert put(c, kind, key, value, 0).status_code == 200
    c.get(f"/api/img/{img['id']}/tile/0/0.jpg")
    c.get("/api/export")
    changed = {p for p in root.rglob("*") if before.get(p) != p.stat().st_mtime_ns}
    assert changed and all(p.relative_to(root).parts[0] == "labels" for p in changed)


MINI = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "campaign_mini"


@pytest.mark.slow
@pytest.mark.skipif(not MINI.is_dir(), reason="the shipped mini campaign is absent")
def test_the_app_on_the_mini_campaign_chain(cli, tmp_path):
    """The chain: the shipped mini campaign ingested and aligned; every item of every task opens,
    every image is served, and align's proposals are the ones shown."""
    from solidkit.align.schema import load_alignment

    camp = tmp_path / "camp"
    assert cli("ingest", MINI / "card", "-o", camp)[0] == 0
    assert cli("align", camp, "--no-report")[0] == 0
    alignment = load_alignment(camp).model_dump(mode="json")
    c = login(TestClient(create_app(camp, alignment=alignment, allowed_hosts=["testserver"])), "ann")
    assert c.get("/api/campaign").json()["problems"] == []
    captures = {f"{s['id']}/{x['probe']}": x for s in alignment["scenes"] for x in s["sun"]["captures"]}
    for kind in ("sun", "probe_pixel", "heading"):
        keys = [q["key"] for q in c.get(f"/api/queue/{kind}").json()["items"]]
        assert keys, kind
        for key in keys:
            it = item(c, kind, key)
            for img in (it["view"].get("image"), (it["view"].get("photo") or {}).get("image")):
                if img:
                    assert c.get(f"/api/img/{img['id']}/preview.jpg").status_code == 200
            if kind == "sun" and captures.get(key, {}).get("found"):
                assert it["proposal"]["azimuth_deg"] == pytest.approx(captures[key]["azimuth_deg"])
            if kind == "heading":
                assert it["view"]["photo"]["outline"], key
    assert len(c.get("/api/queue/sun").json()["items"]) == len(captures)
