"""The labeling app end to end in a real headless browser (Debian's chromium driven by Playwright).

Directions are checked against markers drawn by Python with solidkit's conventions and found on
screen by their colour, so Photo Sphere Viewer's own angle conventions are under test, not assumed.
Screenshots of each task view go to docs/screenshots/ when SOLIDKIT_SCREENSHOTS=1.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.labeling.store import LabelStore
from tests.support.labeling_campaign import HEADING_DOT_AZ, PHOTO_DOT, SUN_DOTS, make_campaign

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SHOTS = Path(__file__).resolve().parents[2] / "docs" / "screenshots"
VIEWPORT = {"width": 1366, "height": 768}  # a laptop screen

pytestmark = [
    pytest.mark.skipif(
        not Path(CHROMIUM).is_file(),
        reason="Debian's chromium is not installed (make installs it as root: apt-get install chromium)",
    ),
]
playwright_api = pytest.importorskip(
    "playwright.sync_api", reason="playwright not installed (pip install -e '.[test]')"
)


def _serve(app):
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    t0 = time.monotonic()
    while not server.started:
        if time.monotonic() - t0 > 10:
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    return server, thread, f"http://127.0.0.1:{port}"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    return make_campaign(tmp_path_factory.mktemp("browser") / "camp")


@pytest.fixture(scope="module")
def server(campaign):
    from solidkit.labeling.app import create_app

    root, alignment = campaign
    store = LabelStore(root)
    for name in ANNOTATORS:
        store.add_user(name, "annotator")
    store.add_user("rev", "reviewer")
    app = create_app(root, alignment=alignment)
    srv, thread, url = _serve(app)
    url_app[url] = app
    yield url
    srv.should_exit = True
    thread.join(5)


@pytest.fixture(scope="module")
def browser():
    with playwright_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield b
        b.close()


ANNOTATORS = ("ann", "bob", "carol", "dave")
url_app: dict = {}  # server address -> its app (to end sessions as a restart would)
_SEEN_GUIDES = "for (const t of ['sun', 'probe_pixel', 'heading']) localStorage.setItem('solidkit.guide.' + t, '1')"


def open_page(browser, url, annotator="ann", viewport=VIEWPORT, guides_seen=True, console=None):
    """A new browser (its own cookies) logged in as ``annotator``, opened at ``url``."""
    ctx = browser.new_context(viewport=viewport)
    if guides_seen:
        ctx.add_init_script(_SEEN_GUIDES)
    base = re.match(r"https?://[^/]+", url).group(0)
    r = ctx.request.post(f"{base}/api/session", data={"name": annotator}, headers={"X-Solidkit": "1"})
    assert r.ok, r.text()
    page = ctx.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    if console is not None:
        page.on("console", lambda m: console.append(f"{m.type}: {m.text}"))
    page.goto(url)
    return page, errors


def loaded(page, task, key=None):
    """Wait until the page shows ``task``'s item ``key`` (set by the app once drawn)."""
    page.wait_for_selector(
        f"body[data-item='{task}:{key}']" if key else f"body[data-item='{task}']", timeout=60000
    )  # generous: CI machines may be loaded
    page.wait_for_timeout(150)  # a frame or two for WebGL


def goto(page, task, key):
    page.evaluate(f"() => {{ window.solidkitApp.switchTask('{task}', '{key}'); }}")
    loaded(page, task, key)


def blob(page, selector, rgb, tol=70):
    """Screen position (page px) of the centroid of the pixels of colour ``rgb`` inside ``selector``."""
    loc = page.locator(selector)
    box = loc.bounding_box()
    img = cv2.imdecode(np.frombuffer(loc.screenshot(), np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(int)
    mask = np.abs(img - np.array(rgb)).sum(axis=2) < tol
    assert mask.sum() > 5, f"colour {rgb} not on screen"
    ys, xs = np.nonzero(mask)
    sx, sy = box["width"] / img.shape[1], box["height"] / img.shape[0]
    return box["x"] + (xs.mean() + 0.5) * sx, box["y"] + (ys.mean() + 0.5) * sy


def centred_blob(page, selector, rgb, tol=70, within=40, tries=40):
    """:func:`blob` once the view has turned to it (a loaded machine renders late): its position
    once it lies within ``within`` px of the view's centre."""
    box = page.locator(selector).bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    for _ in range(tries):
        try:
            x, y = blob(page, selector, rgb, tol)
            if abs(x - cx) < within and abs(y - cy) < within:
                return x, y
        except AssertionError:
            pass
        page.wait_for_timeout(100)
    return blob(page, selector, rgb, tol)


def shot(page, name):
    if os.environ.get("SOLIDKIT_SCREENSHOTS") == "1":
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / f"{name}.jpg"), type="jpeg", quality=70)


