"""Benchmark of the labeling app: serving a 7296x3648 panorama, and labels per minute in a browser.

A. Serving (``solidkit label serve`` in its own process, a Theta Z1-sized 7296x3648 JPEG sun frame):
   memory (VmRSS / VmHWM of the server process) and latency of the preview, of full-resolution
   tiles (cold: first decode; encode from the decoded cache; warm: encoded cache) and of crops.
   Peer in the same run: sending the whole JPEG (Starlette ``StaticFiles`` on the campaign, the
   naive viewer) and decoding it as the browser would have to on every pan (``cv2.imdecode``).
B. A scripted annotator in Debian's chromium (Playwright): 20 sun frames (1024x512, suns at random
   directions, seed 0); (1) "click": find the sun in the overview strip, then in the rectilinear
   view, click its centre, save; (2) "accept": press A on align's proposal. Labels per minute and
   the clicked direction's error against the drawn truth.
C. The chain: the shipped mini campaign (solidkit/assets/campaign_mini) ingested and aligned, its
   sun frames labelled blind by the scripted annotator; its labels and align/'s against the
   campaign's truth, and whether the Review tab flags the labels that are off.

Writes benchmarks/results/labeling.json and labeling.md. Run: ``.venv/bin/python benchmarks/bench_labeling.py``.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from solidkit.capture.manifest import Manifest, Probe, Product, Scene, save_manifest  # noqa: E402
from solidkit.envmap.coords import angular_distance, direction_from_angles  # noqa: E402
from solidkit.labeling.store import LabelStore  # noqa: E402
from tests.support.labeling_campaign import disk  # noqa: E402

OUT = HERE / "results"
MINI = HERE.parent / "solidkit" / "assets" / "campaign_mini"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(app) -> tuple[object, threading.Thread, int]:
    """Serve ``app`` with uvicorn on a free port in a daemon thread; returns ``(server, thread, port)``."""
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, port=port, log_level="warning"))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    while not server.started:
        time.sleep(0.05)
    return server, th, port


def stop_server(server, th: threading.Thread) -> None:
    server.should_exit = True
    th.join(5)


def rss_mb(pid: int) -> dict[str, float]:
    status = Path(f"/proc/{pid}/status").read_text()
    out = {}
    for line in status.splitlines():
        if line.startswith(("VmRSS:", "VmHWM:")):
            out[line.split(":")[0]] = int(line.split()[1]) / 1024
    return out


HEADERS: dict[str, str] = {}  # the session cookie of the server under test


def get(url: str) -> tuple[float, bytes]:
    t0 = time.perf_counter()
    with urllib.request.urlopen(urllib.request.Request(url, headers=HEADERS), timeout=300) as r:
        data = r.read()
    return time.perf_counter() - t0, data


def wait_up(url: str, proc: subprocess.Popen) -> None:
    for _ in range(600):
        if proc.poll() is not None:
            raise RuntimeError(f"server exited: {proc.stderr.read().decode()[-2000:]}")
        try:
            get(url)
            return
        except OSError:
            time.sleep(0.1)
    raise RuntimeError("server did not start")


def login(ctx, port: int, name: str) -> None:
    """Log a Playwright browser context in as ``name`` (guides marked seen: they would take the keys)."""
    ctx.add_init_script(
        "for (const t of ['sun', 'probe_pixel', 'heading']) localStorage.setItem('solidkit.guide.' + t, '1')"
    )
    r = ctx.request.post(f"http://127.0.0.1:{port}/api/session", data={"name": name}, headers={"X-Solidkit": "1"})
    assert r.ok, r.text()


def session_cookie(base: str, name: str) -> dict[str, str]:
    """Headers of a logged-in session (``{}`` for a server without logins, as before users existed)."""
    req = urllib.request.Request(
        base + "/api/session", data=json.dumps({"name": name}).encode(), method="POST",
        headers={"Content-Type": "application/json", "X-Solidkit": "1"},
    )  # fmt: skip
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            cookie = r.headers.get("set-cookie", "").split(";")[0]
    except urllib.error.HTTPError:
        return {}
    return {"Cookie": cookie} if cookie else {}


def big_campaign(root: Path) -> Path:
    """One scene, one position, a 7296x3648 JPEG sun frame (sky gradient, noise, a sun)."""
    h, w = 3648, 7296
    rng = np.random.default_rng(0)
    y = np.linspace(0, 1, h, dtype=np.float32)[:, None, None]
    img = (40 + 60 * (1 - y)) * np.array([1.0, 0.8, 0.6], np.float32) + rng.normal(0, 6, (h, w, 3)).astype(np.float32)
    img = np.clip(img, 0, 255).astype(np.uint8)
    small = np.zeros((512, 1024, 3), np.uint8)
    disk(small, 30.0, 40.0, 0.4, (255, 255, 255))
    img = np.maximum(img, cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR))
    rel = "products/s1/p1/sun.jpg"
    (root / rel).parent.mkdir(parents=True)
    cv2.imwrite(str(root / rel), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    products = [
        Product(id="s1/p1/sun", kind="sun_frame", scene="s1", probe="p1", inputs=[], path=rel, layout="equirect")
    ]
    save_manifest(
        root, Manifest(scenes=[Scene(id="s1", grouping="folder", probes=[Probe(id="p1", shots=[])])], products=products)
    )
    return root / rel


def bench_serving(tmp: Path) -> dict:
    camp = tmp / "big"
    jpeg = big_campaign(camp)
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    code = "import sys; from solidkit.cli import main; sys.argv = ['solidkit'] + sys.argv[1:]; main()"
    proc = subprocess.Popen([sys.executable, "-c", code, "label", "serve", str(camp), "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)  # fmt: skip
    base = f"http://127.0.0.1:{port}"
    res: dict = {"file_mb": jpeg.stat().st_size / 1e6, "size": [7296, 3648]}
    try:
        wait_up(base + "/api/session", proc)
        HEADERS.update(session_cookie(base, "bench"))
        res["rss_idle_mb"] = rss_mb(proc.pid)["VmRSS"]
        item = json.loads(get(base + "/api/item?kind=sun&key=s1/p1")[1])
        img = item["view"]["image"]
        res["tiles"] = img["tiles"]
        res["preview_cold_s"], prev = get(f"{base}/api/img/{img['id']}/preview.jpg")
        res["preview_kb"] = len(prev) / 1e3
        res["preview_warm_s"] = min(get(f"{base}/api/img/{img['id']}/preview.jpg")[0] for _ in range(5))
        res["rss_after_preview_mb"] = rss_mb(proc.pid)["VmRSS"]
        cols, rows = img["tiles"]["cols"], img["tiles"]["rows"]
        times, sizes = [], []
        for r in range(rows):
            for c in range(cols):
                t, data = get(f"{base}/api/img/{img['id']}/tile/{c}/{r}.jpg")
                times.append(t)
                sizes.append(len(data))
        res["tile_encode_median_s"] = statistics.median(times)
        res["tile_kb_median"] = statistics.median(sizes) / 1e3
        res["tiles_all_mb"] = sum(sizes) / 1e6
        res["tile_warm_median_s"] = statistics.median(
            get(f"{base}/api/img/{img['id']}/tile/{c}/{r}.jpg")[0] for c in range(4) for r in range(2)
        )
        crops = [
            get(f"{base}/api/img/{img['id']}/crop.jpg?x={1000 + 64 * k}&y=800&w=1024&h=640&out=1024")[0]
            for k in range(5)
        ]
        res["crop_median_s"] = statistics.median(crops)
        mem = rss_mb(proc.pid)
        res["rss_after_all_tiles_mb"], res["rss_peak_mb"] = mem["VmRSS"], mem["VmHWM"]
    finally:
        proc.terminate()
        proc.wait(10)
    # the peer: the whole JPEG from a static file server, decoded like a browser must on each pan
    from starlette.applications import Starlette
    from starlette.routing import Mount
    from starlette.staticfiles import StaticFiles

    server, th, port = start_server(Starlette(routes=[Mount("/", StaticFiles(directory=camp))]))
    whole = [get(f"http://127.0.0.1:{port}/products/s1/p1/sun.jpg") for _ in range(3)]
    stop_server(server, th)
    res["peer_whole_jpeg_s"] = min(t for t, _ in whole)
    data = whole[0][1]
    t0 = time.perf_counter()
    cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    res["peer_decode_s"] = time.perf_counter() - t0
    # a pan at a 30 deg field of view needs ~2 new full-resolution tiles (456 px = 22.5 deg each)
    res["bytes_per_pan_ratio_whole_over_tiles"] = res["file_mb"] * 1e3 / (2 * res["tile_kb_median"])
    res["first_view_ratio_whole_over_preview_plus_4_tiles"] = (
        res["file_mb"] * 1e3 / (res["preview_kb"] + 4 * res["tile_kb_median"])
    )
    return res


def hdr_campaign(root: Path) -> None:
    """One scene: a 640x480 photo and one position whose HDR product is a 7296x3648 EXR (float32, ZIP; a
    sky gradient with noise, a ground, a sun of 1e5), so the heading task shows it."""
    from solidkit.capture.manifest import Shot
    from solidkit.envmap.io import write_exr

    h, w = 3648, 7296
    rng = np.random.default_rng(0)
    img = np.empty((h, w, 3), np.float32)
    for y0 in range(0, h, 456):  # in strips: the benchmark's own memory stays small
        y = np.linspace(y0 / h, (y0 + 456) / h, 456, endpoint=False, dtype=np.float32)[:, None, None]
        sky = np.where(y < 0.5, 2.0 - 2.0 * y, 0.3) * np.array([0.6, 0.8, 1.0], np.float32)
        img[y0 : y0 + 456] = sky * (1 + 0.05 * rng.standard_normal((456, w, 3), dtype=np.float32))
    img[1000:1030, 2000:2030] = 1e5  # the sun
    write_exr(root / "products/s1/p1/hdr-b01.exr", img)
    del img
    (root / "originals").mkdir(parents=True)
    cv2.imwrite(str(root / "originals/photo.jpg"), np.full((480, 640, 3), 120, np.uint8))
    shot = Shot(sha256="a" * 64, original="originals/photo.jpg", size=1, file_format="jpeg", sources=[],
                metadata={"path": "photo.jpg", "width": 640, "height": 480, "focal_length_35mm": 28.0},
                kind="photo", scene="s1")  # fmt: skip
    products = [Product(id="s1/p1/hdr-b01", kind="hdr", scene="s1", probe="p1", inputs=[],
                        path="products/s1/p1/hdr-b01.exr", layout="equirect")]  # fmt: skip
    scene = Scene(id="s1", grouping="folder", photos=["a" * 64], photo="a" * 64, camera_probe="p1",
                  probes=[Probe(id="p1", shots=[], role="camera")])  # fmt: skip
    save_manifest(root, Manifest(shots=[shot], scenes=[scene], products=products))


def first_heading_view(camp: Path, src: Path, label: str) -> dict:
    """``solidkit label serve`` from source tree ``src`` on ``camp``: the time of the first heading
    item's view (item, panorama preview, photo preview, the 8 tiles of the middle row, in turn), the
    server's peak memory (VmHWM) after it, and the same after a restart (the disk cache warm)."""
    out: dict = {"source": label}
    cache = camp / "labels" / "image-cache"
    for run in ("cold", "prepared", "restart"):
        if run == "prepared" and (src / "solidkit/labeling/images.py").read_text().count("def warm(") == 0:
            continue  # a tree without the background preparation
        port = free_port()
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(src)}
        code = "import sys; from solidkit.cli import main; sys.argv = ['solidkit'] + sys.argv[1:]; main()"
        proc = subprocess.Popen([sys.executable, "-c", code, "label", "serve", str(camp), "--port", str(port)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=src)  # fmt: skip
        base = f"http://127.0.0.1:{port}"
        try:
            t_start = time.perf_counter()
            if run == "prepared":
                shutil.rmtree(cache, ignore_errors=True)  # a fresh campaign again ...
            wait_up(base + "/", proc)
            HEADERS.clear()
            HEADERS.update(session_cookie(base, "bench"))
            idle = rss_mb(proc.pid)["VmRSS"]
            if run == "prepared":  # ... opened once the server has prepared its images
                while len(list(cache.glob("*/*.jpg"))) < 1 + 128 + 1 and proc.poll() is None:
                    time.sleep(0.1)
                out["preparation_s"] = round(time.perf_counter() - t_start, 2)
            t0 = time.perf_counter()
            item = json.loads(get(base + "/api/item?kind=heading&key=s1/p1")[1])
            t_item = time.perf_counter() - t0
            img, photo = item["view"]["image"], item["view"]["photo"]["image"]
            get(f"{base}/api/img/{img['id']}/preview.jpg")
            get(f"{base}/api/img/{photo['id']}/preview.jpg")
            t_view = time.perf_counter() - t0
            cols, rows = img["tiles"]["cols"], img["tiles"]["rows"]
            for c in range(cols // 2 - 4, cols // 2 + 4):
                get(f"{base}/api/img/{img['id']}/tile/{c}/{rows // 2}.jpg")
            t_tiles = time.perf_counter() - t0
            mem = rss_mb(proc.pid)
            out[run] = {"item_s": round(t_item, 3), "first_view_s": round(t_view, 3),
                        "first_view_plus_8_tiles_s": round(t_tiles, 3), "rss_idle_mb": round(idle),
                        "peak_mb": round(mem["VmHWM"])}  # fmt: skip
        finally:
            proc.terminate()
            proc.wait(10)
    return out


def bench_hdr(tmp: Path) -> dict:
    """First heading view of a 7296x3648 HDR: this tree, and the tree at $SOLIDKIT_BENCH_PEER_SRC (e.g. a
    `git worktree` of the commit before the header read and disk cache) as the peer."""
    camp = tmp / "hdr"
    hdr_campaign(camp)
    res = {"size": [7296, 3648], "exr_mb": round((camp / "products/s1/p1/hdr-b01.exr").stat().st_size / 1e6, 1)}
    LabelStore(camp).add_user("bench", "annotator")
    res["app"] = first_heading_view(camp, HERE.parent, "this tree")
    peer = os.environ.get("SOLIDKIT_BENCH_PEER_SRC")
    if peer:
        old = tmp / "hdr-peer"
        shutil.copytree(camp, old, ignore=shutil.ignore_patterns("labels"))
        res["peer"] = first_heading_view(old, Path(peer), f"peer tree {peer}")
    shutil.rmtree(camp, ignore_errors=True)
    return res


def sun_campaign(root: Path, n_scenes: int = 5, per_scene: int = 4, seed: int = 0) -> tuple[dict, dict]:
    """n_scenes x per_scene sun frames (1024x512) with a 0.5 deg-radius sun at random directions;
    an alignment dict whose proposals are off by ~0.2 deg."""
    rng = np.random.default_rng(seed)
    truth, products, scenes, align = {}, [], [], {"scenes": []}
    for s in range(n_scenes):
        probes, captures = [], []
        for p in range(per_scene):
            az, el = float(rng.uniform(-180, 180)), float(rng.uniform(5, 75))
            key = f"sc{s:02d}/p{p}"
            truth[key] = (az, el)
            pano = np.full((512, 1024, 3), 10, np.uint8)
            disk(pano, az, el, 0.9, (255, 255, 255))
            rel = f"products/{key}/sun.png"
            (root / rel).parent.mkdir(parents=True)
            cv2.imwrite(str(root / rel), pano)
            products.append(
                Product(
                    id=f"{key}/sun",
                    kind="sun_frame",
                    scene=f"sc{s:02d}",
                    probe=f"p{p}",
                    inputs=[],
                    path=rel,
                    layout="equirect",
                )
            )
            probes.append(Probe(id=f"p{p}", shots=[]))
            captures.append({"probe": f"p{p}", "found": True, "azimuth_deg": az + rng.normal(0, 0.2),
                             "elevation_deg": el + rng.normal(0, 0.2), "uncertainty_deg": 0.3,
                             "candidates": []})  # fmt: skip
        scenes.append(Scene(id=f"sc{s:02d}", grouping="folder", probes=probes))
        align["scenes"].append({"id": f"sc{s:02d}", "sun": {"found": True, "captures": captures}, "probes": []})
    save_manifest(root, Manifest(scenes=scenes, products=products))
    return truth, align


def bench_annotator(tmp: Path) -> dict:
    from playwright.sync_api import sync_playwright

    from solidkit.labeling.app import create_app

    res: dict = {}
    for mode in ("click", "accept"):
        camp = tmp / f"sun_{mode}"
        camp.mkdir()
        truth, align = sun_campaign(camp)
        server, th, port = start_server(create_app(camp, alignment=align))
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            ctx = browser.new_context(viewport={"width": 1366, "height": 768})
            login(ctx, port, "bench")
            page = ctx.new_page()
            keys = list(truth)
            page.goto(f"http://127.0.0.1:{port}/#task=sun&key={keys[0]}")
            page.wait_for_selector(f"body[data-item='sun:{keys[0]}']", timeout=30000)
            t0 = time.perf_counter()
            for _, key in enumerate(keys):
                page.wait_for_selector(f"body[data-item='sun:{key}']", timeout=30000)
                if mode == "accept":
                    page.keyboard.press("a")
                else:
                    strip = page.locator("#sun-overview")
                    box = strip.bounding_box()
                    shot = cv2.imdecode(np.frombuffer(strip.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE)
                    ys, xs = np.nonzero(shot >= shot.max() - 10)  # the brightest spot, as an eye would
                    page.mouse.click(
                        box["x"] + xs.mean() * box["width"] / shot.shape[1],
                        box["y"] + ys.mean() * box["height"] / shot.shape[0],
                    )
                    page.wait_for_timeout(120)
                    view = page.locator("#sun-sphere")
                    vb = view.bounding_box()
                    g = cv2.imdecode(np.frombuffer(view.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE)
                    ys, xs = np.nonzero(g > 200)
                    page.mouse.click(
                        vb["x"] + (xs.mean() + 0.5) * vb["width"] / g.shape[1],
                        vb["y"] + (ys.mean() + 0.5) * vb["height"] / g.shape[0],
                    )
                    page.keyboard.press("s")
                page.wait_for_selector(f"body[data-saved^='sun:{key}:']", timeout=30000)
            elapsed = time.perf_counter() - t0
            browser.close()
        stop_server(server, th)
        store = LabelStore(camp)
        errs = []
        for key, (az, el) in truth.items():
            v = store.get("sun", key).value
            a = np.asarray(direction_from_angles(math.radians(v["azimuth_deg"]), math.radians(v["elevation_deg"])))
            b = np.asarray(direction_from_angles(math.radians(az), math.radians(el)))
            errs.append(math.degrees(float(angular_distance(a, b))))
        res[mode] = {
            "labels": len(keys), "seconds": elapsed, "labels_per_minute": 60 * len(keys) / elapsed,
            "error_deg_median": statistics.median(errs), "error_deg_max": max(errs),
        }  # fmt: skip
    return res


def chain_mini(tmp: Path) -> Path:
    """The shipped mini campaign's card -> `solidkit ingest` -> `solidkit align`; returns the campaign."""
    code = "import sys; from solidkit.cli import main; sys.argv = ['solidkit'] + sys.argv[1:]; main()"
    camp = tmp / "mini"
    for args in (["ingest", str(MINI / "card"), "-o", str(camp)], ["align", str(camp), "--no-report"]):
        subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True)
    return camp


def truth_suns(truth_json: Path) -> dict[str, tuple[bool, float | None, float | None]]:
    """Truth sun per capture in the level frame of its sun-frame product (as align/evaluate.py:
    ``R(0, recorded pitch, recorded roll) sun_body``); read only here, to measure."""
    from solidkit.envmap.coords import angles_from_direction, rotation_from_ypr

    out = {}
    for st in json.loads(truth_json.read_text())["scenes"]:
        for ct in st["captures"]:
            if not ct["sun_visible"] or ct["sun_body"] is None:
                out[f"{st['id']}/{ct['id']}"] = (False, None, None)
                continue
            R = np.asarray(
                rotation_from_ypr(0.0, math.radians(ct["recorded_pitch_deg"]), math.radians(ct["recorded_roll_deg"]))
            )
            az, el = (math.degrees(float(v)) for v in angles_from_direction(R @ np.asarray(ct["sun_body"])))
            out[f"{st['id']}/{ct['id']}"] = (True, az, el)
    return out


def bench_virtual_campaign(campaign: Path, truth_json: Path, tmp: Path) -> dict:
    """A scripted annotator labels every sun frame of an ingested + aligned virtual campaign in the
    browser (brightest blob, clicked at its centre in the rectilinear view; "no sun" when nothing is
    saturated); its labels and align/'s automatic ones against the truth."""
    from playwright.sync_api import sync_playwright

    from solidkit.align.schema import load_alignment
    from solidkit.labeling.app import create_app

    camp = Path(tempfile.mkdtemp(prefix=".bench-labeling-", dir=campaign.parent))  # hard links: same file system
    for name in ("originals", "products", "align"):
        shutil.copytree(campaign / name, camp / name, copy_function=os.link)
    shutil.copy(campaign / "manifest.json", camp / "manifest.json")  # a fresh label store: labels/ not copied
    align = load_alignment(camp).model_dump(mode="json")
    auto = {f"{s['id']}/{c['probe']}": c for s in align["scenes"] for c in s["sun"]["captures"]}
    truth = truth_suns(truth_json)
    server, th, port = start_server(create_app(camp, alignment=align))
    keys = [q["key"] for q in json.loads(get(f"http://127.0.0.1:{port}/api/queue/sun")[1])["items"]]
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        ctx = browser.new_context(viewport={"width": 1366, "height": 768})
        login(ctx, port, "bench")
        ctx.add_init_script("localStorage.setItem('solidkit.blind', '1')")
        page = ctx.new_page()  # blind: the scripted annotator does not see align's proposal
        t0 = time.perf_counter()
        for key in keys:
            page.goto(f"http://127.0.0.1:{port}/#task=sun&key={key}")
            page.wait_for_selector(f"body[data-item='sun:{key}']", timeout=30000)
            strip = page.locator("#sun-overview img")
            box = strip.bounding_box()
            g = cv2.imdecode(np.frombuffer(strip.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE)
            if g.max() < 120:  # nothing bright in the (downscaled) strip
                page.keyboard.press("n")
            else:  # look at the biggest small bright blob of the strip (not a bright sky patch), as an eye would
                n, _, stats, cent = cv2.connectedComponentsWithStats((g >= int(g.max()) - 20).astype(np.uint8))
                area = np.where(stats[1:, cv2.CC_STAT_AREA] <= 0.002 * g.size, stats[1:, cv2.CC_STAT_AREA], 0)
                c = 1 + int(np.argmax(area))
                page.mouse.click(
                    box["x"] + (cent[c][0] + 0.5) * box["width"] / g.shape[1],
                    box["y"] + (cent[c][1] + 0.5) * box["height"] / g.shape[0],
                )
                page.wait_for_timeout(150)
                view = page.locator("#sun-sphere")
                vb = view.bounding_box()
                v = cv2.imdecode(np.frombuffer(view.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE)
                n, _, stats, cent = cv2.connectedComponentsWithStats((v >= 250).astype(np.uint8))
                if n < 2:
                    page.keyboard.press("n")
                else:
                    c = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
                    page.mouse.click(
                        vb["x"] + (cent[c][0] + 0.5) * vb["width"] / v.shape[1],
                        vb["y"] + (cent[c][1] + 0.5) * vb["height"] / v.shape[0],
                    )
                    page.keyboard.press("s")
            page.wait_for_selector(f"body[data-saved^='sun:{key}:']", timeout=30000)
        elapsed = time.perf_counter() - t0
        browser.close()
    review = json.loads(get(f"http://127.0.0.1:{port}/api/queue/review")[1])["items"]
    flagged = {
        r["key"] for r in review if r["kind"] == "sun" and any(f.startswith("differs_from_auto") for f in r["flags"])
    }
    stop_server(server, th)
    store = LabelStore(camp)

    def err(v: dict, t: tuple) -> float | None:
        if not (v.get("found") and t[0]):
            return None
        a = np.asarray(direction_from_angles(math.radians(v["azimuth_deg"]), math.radians(v["elevation_deg"])))
        b = np.asarray(direction_from_angles(math.radians(t[1]), math.radians(t[2])))
        return math.degrees(float(angular_distance(a, b)))

    rows = []
    for key in keys:
        t = truth.get(key)
        if t is None:
            continue
        human = store.get("sun", key).value
        a = auto.get(key, {})
        rows.append({"key": key, "truth_visible": t[0], "scripted_found": human["found"],
                     "auto_found": bool(a.get("found")), "scripted_error_deg": err(human, t),
                     "auto_error_deg": err(a, t) if a else None, "review_flags_it": key in flagged})  # fmt: skip
    se = [r["scripted_error_deg"] for r in rows if r["scripted_error_deg"] is not None]
    ae = [r["auto_error_deg"] for r in rows if r["auto_error_deg"] is not None]
    out = {
        "campaign": str(campaign), "truth": str(truth_json), "captures": len(rows), "seconds": elapsed,
        "labels_per_minute": 60 * len(keys) / elapsed,
        "scripted_error_deg_median": statistics.median(se) if se else None,
        "scripted_error_deg_max": max(se) if se else None,
        "auto_error_deg_median": statistics.median(ae) if ae else None, "auto_error_deg_max": max(ae) if ae else None,
        "found_agrees_with_truth_scripted": sum(r["scripted_found"] == r["truth_visible"] for r in rows),
        "found_agrees_with_truth_auto": sum(r["auto_found"] == r["truth_visible"] for r in rows),
        "scripted_within_1deg": sum(e <= 1.0 for e in se),
        "scripted_over_1deg_flagged_by_review": sum(
            r["review_flags_it"] for r in rows if (r["scripted_error_deg"] or 0) > 1.0
        ),
        "scripted_over_1deg": sum(e > 1.0 for e in se),
        "rows": rows,
    }  # fmt: skip
    shutil.rmtree(camp)
    return out


def main() -> None:
    OUT.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        hdr = bench_hdr(tmp)
        if os.environ.get("SOLIDKIT_BENCH_ONLY") == "hdr":
            hdr["load_average_1min"] = os.getloadavg()[0]
            (OUT / "labeling_hdr.json").write_text(json.dumps(hdr, indent=1) + "\n")
            print(json.dumps(hdr, indent=1))
            return
        serving = bench_serving(tmp)
        annot = bench_annotator(tmp) if Path(CHROMIUM).is_file() else {"skipped": "no chromium"}
        # an ingested + aligned virtual campaign and its truth: $SOLIDKIT_BENCH_CAMPAIGN/_TRUTH, else the
        # shipped mini campaign run through `solidkit ingest` and `solidkit align` here
        vc, vt = os.environ.get("SOLIDKIT_BENCH_CAMPAIGN"), os.environ.get("SOLIDKIT_BENCH_TRUTH")
        if not (vc and vt) and MINI.is_dir():
            vc, vt = str(chain_mini(tmp)), str(MINI / "truth" / "truth.json")
        virtual = (
            bench_virtual_campaign(Path(vc), Path(vt), tmp)
            if vc and vt and Path(CHROMIUM).is_file()
            else {"skipped": "no chromium, or no campaign (set SOLIDKIT_BENCH_CAMPAIGN and SOLIDKIT_BENCH_TRUTH)"}
        )
    load = os.getloadavg()[0]
    doc = {
        "machine": platform.platform(),
        "load_average_1min": load,
        "serving_7296x3648": serving,
        "hdr_first_heading_view_7296x3648": hdr,
        "scripted_annotator": annot,
        "virtual_campaign": virtual,
    }
    (OUT / "labeling.json").write_text(json.dumps(doc, indent=1) + "\n")
    s = serving
    lines = [
        "# Labeling app",
        "",
        f"Machine: {platform.machine()}, load average {load:.1f} during the run (shared; numbers are upper bounds).",
        "",
        f"## Serving a 7296x3648 panorama ({s['file_mb']:.1f} MB JPEG)",
        "",
        "| what | app (preview + tiles) | peer: whole JPEG |",
        "|---|---|---|",
        f"| first view | preview {s['preview_kb']:.0f} kB in {s['preview_cold_s']:.2f} s cold, "
        f"{s['preview_warm_s'] * 1e3:.0f} ms warm | {s['file_mb'] * 1e3:.0f} kB in {s['peer_whole_jpeg_s'] * 1e3:.0f} "
        f"ms + {s['peer_decode_s'] * 1e3:.0f} ms decode |",
        f"| one pan (~2 new tiles of {s['tiles']['cols']}x{s['tiles']['rows']}) | {2 * s['tile_kb_median']:.0f} kB, "
        f"{s['tile_encode_median_s'] * 1e3:.0f} ms/tile (encode), {s['tile_warm_median_s'] * 1e3:.1f} ms/tile cached | "
        f"{s['file_mb'] * 1e3:.0f} kB again |",
        f"| bytes ratio whole/app | per pan {s['bytes_per_pan_ratio_whole_over_tiles']:.0f}x, first view "
        f"{s['first_view_ratio_whole_over_preview_plus_4_tiles']:.1f}x | |",
        f"| crop 1024x640 (photo zoom) | {s['crop_median_s'] * 1e3:.0f} ms | |",
        "",
        f"Server memory: {s['rss_idle_mb']:.0f} MB idle, {s['rss_after_preview_mb']:.0f} MB after the preview (decoded "
        f"image cached), {s['rss_after_all_tiles_mb']:.0f} MB after all {s['tiles']['cols'] * s['tiles']['rows']} "
        f"tiles ({s['tiles_all_mb']:.1f} MB encoded, cached), peak {s['rss_peak_mb']:.0f} MB.",
        "",
        f"## First heading view of a 7296x3648 HDR ({hdr['exr_mb']:.0f} MB EXR)",
        "",
        "Item, panorama preview and photo preview in turn (then 8 full-resolution tiles); cold: a fresh campaign, "
        "restart: the server started again on it.",
        "",
        "| tree | run | first view | + 8 tiles | server peak (VmHWM) |",
        "|---|---|---|---|---|",
        *(
            f"| {r['source']} | {run} | {r[run]['first_view_s']:.2f} s | {r[run]['first_view_plus_8_tiles_s']:.2f} s | "
            f"{r[run]['peak_mb']} MB |"
            for r in (hdr["app"], hdr.get("peer"))
            if r
            for run in ("cold", "prepared", "restart")
            if run in r
        ),
        "",
        "## Scripted annotator in chromium (20 sun frames, 1024x512)",
        "",
    ]
    if "skipped" in annot:
        lines.append("skipped: no chromium")
    else:
        lines += ["| mode | labels/min | median error vs truth | max error |", "|---|---|---|---|"]
        for mode, r in annot.items():
            lines.append(
                f"| {mode} | {r['labels_per_minute']:.0f} | {r['error_deg_median']:.3f} deg | {r['error_deg_max']:.3f} "
                "deg |"
            )
    lines += ["", "## A virtual campaign's sun frames, labelled blind by the scripted annotator, against the truth", ""]
    if "skipped" in virtual:
        lines.append(f"skipped: {virtual['skipped']}")
    else:
        v = virtual
        lines += [
            f"{v['captures']} captures of `{v['campaign']}` (truth `{v['truth']}`), {v['labels_per_minute']:.0f} "
            "labels/min.",
            "",
            "| labels | median error | max error | found/not found agrees with truth |",
            "|---|---|---|---|",
            f"| scripted annotator in the app | {v['scripted_error_deg_median']:.3f} deg | "
            f"{v['scripted_error_deg_max']:.3f} deg | {v['found_agrees_with_truth_scripted']}/{v['captures']} |",
            f"| align/ (auto) | {v['auto_error_deg_median']:.3f} deg | {v['auto_error_deg_max']:.3f} deg | "
            f"{v['found_agrees_with_truth_auto']}/{v['captures']} |",
            "",
            f"Scripted labels within 1 deg of the truth: {v['scripted_within_1deg']}; more than 1 deg off (a wrong "
            f"blob clicked): {v['scripted_over_1deg']}, of which the Review tab flags "
            f"{v['scripted_over_1deg_flagged_by_review']} as `differs_from_auto`.",
        ]
    (OUT / "labeling.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
