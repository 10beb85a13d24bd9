"""`solidkit ingest`: content-addressed originals, grouping, products, idempotence, kill -9 resume."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin
from typer.testing import CliRunner

from solidkit.capture.campaign import ingest
from solidkit.capture.manifest import MANIFEST_NAME, SCHEMA_VERSION, load_manifest
from solidkit.envmap.io import read_exr
from solidkit.errors import InputError

REPO = Path(__file__).resolve().parents[2]
T0 = datetime(2024, 6, 1, 12, 0, 0)
XMP_EQUIRECT = (
    b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    b'<rdf:Description xmlns:GPano="http://ns.google.com/photos/1.0/panorama/" GPano:ProjectionType="equirectangular"/>'
    b"</rdf:RDF></x:xmpmeta>"
)
RADIANCE = np.exp(np.linspace(np.log(0.5), np.log(500.0), 64))[None, :, None] * np.array([1.0, 0.8, 0.6])


def write_shot(
    path: Path, when: datetime, exposure: tuple[int, int], make: str = "RICOH", model: str = "RICOH THETA V"
) -> None:
    """A 64x32 equirect JPEG of a synthetic gradient scene exposed for ``exposure`` seconds, with EXIF."""
    t = exposure[0] / exposure[1]
    code = np.round(255 * np.clip(RADIANCE * t, 0, 1) ** (1 / 2.2)).astype(np.uint8)
    img = Image.fromarray(np.broadcast_to(code, (32, 64, 3)).copy())
    ex = Image.Exif()
    ex[0x010F], ex[0x0110] = make, model
    ifd = ex.get_ifd(0x8769)
    ifd[0x829A] = TiffImagePlugin.IFDRational(*exposure)
    ifd[0x829D] = TiffImagePlugin.IFDRational(2, 1)
    ifd[0x8827] = 100
    ifd[0x9003] = when.strftime("%Y:%m:%d %H:%M:%S")
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path, exif=ex.tobytes(), xmp=XMP_EQUIRECT if make == "RICOH" else b"", quality=95)


def make_card(root: Path, bad: bool = True, extra_brackets: int = 0) -> Path:
    """A Theta card in the camera's own layout (DCIM/100RICOH), two scenes, plus a photo and junk."""
    d = root / "DCIM" / "100RICOH"
    n = [0]

    def shot(dt: float, exposure: tuple[int, int], **kw) -> Path:
        n[0] += 1
        p = d / f"R00100{n[0]:02d}.JPG"
        write_shot(p, T0 + timedelta(seconds=dt), exposure, **kw)
        return p

    # scene 1, probe 1: a 3-shot bracket, then the sun frame 20 s later
    shot(0, (1, 500)), shot(1, (1, 125)), shot(2, (1, 30))
    shot(22, (1, 25000))
    # scene 1, probe 2 (2 minutes later): a single shot and a 2-shot bracket
    shot(140, (1, 60))
    shot(160, (1, 250)), shot(161, (1, 15))
    # scene 2, two hours later: a bracket
    shot(7200, (1, 1000)), shot(7201, (1, 100)), shot(7202, (1, 10))
    for i in range(extra_brackets):
        base = 14400 + 60 * i
        shot(base, (1, 1000)), shot(base + 1, (1, 100)), shot(base + 2, (1, 10))
    # the scene photo from another camera
    write_shot(
        root / "DCIM" / "100CANON" / "IMG_0001.JPG", T0 + timedelta(seconds=60), (1, 200), make="Canon", model="EOS R"
    )
    (root / "notes.txt").write_text("field notes\n")
    (root / ".hidden.JPG").write_bytes(b"x")
    (d / "R0010099.MP4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    if bad:
        (d / "R0010090.JPG").write_bytes(b"")
        good = (d / "R0010001.JPG").read_bytes()
        (d / "R0010091.JPG").write_bytes(good[: len(good) // 2])
        (d / "R0010092.JPG").write_bytes(b"II*\x00\x08\x00\x00\x00" + bytes(64))
    return root


def tree_digest(root: Path) -> dict[str, tuple[str, int]]:
    return {
        str(p.relative_to(root)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def card(tmp_path) -> Path:
    return make_card(tmp_path / "card")


def test_ingest_builds_campaign(card, tmp_path):
    before = tree_digest(card)
    camp = tmp_path / "camp"
    report = ingest(card, camp)
    assert tree_digest(card) == before  # the card is never modified
    m = load_manifest(camp)
    assert m.schema_version == SCHEMA_VERSION and m.solidkit_version

    # originals: content-addressed, byte-identical, read-only
    assert len(m.shots) == 11 and report.copied == 11
    for s in m.shots:
        orig = camp / s.original
        assert orig.read_bytes() == (card / s.sources[0].path).read_bytes()
        assert hashlib.sha256(orig.read_bytes()).hexdigest() == s.sha256 and s.sha256 in orig.name
        assert orig.stat().st_mode & 0o222 == 0

    # grouping: 2 scenes; scene 1 has probes p01 (bracket + sun frame) and p02, and the photo
    assert [sc.id for sc in m.scenes] == ["scene-20240601-120000", "scene-20240601-140000"]
    s1 = m.scenes[0]
    assert [p.id for p in s1.probes] == ["p01", "p02"] and len(s1.photos) == 1
    kinds = {s.sources[0].path.rsplit("/", 1)[-1]: s.kind for s in m.shots}
    assert kinds["R0010001.JPG"] == kinds["R0010003.JPG"] == "bracket_member"
    assert kinds["R0010004.JPG"] == "low_exposure" and kinds["R0010005.JPG"] == "probe"
    assert kinds["IMG_0001.JPG"] == "photo"
    p01 = s1.probes[0]
    assert [b.exposure_times for b in p01.brackets] == [[1 / 500, 1 / 125, 1 / 30]]
    assert m.shot(p01.sun_frame).metadata["exposure_time"] == pytest.approx(1 / 25000)

    # products: 3 HDR merges + 1 sun frame, reproducible records
    kinds = sorted(p.kind for p in m.products)
    assert kinds == ["hdr", "hdr", "hdr", "sun_frame"]
    sun = next(p for p in m.products if p.kind == "sun_frame")
    assert sun.path == m.shot(p01.sun_frame).original and sun.exposure_time == pytest.approx(1 / 25000)
    assert sun.layout == "equirect" and sun.error is None
    for p in m.products:
        if p.kind == "hdr":
            hdr, meta = read_exr(camp / p.path)
            assert [i["sha256"] for i in meta["provenance"]["inputs"]] == p.inputs
            assert meta["provenance"]["solidkit_version"] == p.solidkit_version
            assert hashlib.sha256((camp / p.path).read_bytes()).hexdigest() == p.sha256
            # the merge recovers the synthetic scene's radiance ratios
            row = hdr[16, :, 1]
            true = RADIANCE[0, :, 0] * 0.8
            ok = row > 0
            ratio = row[ok] / true[ok]
            assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.03

    # per-file errors, collected; unrelated files listed
    errs = {e.path.rsplit("/", 1)[-1]: e.message for e in m.errors}
    assert set(errs) == {"R0010090.JPG", "R0010091.JPG", "R0010092.JPG"}
    assert "empty" in errs["R0010090.JPG"]
    assert "truncated" in errs["R0010091.JPG"]
    assert "rename it to .dng" in errs["R0010092.JPG"]
    assert {r.path for r in m.skipped} == {"notes.txt", ".hidden.JPG", "DCIM/100RICOH/R0010099.MP4"}
    assert not [p for p in camp.rglob(".*") if p.name != ".lock"]  # no temporaries left


def test_second_run_does_nothing_and_says_so(card, tmp_path):
    from solidkit.cli import app

    camp = tmp_path / "camp"
    ingest(card, camp)
    before = tree_digest(camp)
    runner = CliRunner()
    r = runner.invoke(app, ["ingest", str(card), "-o", str(camp)])
    assert "nothing to do" in r.output
    assert "skipped notes.txt: not a capture" in r.output and "R0010091.JPG: cannot decode JPEG" in r.output
    assert isinstance(r.exception, InputError) and "3 file(s)" in str(r.exception)  # the bad files, again
    assert tree_digest(camp) == before  # not a byte or an mtime changed


def test_fixed_file_is_picked_up_and_error_cleared(card, tmp_path):
    camp = tmp_path / "camp"
    ingest(card, camp)
    bad = card / "DCIM" / "100RICOH" / "R0010091.JPG"
    bad.unlink()
    write_shot(bad, T0 + timedelta(hours=5), (1, 8))
    report = ingest(card, camp)
    assert report.copied == 1 and not report.errors and report.known_errors == 2
    m = load_manifest(camp)
    assert "R0010091.JPG" not in {e.path.rsplit("/", 1)[-1] for e in m.errors}
    # bad files removed from the card: their errors are forgotten, the campaign is clean
    for name in ("R0010090.JPG", "R0010092.JPG"):
        (card / "DCIM" / "100RICOH" / name).unlink()
    (card / "notes.txt").unlink()
    report = ingest(card, camp)
    m = load_manifest(camp)
    assert not m.errors and not report.known_errors and "notes.txt" not in {r.path for r in m.skipped}
    assert len(m.shots) == 12  # nothing else changed


def test_duplicate_exposure_is_reported(tmp_path):
    card = tmp_path / "card"
    for i, dt in enumerate((0, 1, 2)):
        write_shot(
            card / "s1" / "p1" / f"R00100{i + 1:02d}.JPG", T0 + timedelta(seconds=dt), (1, 8) if i < 2 else (1, 2)
        )
    ingest(card, tmp_path / "camp")
    m = load_manifest(tmp_path / "camp")
    probe = m.scenes[0].probes[0]
    assert m.scenes[0].id == "s1" and probe.id == "p1"  # explicit folder layout
    assert len(probe.brackets) == 1 and len(probe.brackets[0].shots) == 2  # 1/8 (second one) + 1/2
    assert any("duplicate_exposure" in w and "R0010002.JPG" in w for w in probe.warnings)


def test_parallel_jobs_give_the_same_manifest(tmp_path):
    card = make_card(tmp_path / "card", bad=True)
    ingest(card, tmp_path / "a", jobs=1)
    ingest(card, tmp_path / "b", jobs=2)
    assert (tmp_path / "a" / MANIFEST_NAME).read_bytes() == (tmp_path / "b" / MANIFEST_NAME).read_bytes()


def test_the_workers_get_the_brackets_before_the_sun_frames():
    """With a pool the costliest products go first (a bracket's merge, then the larger frames), so the
    workers end together; the manifest is sorted by id whatever the order (test above)."""
    from solidkit.capture.campaign import _product_cost

    def task(kind, n, w):
        return ({"kind": kind}, [{"metadata": {"width": w, "height": w // 2}}] * n, "camp", {})

    tasks = [task("sun_frame", 1, 1920), task("hdr", 3, 1920), task("sun_frame", 1, 5792), task("hdr", 3, 5792)]
    order = sorted(tasks, key=_product_cost, reverse=True)
    assert [(t[0]["kind"], t[1][0]["metadata"]["width"]) for t in order] == [
        ("hdr", 5792),
        ("hdr", 1920),
        ("sun_frame", 5792),
        ("sun_frame", 1920),
    ]


def test_kill9_mid_run_then_resume(tmp_path):
    card = make_card(tmp_path / "card", bad=True, extra_brackets=4)
    camp = tmp_path / "camp"
    env = {**os.environ, "SOLIDKIT_INGEST_THROTTLE_S": "0.15"}
    proc = subprocess.Popen(
        [sys.executable, "-c", "from solidkit.cli import main; main()", "ingest", str(card), "-o", str(camp)],
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    originals = camp / "originals"
    while time.monotonic() < deadline:
        if originals.is_dir() and sum(1 for p in originals.rglob("*.jpg")) >= 4:
            break
        time.sleep(0.01)
    assert proc.poll() is None, "ingest finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # nothing half-written under a final name
    for p in originals.rglob("*.jpg"):
        if not p.name.startswith("."):
            assert hashlib.sha256(p.read_bytes()).hexdigest() == p.stem
    if (camp / MANIFEST_NAME).exists():
        json.loads((camp / MANIFEST_NAME).read_text())  # a complete, valid manifest or none
    n_before = len(load_manifest(camp).shots)
    assert n_before < 23
    ingest(card, camp)  # resume
    ingest(card, tmp_path / "clean")  # an uninterrupted run
    assert (camp / MANIFEST_NAME).read_bytes() == (tmp_path / "clean" / MANIFEST_NAME).read_bytes()
    assert not [p for p in camp.rglob(".*") if p.name != ".lock"]
    assert ingest(card, camp).nothing_done


def test_bad_arguments(tmp_path, card):
    with pytest.raises(InputError, match="not found"):
        ingest(tmp_path / "nope", tmp_path / "camp")
    with pytest.raises(InputError, match="inside the card"):
        ingest(card, card / "camp")
    (tmp_path / "camp2").mkdir()
    (tmp_path / "camp2" / MANIFEST_NAME).write_text('{"schema_version": 99}')
    with pytest.raises(InputError, match="schema version 99"):
        ingest(card, tmp_path / "camp2")


@pytest.mark.real
def test_real_theta_jpeg_ingests_with_metadata(real_data, tmp_path):
    card = tmp_path / "card" / "DCIM" / "100RICOH"
    card.mkdir(parents=True)
    shutil.copyfile(real_data / "theta_s_equirect" / "Jobsite1.JPG", card / "R0010001.JPG")
    ingest(tmp_path / "card", tmp_path / "camp")
    m = load_manifest(tmp_path / "camp")
    (shot,) = m.shots
    md = shot.metadata
    assert md["make"].upper().startswith("RICOH") and "THETA S" in md["model"]
    assert md["exposure_time"] == pytest.approx(1 / 500) and md["f_number"] == 2.0 and md["iso"] == 100
    assert md["image_type"] == "equirect" and (md["width"], md["height"]) == (5376, 2688)
    assert shot.kind == "probe" and m.scenes[0].id == "scene-20150101-000128"
    assert (tmp_path / "camp" / shot.original).read_bytes() == (card / "R0010001.JPG").read_bytes()


def test_dual_fisheye_products_become_panoramas():
    """A dual-fisheye capture (Theta V layout) goes through the shipped lens profile."""
    from solidkit.camera.lens import load_profile
    from solidkit.capture.products import to_panorama
    from solidkit.capture.unwarp import default_out_height, render_fisheye
    from solidkit.envmap.coords import direction_grid

    H = 64

    def scene(d):
        return np.stack([1.0 + 0.5 * d[..., 0], 1.0 - 0.5 * d[..., 1], 1.0 + 0.5 * d[..., 2]], -1).astype(np.float32)

    truth = scene(np.asarray(direction_grid(H)))  # (H, 2H, 3): directions in the panorama frame
    fish = render_fisheye(truth, load_profile("theta-v"), (4 * H, 2 * H))
    md = {"path": "x", "width": 4 * H, "height": 2 * H, "model": "RICOH THETA V", "image_type": "dual_fisheye"}
    pano, info = to_panorama(fish, md)
    # as wide as the capture, like `solidkit capture unwarp` without --size
    assert pano.shape == (2 * H, 4 * H, 3) and default_out_height(4 * H) == 2 * H
    assert info["resampled"] and info["profile"] and info["vignetting"] is False
    assert np.median(np.abs(pano - scene(np.asarray(direction_grid(2 * H))))) < 0.02
    truth = scene(np.asarray(direction_grid(H)))
    md_eq = {"path": "x", "width": 2 * H, "height": H, "image_type": "equirect"}
    same, info = to_panorama(truth, md_eq)
    assert same is truth and info == {"resampled": False}  # level stitched input: untouched
    with pytest.raises(InputError):
        to_panorama(truth, {**md_eq, "image_type": "perspective"})


def test_products_are_reproducible_from_originals(card, tmp_path):
    """A deleted (or tampered) product is rebuilt bit-identically from the originals and the recipe."""
    camp = tmp_path / "camp"
    ingest(card, camp)
    m = load_manifest(camp)
    hdr = next(p for p in m.products if p.kind == "hdr")
    (camp / hdr.path).unlink()
    other = next(p for p in m.products if p.kind == "hdr" and p.id != hdr.id)
    (camp / other.path).write_bytes(b"tampered")
    report = ingest(card, camp)
    assert report.products_built == 2 and report.products_up_to_date == len(m.products) - 2
    m2 = load_manifest(camp)
    assert m2.model_dump() == m.model_dump()
    assert hashlib.sha256((camp / hdr.path).read_bytes()).hexdigest() == hdr.sha256


@pytest.mark.real
def test_real_dng_ingests(real_data, tmp_path):
    card = tmp_path / "card" / "s1" / "p1"
    card.mkdir(parents=True)
    shutil.copyfile(real_data / "raw_dng" / "colorchart.dng", card / "R0010001.DNG")
    ingest(tmp_path / "card", tmp_path / "camp")
    (shot,) = load_manifest(tmp_path / "camp").shots
    assert shot.file_format == "dng" and shot.original.endswith(".dng") and shot.kind == "probe"
    assert (shot.metadata["width"], shot.metadata["height"]) != (0, 0)


def test_grouping_parameters_are_remembered(card, tmp_path):
    from solidkit.cli import app

    camp = tmp_path / "camp"
    runner = CliRunner()
    runner.invoke(app, ["ingest", str(card), "-o", str(camp), "--probe-gap", "3600", "--no-products"])
    m = load_manifest(camp)
    assert m.grouping.probe_gap_s == 3600 and [p.id for p in m.scenes[0].probes] == ["p01"]  # one probe now
    before = tree_digest(camp)
    r = runner.invoke(app, ["ingest", str(card), "-o", str(camp), "--no-products"])  # no option: the stored value holds
    assert "nothing to do" in r.output and tree_digest(camp) == before


@pytest.mark.slow
def test_synthetic_campaign_end_to_end(tmp_path):
    """The synthetic campaign's card ingests: kinds match the truth roles and the merged,
    unwarped, levelled HDR matches the true probe panorama once the true yaw is applied."""
    pytest.importorskip("mitsuba")
    import math

    from solidkit.cli import app
    from solidkit.envmap.coords import rotation_from_ypr
    from solidkit.envmap.resample import resize, rotate

    out = tmp_path / "syn"
    r = CliRunner().invoke(
        app,
        [
            "synth",
            "campaign",
            "--scenes",
            "1",
            "--probes",
            "1",
            "--out",
            str(out),
            "--photo-spp",
            "4",
            "--pano-height",
            "64",
            "--pano-spp",
            "4",
            "--fisheye-width",
            "256",
            "--brackets",
            "1/640,1/160,1/40",
        ],
    )
    assert r.exit_code == 0, r.output
    ingest(out / "card", tmp_path / "camp")
    m = load_manifest(tmp_path / "camp")
    truth = json.loads((out / "truth" / "truth.json").read_text())
    # the field protocol: every Theta shot of a position belongs to its one bracket
    role_to_kind = {
        "photo": "photo",
        "bracket": "bracket_member",
        "low_exposure": "bracket_member",
        "normal": "bracket_member",
    }
    by_path = {s.sources[0].path: s for s in m.shots}
    sc = truth["scenes"][0]
    shots = [sc["photo"]["shot"]] + [s for c in sc["captures"] for s in c["shots"]]
    for s in shots:
        assert by_path[s["file"].removeprefix("card/")].kind == role_to_kind[s["role"]], s
    assert [p.id for p in m.scenes[0].probes] == sorted(c["id"] for c in sc["captures"])
    cap = next(c for c in sc["captures"] if c["kind"] == "probe")
    prod = next(p for p in m.products if p.id == f"{sc['id']}/{cap['id']}/hdr-b01")
    ours, _ = read_exr(tmp_path / "camp" / prod.path)
    true, _ = read_exr(out / cap["probe"]["hdr_file"])
    R_level = np.asarray(
        rotation_from_ypr(0.0, math.radians(cap["recorded_pitch_deg"]), math.radians(cap["recorded_roll_deg"]))
    )

    def err(R):
        a, b = resize(np.asarray(rotate(ours, R, "linear")), 32).mean(-1), resize(true[..., :3], 32).mean(-1)
        ok = (a > 0) & (b > 0) & (b < np.percentile(b, 99))
        lr = np.log(a[ok] / b[ok])
        return float(np.median(np.abs(lr - np.median(lr))))

    aligned = err(np.asarray(cap["R_pano_from_body"]) @ R_level.T)
    print(
        f"synthetic probe HDR vs truth: median |log ratio| {aligned:.3f} (not levelled: "
        f"{err(np.asarray(cap['R_pano_from_body'])):.3f}, not rotated: {err(np.eye(3)):.3f})"
    )
    assert aligned < 0.1 and aligned < err(np.eye(3)) / 2


def _dual_fisheye_card(root: Path, lens, vignetting, size=(512, 256)) -> tuple[Path, np.ndarray]:
    """A Theta V card with one 2-shot bracket of dual-fisheye JPEGs (Ricoh maker note: image type 2)
    of a textured HDR scene (radiance 20..120) seen through ``lens`` with ``vignetting``'s falloff.
    Returns the card and the true radiance panorama at the products' size."""
    import cv2

    from solidkit.calibration.vignetting import vignetting_map
    from solidkit.capture.unwarp import default_out_height, encode_srgb8, render_fisheye
    from solidkit.envmap.coords import direction_grid
    from solidkit.envmap.io import tonemap
    from solidkit.envmap.resample import resize, sample_panorama
    from solidkit.synth.exif import exif_app1, insert_app1
    from tests.conftest import ASSETS

    city, _ = read_exr(ASSETS / "hdr_panoramas" / "city.exr")
    ldr = cv2.GaussianBlur(np.clip(tonemap(resize(city[..., :3], 256)), 0, 1).astype(np.float32), (0, 0), 1.5)
    radiance = 20.0 + 100.0 * ldr
    fish = render_fisheye(radiance, lens, size) * vignetting_map(vignetting, size)[..., None]
    d = root / "DCIM" / "100RICOH"
    d.mkdir(parents=True)
    for i, t in enumerate((1 / 500, 1 / 125)):
        ok, jpg = cv2.imencode(
            ".jpg", cv2.cvtColor(encode_srgb8(fish * t), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 98]
        )
        app1 = exif_app1(
            make="RICOH",
            model="RICOH THETA V",
            when=T0 + timedelta(seconds=i),
            exposure_time=t,
            f_number=2.0,
            iso=100,
            theta={"image_type": 2, "roll_deg": 0.0, "pitch_deg": 0.0},
        )
        (d / f"R00100{i + 1:02d}.JPG").write_bytes(insert_app1(jpg.tobytes(), app1))
    return root, sample_panorama(radiance, direction_grid(default_out_height(size[0])))


def _hdr_error(camp: Path, truth: np.ndarray, q: float = 50) -> tuple[float, dict]:
    """``q``-th percentile of the relative error of the campaign's HDR panorama vs the true radiance, and its stats."""
    m = load_manifest(camp)
    (prod,) = [p for p in m.products if p.kind == "hdr"]
    assert prod.error is None and prod.layout == "equirect", prod.error
    hdr, _ = read_exr(camp / prod.path)
    return float(np.percentile(np.abs(hdr[..., :3] / truth - 1), q)), prod.stats


def test_ingest_unit_profile_and_vignetting(tmp_path):
    """`ingest --profile unit.json --vignetting v.json`: both recorded in the campaign and used for the
    dual-fisheye HDR product, which then matches the true radiance; without them it does not."""
    from solidkit.calibration.vignetting import lenses_from_profile, make_profile
    from solidkit.camera.lens import load_profile
    from solidkit.cli import app

    base = load_profile("theta-v")
    # this unit: back lens centre 30 px (at 5792 wide) off the model's, rotated 0.5 deg
    ref = base.lenses[1]
    unit = base.model_copy(
        update={
            "model": "theta-v unit 123",
            "lenses": [
                base.lenses[0],
                ref.model_copy(
                    update={
                        "center": (ref.center[0] + 30.0, ref.center[1] - 20.0),
                        "ypr_deg": tuple(v + 0.5 for v in ref.ypr_deg),
                    }
                ),
            ],
        }
    )
    unit_file = unit.save(tmp_path / "unit.json")
    size = (512, 256)
    lenses = [
        l.model_copy(update={"coeffs": c})
        for l, c in zip(lenses_from_profile(unit.scaled(*size)), ([-0.3], [-0.45, 0.05]))
    ]
    vig = make_profile("flat-field", lenses, size, {})
    vig_file = vig.save(tmp_path / "vignetting.json")
    card, truth = _dual_fisheye_card(tmp_path / "card", unit, vig, size)

    runner = CliRunner()
    camp = tmp_path / "camp"
    r = runner.invoke(
        app, ["ingest", str(card), "-o", str(camp), "--profile", str(unit_file), "--vignetting", str(vig_file)]
    )
    assert r.exit_code == 0, r.output
    m = load_manifest(camp)
    assert m.lens_profile["kind"] == "file" and m.lens_profile["model"] == "theta-v unit 123"
    assert (camp / m.lens_profile["path"]).read_bytes() == unit_file.read_bytes()
    assert (camp / m.vignetting["path"]).read_bytes() == vig_file.read_bytes()
    (hdr,) = [p for p in m.products if p.kind == "hdr"]
    assert hdr.recipe["lens_profile"] == m.lens_profile and hdr.recipe["vignetting"] == m.vignetting
    assert hdr.recipe["pano_height"] == 256
    err_both, stats = _hdr_error(camp, truth)
    assert stats["profile_key"] == unit.key() and stats["vignetting"] is True
    # a second run without the options keeps the recorded profiles: nothing to do
    before = tree_digest(camp)
    r = runner.invoke(app, ["ingest", str(card), "-o", str(camp)])
    assert "nothing to do" in r.output and tree_digest(camp) == before

    ingest(card, tmp_path / "no-vig", lens_profile=unit_file)
    err_no_vig, stats_no_vig = _hdr_error(tmp_path / "no-vig", truth)
    ingest(card, tmp_path / "no-unit", vignetting_path=vig_file)
    err_no_unit, stats_no_unit = _hdr_error(tmp_path / "no-unit", truth)
    p95_both, p95_no_unit = _hdr_error(camp, truth, 95)[0], _hdr_error(tmp_path / "no-unit", truth, 95)[0]
    print(
        f"HDR product median relative error: profile+vignetting {err_both:.4f} (p95 {p95_both:.4f}, seam "
        f"{stats['seam_mad']:.4g}), no vignetting {err_no_vig:.4f} (seam {stats_no_vig['seam_mad']:.4g}), "
        f"model-default lens {err_no_unit:.4f} (p95 {p95_no_unit:.4f}, seam {stats_no_unit['seam_mad']:.4g})"
    )
    # measured: median 0.0039 / 0.203 / 0.0056; p95 0.0195 vs 0.0915 (model lens); seam 0.35 / 1.82 / 0.62
    assert err_both < 0.02 and err_no_vig > 0.1 and stats["seam_mad"] < 0.3 * stats_no_vig["seam_mad"]
    assert p95_no_unit > 3 * p95_both and stats_no_unit["seam_mad"] > 1.5 * stats["seam_mad"]
    # adding the vignetting profile later rebuilds the dual-fisheye product, identical to the first campaign's
    report = ingest(card, tmp_path / "no-vig", vignetting_path=vig_file)
    assert report.products_built == 1
    (a,) = [p for p in load_manifest(tmp_path / "no-vig").products if p.kind == "hdr"]
    assert a.sha256 == hdr.sha256
    # a shipped profile by name is recorded by name (and gives the model default's result)
    ingest(card, tmp_path / "shipped", lens_profile="theta-v", vignetting_path=vig_file)
    m = load_manifest(tmp_path / "shipped")
    assert m.lens_profile == {"kind": "shipped", "name": "theta-v", "key": base.key()}
    err_shipped, stats_shipped = _hdr_error(tmp_path / "shipped", truth)
    assert stats_shipped["profile_key"] == base.key() and err_shipped == pytest.approx(err_no_unit)
    # a lens profile given as the vignetting profile: a clear error, nothing recorded
    with pytest.raises(InputError, match="expected 'vignetting'"):
        ingest(card, tmp_path / "bad", vignetting_path=unit_file)
    assert not (tmp_path / "bad" / MANIFEST_NAME).exists()


def test_skipped_entries_say_why(tmp_path):
    """Links, special files and hidden folders are skipped with their true reason."""
    card = make_card(tmp_path / "card", bad=False)
    d = card / "DCIM" / "100RICOH"
    os.symlink(d / "R0010001.JPG", d / "R0010050.JPG")
    os.mkfifo(d / "R0010051.JPG")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.copy(d / "R0010001.JPG", elsewhere / "R0010060.JPG")
    os.symlink(elsewhere, card / "linked")
    (card / ".Trashes").mkdir()
    (card / ".Trashes" / "R0010070.JPG").write_bytes(b"x")
    camp = tmp_path / "camp"
    report = ingest(card, camp)
    why = report.skip_reasons
    assert why["DCIM/100RICOH/R0010050.JPG"].startswith("symbolic link (not followed")
    assert why["DCIM/100RICOH/R0010051.JPG"] == "not a regular file (named pipe)"
    assert why["linked"].startswith("symbolic link to a folder")
    assert why[".Trashes"] == "hidden folder (not searched)"
    assert why["notes.txt"] == "not a capture (.jpg/.jpeg/.dng)" and why[".hidden.JPG"] == "hidden file"
    assert not report.errors  # none of them is a per-file error
    skipped = {r.path: r.reason for r in load_manifest(camp).skipped}
    assert skipped == why
    assert ingest(card, camp).nothing_done


def test_products_and_manifest_are_readable_by_all(tmp_path):
    """Products and manifest.json get normal permissions (0644 under umask 022), originals stay 0444."""
    old = os.umask(0o022)
    try:
        camp = tmp_path / "camp"
        ingest(make_card(tmp_path / "card", bad=False), camp)
    finally:
        os.umask(old)
    m = load_manifest(camp)
    assert (camp / MANIFEST_NAME).stat().st_mode & 0o777 == 0o644
    built = [camp / p.path for p in m.products if p.path and p.path.startswith("products/")]
    assert built and all(p.stat().st_mode & 0o777 == 0o644 for p in built)
    assert all((camp / s.original).stat().st_mode & 0o777 == 0o444 for s in m.shots)


def _children(pid: int) -> list[int]:
    out = []
    for stat_file in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat_file.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat_file.parent.name))
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_kill9_takes_the_workers_with_it(tmp_path):
    """``ingest -j 2`` killed with -9: its worker processes end too, within seconds."""
    card = make_card(tmp_path / "card", bad=False, extra_brackets=6)
    camp = tmp_path / "camp"
    env = {**os.environ, "SOLIDKIT_INGEST_THROTTLE_S": "0.3"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from solidkit.cli import main; main()",
            "ingest",
            "-j",
            "2",
            str(card),
            "-o",
            str(camp),
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (
        (camp / "originals").is_dir() and any((camp / "originals").rglob("*.jpg"))
    ):
        time.sleep(0.02)
    workers = _children(proc.pid)
    assert proc.poll() is None and len(workers) >= 2, "ingest finished (or had no workers) before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 5.0
    alive = workers
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [
            w
            for w in alive
            if Path(f"/proc/{w}").exists()
            and "Z" not in Path(f"/proc/{w}/stat").read_text().rsplit(")", 1)[1].split()[0]
        ]
    assert not alive, f"workers {alive} outlived the killed ingest"


def test_disk_full_is_retried_not_remembered(tmp_path, monkeypatch, cli):
    """ENOSPC while copying or while building products: reported per file/product (exit 2, naming the
    final file), not remembered: the next run, with space again, completes the campaign."""
    import errno

    import solidkit.capture.bracket_merge as merge_mod
    import solidkit.capture.card as card_mod
    import solidkit.capture.products as products_mod
    import solidkit.capture.unwarp as unwarp_mod

    exr_users = (products_mod, merge_mod, unwarp_mod)  # the modules that write product EXRs
    card = make_card(tmp_path / "card", bad=False)
    camp = tmp_path / "camp"
    real_copy, real_exr = card_mod.copy_original, products_mod.write_exr
    calls = [0]

    def full_copy(src, dest, sha):
        calls[0] += 1
        if calls[0] % 2 == 0:
            raise OSError(errno.ENOSPC, "No space left on device", str(dest.parent / f".{dest.name}.tmp123"))
        return real_copy(src, dest, sha)

    def full_exr(path, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(Path(path).parent / ".hidden.exr.tmp"))

    monkeypatch.setattr(card_mod, "copy_original", full_copy)
    code, out, err = cli("ingest", card, "-o", camp)
    assert code == 2, err
    flat = " ".join(out.split())
    assert "could not be copied" in flat and "No space left on device" in flat and ".tmp123" not in flat
    assert "not tried: the disk is full" in flat  # once the disk is full, the other files are not read in vain
    assert not load_manifest(camp).errors  # nothing remembered as a bad file
    monkeypatch.setattr(card_mod, "copy_original", real_copy)
    for mod in exr_users:
        monkeypatch.setattr(mod, "write_exr", full_exr)
    code, out, err = cli("ingest", card, "-o", camp)
    assert code == 2, err
    flat = " ".join(out.split())
    assert "hdr-b01.exr: could not be built: No space left on device" in flat and ".hidden.exr" not in flat
    assert "not built: the disk is full" in flat  # the products after it are not tried
    m = load_manifest(camp)
    assert not m.errors and all(p.error_transient for p in m.products if p.error)
    for mod in exr_users:
        monkeypatch.setattr(mod, "write_exr", real_exr)
    report = ingest(card, camp)  # space freed
    assert not report.errors and not report.transient_errors and report.known_errors == 0
    m = load_manifest(camp)
    assert len(m.shots) == 11 and all(p.error is None and p.path for p in m.products)
    ingest(card, tmp_path / "clean")
    assert (camp / MANIFEST_NAME).read_bytes() == (tmp_path / "clean" / MANIFEST_NAME).read_bytes()


@pytest.mark.slow
def test_products_are_the_same_bytes_whatever_the_thread_count(tmp_path):
    """The BLAS libraries split reductions by thread (OpenCV's Debevec solve among them): every file
    of the shipped mini card's campaign ingested with 1 thread and with 2 threads is byte-identical
    (about 2 x 1 min)."""
    card = REPO / "solidkit" / "assets" / "campaign_mini" / "card"
    digests = []
    for n in (1, 2):
        camp = tmp_path / f"camp{n}"
        env = dict(os.environ, OMP_NUM_THREADS=str(n), OPENBLAS_NUM_THREADS=str(n))
        subprocess.run(
            [sys.executable, "-m", "solidkit.cli", "--threads", str(n), "ingest", str(card), "-o", str(camp)],
            check=True,
            env=env,
            capture_output=True,
            timeout=1200,
        )
        files = sorted(p for p in camp.rglob("*") if p.is_file())
        digests.append({p.relative_to(camp).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in files})
    assert sum(k.endswith(".exr") for k in digests[0]) >= 7, "the card makes HDR products"
    differ = sorted(k for k in digests[0] if digests[0][k] != digests[1].get(k))
    assert digests[0].keys() == digests[1].keys() and not differ, differ