def numbers(text):
    return [float(x) for x in re.findall(r"-?\d+\.\d+", text)]


def test_sun_click_markers_store_the_drawn_direction(server, browser, campaign):
    """Markers drawn at known (azimuth, elevation) (one at negative azimuth, one at 62 deg up),
    clicked where they appear on screen: the store holds those directions; a reload shows them."""
    root, _ = campaign
    page, errors = open_page(browser, f"{server}/#task=sun&key=s1/cam")
    loaded(page, "sun", "s1/cam")
    for key in ("s1/cam", "s1/p2"):
        pid = key.split("/")[1]
        az, el, bgr = SUN_DOTS[pid]
        goto(page, "sun", key)
        ov = page.locator("#sun-overview canvas").bounding_box()  # look there through the overview strip
        page.mouse.click(ov["x"] + (az + 180) / 360 * ov["width"], ov["y"] + (90 - el) / 180 * ov["height"])
        x, y = centred_blob(page, "#sun-sphere", bgr[::-1])
        page.mouse.click(x + 25, y - 10)  # a first, careless click beside the sun ...
        page.wait_for_selector("#draft-value:text-matches('^az')")
        page.mouse.move(x + 25, y - 10)  # ... then the mark is dragged onto it
        page.mouse.down()
        page.mouse.move(x + 10, y - 4, steps=3)
        page.mouse.move(x, y, steps=3)
        page.mouse.up()
        page.keyboard.press("s")
        page.wait_for_selector(f"body[data-saved^='sun:{key}:']")
        lab = LabelStore(root).get("sun", key)
        assert (lab.source, lab.annotator, lab.value["found"]) == ("annotator", "ann", True)
        assert lab.value["azimuth_deg"] == pytest.approx(az, abs=0.3) and lab.value["elevation_deg"] == pytest.approx(
            el, abs=0.3
        )
    # the save moves on to the next item, and that rewrites the address: let it finish first, or
    # the reload below may open the next item instead of s1/cam (seen under load)
    page.wait_for_selector("body[data-item^='sun:']:not([data-item='sun:s1/p2'])", timeout=60000)
    page.goto(f"{server}/#task=sun&key=s1/cam")  # reload: the label persists as that direction
    page.reload()
    loaded(page, "sun", "s1/cam")
    page.wait_for_selector("#saved-value")
    saved = numbers(page.locator("#saved-value").text_content())
    assert saved[0] == pytest.approx(SUN_DOTS["cam"][0], abs=0.3) and saved[1] == pytest.approx(
        SUN_DOTS["cam"][1], abs=0.3
    )
    assert not errors


@pytest.mark.slow
def test_sun_accept_with_one_key(server, browser, campaign):
    root, alignment = campaign
    page, errors = open_page(browser, f"{server}/#task=sun&key=city/p1")
    loaded(page, "sun", "city/p1")
    page.wait_for_selector("#auto-value")
    shot(page, "sun")
    page.keyboard.press("a")
    page.wait_for_selector("body[data-saved^='sun:city/p1:']")
    proposal = next(
        c for s in alignment["scenes"] if s["id"] == "city" for c in s["sun"]["captures"] if c["probe"] == "p1"
    )
    lab = LabelStore(root).get("sun", "city/p1")
    assert lab.value["azimuth_deg"] == pytest.approx(proposal["azimuth_deg"], abs=1e-6)
    keys = ["city/cam", "city/p1", "s1/cam", "s1/p1", "s1/p2"]
    store = LabelStore(root)
    unfinished = [k for k in keys[2:] + keys[:2] if store.get("sun", k) is None or store.get("sun", k).source == "auto"]
    loaded(page, "sun", unfinished[0])  # moved on to the next item still to do
    assert not errors


def test_probe_pixel_click_and_concurrent_edit(server, browser, campaign):
    """Click the red dot on the photo: stored in full-res pixels. Two annotators edit one label at
    once: the second gets the conflict dialog, keeps their value and may save it on top."""
    root, _ = campaign
    a, errors_a = open_page(browser, f"{server}/#task=probe_pixel&key=s1/p1", "ann")
    b, errors_b = open_page(browser, f"{server}/#task=probe_pixel&key=s1/p1", "bob")
    loaded(a, "probe_pixel", "s1/p1")
    loaded(b, "probe_pixel", "s1/p1")
    x, y = blob(a, "#pixel-view", (255, 0, 0), tol=120)
    a.mouse.click(x, y)
    a.keyboard.press("s")
    a.wait_for_selector("body[data-saved^='probe_pixel:s1/p1:']")
    first = LabelStore(root).get("probe_pixel", "s1/p1")
    scale = 640 / a.locator("#pixel-view").bounding_box()["width"]  # photo px per screen px (fit to width)
    assert (first.value["x"], first.value["y"]) == pytest.approx(PHOTO_DOT, abs=max(1.0, 1.5 * scale))
    x, y = blob(b, "#pixel-view", (255, 0, 0), tol=120)
    b.mouse.click(x + 30, y + 10)  # bob, who opened the item before ann saved, marks elsewhere
    mine = b.locator("#draft-value").text_content()
    b.keyboard.press("s")
    b.wait_for_selector("#conflict:not([hidden])")
    assert b.locator("#conflict-mine").text_content() == mine  # nothing lost
    assert "ann" in b.locator("#conflict-text").text_content()
    assert LabelStore(root).get("probe_pixel", "s1/p1") == first  # the first label stands
    b.click("#conflict-keep-mine")
    b.wait_for_selector("body[data-saved^='probe_pixel:s1/p1:2']")
    second = LabelStore(root).get("probe_pixel", "s1/p1")
    assert second.annotator == "bob" and second.version == 2
    assert [c.annotator for c in LabelStore(root).history("probe_pixel", "s1/p1")] == ["ann", "bob"]
    assert not errors_a and not errors_b


@pytest.mark.slow
def test_heading_frame_and_yaw(server, browser, campaign):
    """A red disk drawn at azimuth 30 deg of the capture's level frame, with align's yaw -30: looking
    through the photo puts it at the centre of the view; a nudge stores the new yaw."""
    root, _ = campaign
    page, errors = open_page(browser, f"{server}/#task=heading&key=s1/p1")
    loaded(page, "heading", "s1/p1")
    page.keyboard.press("o")  # photo overlay off: only the panorama
    page.keyboard.press("f")
    x, y = centred_blob(page, "#heading-sphere", (255, 0, 0), tol=150, within=12)
    box = page.locator("#heading-sphere").bounding_box()
    assert x == pytest.approx(box["x"] + box["width"] / 2, abs=6) and y == pytest.approx(
        box["y"] + box["height"] / 2, abs=6
    )
    x0 = box["x"] + box["width"] / 2
    page.mouse.move(x0, y)  # drag the frame 60 px to the right: the photo turns right, yaw decreases
    page.mouse.down()
    page.mouse.move(x0 + 60, y, steps=4)
    page.mouse.up()
    dragged = float(page.locator("#yaw-input").input_value())
    assert -HEADING_DOT_AZ - 10 < dragged < -HEADING_DOT_AZ - 0.5
    page.fill("#yaw-input", str(-HEADING_DOT_AZ))
    page.locator("#yaw-input").press("Enter")
    page.locator("#yaw-input").blur()
    page.keyboard.press("ArrowRight")  # turns the frame to the right: yaw decreases
    page.keyboard.press("o")  # overlay back on
    page.keyboard.press("s")
    page.wait_for_selector("body[data-saved^='heading:s1/p1:']")
    assert LabelStore(root).get("heading", "s1/p1").value["yaw_deg"] == pytest.approx(-HEADING_DOT_AZ - 0.2, abs=1e-6)
    goto(page, "heading", "city/p1")
    shot(page, "heading")
    assert not errors


@pytest.mark.slow
def test_review_lists_the_disagreement(server, browser, campaign):
    store = LabelStore(campaign[0])
    store.put("heading", "city/cam", {"yaw_deg": 1.0}, source="annotator", annotator="ann")
    store.put(
        "heading", "city/cam", {"yaw_deg": 9.0}, source="annotator", annotator="bob"
    )  # 8 deg apart: 4x the threshold
    page, errors = open_page(browser, f"{server}/#task=review", "rev")
    loaded(page, "review")
    row = page.locator("#review-table tr[data-key='heading:city/cam']")
    assert "8.00°" in row.text_content() and "open" in row.get_attribute("class")
    assert page.locator("#review-table tbody tr").first.get_attribute("class").endswith("open")  # disagreements first
    row.click()
    loaded(page, "heading", "city/cam")
    assert page.locator("#review-badge").is_visible()
    page.keyboard.press("s")  # the reviewer settles it
    page.wait_for_selector("body[data-saved^='heading:city/cam:3']")
    assert store.get("heading", "city/cam").source == "reviewed"
    goto(page, "probe_pixel", "city/p1")
    box = page.locator("#pixel-view").bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.52, box["y"] + box["height"] * 0.86)
    shot(page, "probe_pixel")
    assert not errors


def test_traversal_404_and_token_401(server, browser, campaign):
    from solidkit.labeling.app import create_app

    page, _ = open_page(browser, f"{server}/")
    for url in (
        "/static/%2e%2e/%2e%2e/manifest.json",
        "/static/..%2f..%2fstore.py",
        "/api/img/..%2fmanifest.json/preview.jpg",
    ):
        assert page.request.get(server + url).status == 404
    root, alignment = campaign
    token = "token-for-the-browser-test"
    srv, thread, url = _serve(create_app(root, alignment=alignment, token=token))
    try:
        ctx = browser.new_context(viewport=VIEWPORT)
        ctx.add_init_script(_SEEN_GUIDES)
        page = ctx.new_page()
        page.goto(f"{url}/")
        assert page.request.get(f"{url}/api/campaign").status == 401
        page.wait_for_selector("#login:not([hidden])")
        page.fill("#login-name", "ann")
        page.fill("#login-token", token)
        shot(page, "login")
        page.keyboard.press("Enter")
        page.wait_for_selector("body[data-item^='sun:']", timeout=60000)  # generous: CI machines may be loaded
        assert page.request.get(f"{url}/api/campaign").status == 200  # the session cookie, not the URL
        assert token not in page.url
    finally:
        srv.should_exit = True
        thread.join(5)


def test_the_mark_readout_follows_the_visible_panel_after_switching_tasks(server, browser, campaign):
    """After the Sun panel has been shown, a click on the probe photo updates the Probe pixels panel's own
    "Your mark" readout (each panel writes into its own element, not the first one in the page)."""
    page, errors = open_page(browser, f"{server}/#task=sun&key=s1/p1")
    loaded(page, "sun", "s1/p1")
    goto(page, "probe_pixel", "s1/p1")
    x, y = blob(page, "#pixel-view", (255, 0, 0), tol=120)
    page.mouse.click(x, y)
    shown = page.locator("#draft-value:visible")
    assert shown.count() == 1
    assert numbers(shown.text_content()), shown.text_content()  # pixel coordinates, not "click the photo"
    assert not errors


def test_blind_mode_hides_the_other_annotators_values_in_the_history(server, browser, campaign):
    """Blind: the History block lists only the annotator's own changes, never another's value."""
    store = LabelStore(campaign[0])
    store.put("probe_pixel", "s1/p2", {"x": 123.0, "y": 45.0}, source="annotator", annotator="carol")
    page, errors = open_page(browser, f"{server}/#task=probe_pixel&key=s1/p2", "dave")
    loaded(page, "probe_pixel", "s1/p2")
    page.evaluate("() => { localStorage.setItem('solidkit.blind', '1'); }")
    page.reload()
    loaded(page, "probe_pixel", "s1/p2")
    panel = page.locator("#pixel-panel").text_content()
    assert "carol" not in panel and "123" not in panel, panel
    page.evaluate("() => { localStorage.setItem('solidkit.blind', '0'); }")
    page.reload()
    loaded(page, "probe_pixel", "s1/p2")
    assert "carol" in page.locator("#pixel-panel").text_content()  # seen again once not blind
    assert not errors


def test_wheel_zoom_stops_at_a_five_degree_view(server, browser, campaign):
    """Zooming in with the wheel stops at a 5° field of view (the sun a tenth of it), not at 1°."""
    page, errors = open_page(browser, f"{server}/#task=sun&key=s1/p1")
    loaded(page, "sun", "s1/p1")
    box = page.locator("#sun-sphere").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    for _ in range(40):
        page.mouse.wheel(0, -400)
    page.wait_for_timeout(300)
    fov = page.evaluate("() => window.solidkitApp.controller('sun').sphere.view().fov")
    assert fov == pytest.approx(5.0, abs=0.3)
    assert not errors


def test_layout_for_annotators_at_1024_px(server, browser, campaign):
    """At 1024 px the header keeps the user and help buttons; the overview strip is 2:1 (was about
    6:1); queue titles are whole and the dots have a legend; an automatic label is not shown as a
    stored (green) one and leaves the item to do; no internal words or raw flags."""
    LabelStore(campaign[0]).put(
        "sun", "city/cam", {"found": True, "azimuth_deg": -120.0, "elevation_deg": 35.0, "uncertainty_deg": 0.4},
        source="auto", annotator="align",
    )  # fmt: skip
    page, errors = open_page(
        browser, f"{server}/#task=sun&key=city/cam", "dave", viewport={"width": 1024, "height": 700}
    )
    loaded(page, "sun", "city/cam")
    for sel in ("#annotator-btn", "#help-btn"):
        box = page.locator(sel).bounding_box()
        assert box and box["x"] + box["width"] <= 1024, sel
    ov = page.locator("#sun-overview img").bounding_box()
    assert ov["width"] / ov["height"] == pytest.approx(2.0, abs=0.05)
    titles = page.locator("#queue-list .qt")
    assert titles.count() == 5
    assert not any(titles.nth(i).evaluate("e => e.scrollWidth > e.clientWidth + 1") for i in range(titles.count()))
    assert "camera position" in page.locator("#queue-list li[data-key='s1/cam']").text_content()
    legend = page.locator("#queue-legend").text_content()
    assert all(w in legend for w in ("to do", "done", "returned to you", "flagged"))
    assert page.locator("#saved-value").count() == 0 and page.locator("#stored-auto").is_visible()
    assert "done" not in page.locator("#queue-list li[data-key='city/cam']").get_attribute("class")
    text = ""
    for task, key in (("sun", "s1/p1"), ("sun", "s1/p2"), ("probe_pixel", "s1/p1"), ("heading", "s1/p2")):
        goto(page, task, key)
        text += page.locator("#panel").inner_text() + page.locator("#queue").inner_text()
    for word in ("align/", "pvlib", "field_notes", "low_confidence", "no_sun", "solidkit align"):
        assert word not in text, word
    assert "the automatic value is uncertain" in text  # low_confidence, said plainly
    assert not errors


def test_review_reject_returns_the_item_with_the_comment_and_no_nan(server, browser, campaign):
    """A reviewer rejects an annotator's pixel with a comment: the annotator's queue shows the item
    returned, with the comment in the panel. Switching to the Review tab logs no SVG NaN errors."""
    store = LabelStore(campaign[0])
    store.put("probe_pixel", "city/p1", {"x": 330.0, "y": 400.0}, source="annotator", annotator="carol")
    console: list[str] = []
    rev, errors = open_page(browser, f"{server}/#task=sun&key=s1/p1", "rev", console=console)
    loaded(rev, "sun", "s1/p1")
    rev.keyboard.press("4")
    loaded(rev, "review")
    rev.wait_for_timeout(400)
    assert not [c for c in console if "NaN" in c], console
    shot(rev, "review")
    rev.locator("#review-table tr[data-key='probe_pixel:city/p1']").click()
    loaded(rev, "probe_pixel", "city/p1")
    rev.fill("#verdict-comment", "that is the lamp post; the tripod stood left of it")
    shot(rev, "review_item")
    rev.locator("#review-box li[data-annotator='carol'] button.reject").click()
    rev.wait_for_selector("body[data-verdict^='probe_pixel:city/p1:carol:reject']")
    ann, errors_a = open_page(browser, f"{server}/#task=probe_pixel&key=city/p1", "carol")
    loaded(ann, "probe_pixel", "city/p1")
    assert "returned" in ann.locator("#queue-list li[data-key='city/p1']").get_attribute("class")
    assert "lamp post" in ann.locator("#returned").text_content()
    shot(ann, "returned")
    assert not errors and not errors_a


def test_redo_and_a_restart_keeps_the_unsaved_mark(server, browser, campaign):
    """Undo then redo puts the value back. A 401 (the server forgot the session, as after a restart)
    shows the login form, and the mark the annotator had not saved yet is saved after logging in."""
    root = campaign[0]
    page, errors = open_page(browser, f"{server}/#task=probe_pixel&key=s1/p1", "bob")
    loaded(page, "probe_pixel", "s1/p1")
    box = page.locator("#pixel-view").bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.4)
    mine = page.locator("#draft-value:visible").text_content()
    page.keyboard.press("s")
    page.wait_for_selector("body[data-saved^='probe_pixel:s1/p1:']")
    saved = LabelStore(root).get("probe_pixel", "s1/p1")
    goto(page, "probe_pixel", "s1/p1")
    page.keyboard.press("u")
    page.wait_for_function("() => !document.querySelector('#btn-redo').disabled")
    assert LabelStore(root).get("probe_pixel", "s1/p1") != saved
    page.keyboard.press("r")
    page.wait_for_function(
        f"() => document.body.dataset.saved && !document.body.dataset.saved.endsWith(':{saved.version}')"
    )
    assert LabelStore(root).get("probe_pixel", "s1/p1").value == saved.value
    page.mouse.click(box["x"] + box["width"] * 0.6, box["y"] + box["height"] * 0.5)
    mine = page.locator("#draft-value:visible").text_content()
    url_app[server].state.sessions.clear()  # what a restart does to the sessions
    page.keyboard.press("s")
    page.wait_for_selector("#login:not([hidden])")
    assert page.locator("#draft-value:visible").text_content() == mine  # still on screen
    page.fill("#login-name", "bob")
    page.keyboard.press("Enter")
    page.wait_for_function("() => !document.body.dataset.login")
    page.wait_for_function(
        "() => (document.body.dataset.saved || '').startsWith('probe_pixel:s1/p1:')"
        f" && !document.body.dataset.saved.endsWith(':{saved.version + 2}')"
    )
    lab = LabelStore(root).get("probe_pixel", "s1/p1")
    assert lab.annotator == "bob" and f"x {lab.value['x']:.1f}, y {lab.value['y']:.1f} px" == mine
    assert not errors


@pytest.mark.slow
def test_the_task_guide_opens_on_first_use(server, browser):
    page, errors = open_page(browser, f"{server}/#task=heading&key=s1/p1", "dave", guides_seen=False)
    loaded(page, "heading", "s1/p1")
    page.wait_for_selector("#guide:not([hidden])")
    assert "distant" in page.locator("#guide-body").text_content()
    page.keyboard.press("Escape")
    page.wait_for_selector("#guide", state="hidden")
    page.reload()
    loaded(page, "heading", "s1/p1")
    assert page.locator("#guide").is_hidden()  # once seen, not again
    assert not errors


def test_own_queue_in_blind_mode_and_skip_with_a_reason(server, browser, campaign):
    """Blind: another annotator's label does not make the item done in this annotator's queue (it
    did, so "next unfinished" skipped it). "Skip: can't tell" needs a reason, then counts as done."""
    store = LabelStore(campaign[0])
    store.put("heading", "s1/cam", {"yaw_deg": 12.0}, source="annotator", annotator="carol")
    page, errors = open_page(browser, f"{server}/#task=heading&key=s1/cam", "dave")
    page.add_init_script("localStorage.setItem('solidkit.blind', '1')")
    page.reload()
    loaded(page, "heading", "s1/cam")
    row = page.locator("#queue-list li[data-key='s1/cam']")
    assert "done" not in row.get_attribute("class") and "12.00" not in page.locator("#panel").inner_text()
    page.locator("details.note summary").click()
    page.locator("#btn-skip").click()  # no reason yet: refused
    page.wait_for_timeout(300)
    assert ("heading", "s1/cam", "dave") not in store.notes()
    page.fill("#note-text", "the photo shows only sky and cranes")
    page.locator("#btn-skip").click()
    page.wait_for_selector("body[data-noted='heading:s1/cam']")
    assert store.notes()[("heading", "s1/cam", "dave")].skip
    assert "done" in page.locator("#queue-list li[data-key='s1/cam']").get_attribute("class")
    assert not errors
