"""solidkit testset build / validate on an analytic campaign with a known truth (tests/support/testset_campaign.py)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from solidkit.align.schema import body_to_pano, level_to_pano
from solidkit.envmap.io import read_exr, read_ldr
from solidkit.envmap.resample import resize, rotate
from solidkit.errors import InputError
from solidkit.labeling.store import LabelStore
from solidkit.metrics import exposure_scale, ldr_from_hdr
from solidkit.testset.build import build_testset, load_testset
from solidkit.testset.schema import content_version
from solidkit.testset.validate import validate_testset
from tests.support.testset_campaign import make_campaign

PSNR_MIN_DB = 30.0


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("campaign") / "camp"
    return root, make_campaign(root)


@pytest.fixture(scope="module")
def built(campaign, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ts") / "testset"
    build_testset(campaign[0], out)
    return out


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def psnr_ldr(ldr: np.ndarray, truth_hdr: np.ndarray, saturated: np.ndarray) -> float:
    """PSNR (dB, sRGB [0, 1]) of an LDR probe against the truth HDR exposed like it, unsaturated pixels."""
    s = exposure_scale(truth_hdr, ldr, saturated)
    ref = ldr_from_hdr(truth_hdr, s)
    mse = float(np.mean((ldr[~saturated] - ref[~saturated]) ** 2))
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def test_build_against_truth(campaign, built):
    camp, truth = campaign
    ts = load_testset(built)
    assert [s.id for s in ts.scenes] == sorted(truth)
    for s in ts.scenes:
        t = truth[s.id]
        assert (s.pitch_deg, s.roll_deg) == (t["pitch"], t["roll"])
        assert s.photo_size == (320, 240) and s.photo_full_size == (640, 480)
        for p in s.probes:
            # probe pixels exactly the field notes'; 640 -> 320 is a plain /2 resize (conventions §1)
            assert p.pixel_full == t["pixels"][p.id] and p.pixel_source == "field_notes"
            x, y = t["pixels"][p.id]
            assert p.pixel == pytest.approx(((x + 0.5) / 2 - 0.5, (y + 0.5) / 2 - 0.5), abs=1e-9)
            # rotation: body -> photo panorama of the capture's yaw and levelling
            np.testing.assert_allclose(
                np.asarray(p.rotation)[:, 2], body_to_pano(t["yaws"][p.id], 0, 0)[:, 2], atol=0.05
            )
            # the aligned probe equals the environment (distant world): LDR and HDR
            truth_small = resize(t["panorama"], 128)
            ldr = read_ldr(built / p.ldr)
            sat = read_ldr(built / p.images.saturation)[..., 0] > 0.5
            assert psnr_ldr(ldr, truth_small, sat) > PSNR_MIN_DB
            hdr = read_exr(built / p.hdr)[0]
            rel = np.median(np.abs(hdr - truth_small) / np.maximum(truth_small, 1e-3))
            assert rel < 0.05
        if t["sun"] is None:
            assert not s.sun.found and s.sun.azimuth_deg is None
        else:
            assert s.sun.found and (s.sun.azimuth_deg, s.sun.elevation_deg) == pytest.approx(t["sun"], abs=1e-9)
            assert s.sun.source == "auto"
            # the sun panorama is in the photo's panorama frame: its brightest spot is the sun
            pano = read_ldr(built / s.sun.panorama)
            h = pano.shape[0]
            v, u = np.unravel_index(np.argmax(pano.sum(-1)), pano.shape[:2])
            az, el = (u + 0.5) / (2 * h) * 360 - 180, 90 - (v + 0.5) / h * 180
            assert abs(az - t["sun"][0]) < 2.0 and abs(el - t["sun"][1]) < 2.0
    lens = [r for r in ts.profiles if r.role == "lens"]
    assert [(r.kind, r.name) for r in lens] == [("shipped", "theta-v")]
    assert lens[0].path == f"profiles/{lens[0].sha256}.json" and ts.files[lens[0].path].sha256 == lens[0].sha256
    assert validate_testset(built) == []


def test_two_builds_byte_identical_and_rebuild_is_a_no_op(campaign, built, tmp_path):
    other = tmp_path / "again"
    report = build_testset(campaign[0], other)
    assert _tree(other) == _tree(built)
    before = {p: p.stat().st_mtime_ns for p in built.rglob("*")}
    report = build_testset(campaign[0], built)
    assert not report.changed and {p: p.stat().st_mtime_ns for p in built.rglob("*")} == before
    assert load_testset(built).dataset_version == content_version(load_testset(built))


def test_refuses_unrelated_and_overlapping_folders(campaign, tmp_path):
    camp = campaign[0]
    unrelated = tmp_path / "photos"
    unrelated.mkdir()
    (unrelated / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(InputError, match="not a solidkit test set"):
        build_testset(camp, unrelated)
    assert (unrelated / "holiday.jpg").read_bytes() == b"x"
    with pytest.raises(InputError, match="outside the campaign"):
        build_testset(camp, camp / "testset")
    with pytest.raises(InputError, match="not a campaign"):
        build_testset(tmp_path, tmp_path / "out")


def test_human_labels_win_with_provenance(campaign, tmp_path):
    camp = tmp_path / "camp"
    shutil.copytree(campaign[0], camp)
    truth = campaign[1]
    store = LabelStore(camp)
    store.put("probe_pixel", "sA/p01", {"x": 210.0, "y": 430.0}, source="annotator", annotator="ann")
    store.put("probe_pixel", "sA/p02", {"x": 1.0, "y": 1.0}, source="auto", annotator="align")  # loses to field notes
    store.put(
        "sun_scene",
        "sA",
        {"found": True, "azimuth_deg": 36.0, "elevation_deg": 41.0, "uncertainty_deg": 0.3},
        source="reviewed",
        annotator="rev",
    )
    yaw = truth["sA"]["yaws"]["p02"] + 10.0
    store.put("heading", "sA/p02", {"yaw_deg": yaw}, source="annotator", annotator="ann", flags=["check"])
    out = tmp_path / "ts"
    report = build_testset(camp, out)
    ts = load_testset(out)
    s = ts.scenes[0]
    p1, p2 = s.probes
    assert (p1.pixel_full, p1.pixel_source, p1.pixel_annotator) == ((210.0, 430.0), "annotator", "ann")
    assert (p2.pixel_full, p2.pixel_source) == (truth["sA"]["pixels"]["p02"], "field_notes")
    assert (s.sun.azimuth_deg, s.sun.elevation_deg, s.sun.source, s.sun.annotator) == (36.0, 41.0, "reviewed", "rev")
    assert s.sun.label_version == 1
    assert p2.alignment.source == "annotator" and p2.alignment.yaw_deg == pytest.approx(yaw)
    assert "check" in p2.flags and report.overrides
    np.testing.assert_allclose(p2.rotation, body_to_pano(yaw, -1.5 + 3.0, -1.4), atol=1e-9)  # levelling of capture #2
    # the probe was re-rotated by the 10 degree correction: it now shows the world turned by 10 degrees
    turned = resize(rotate(truth["sA"]["panorama"], level_to_pano(10.0)), 128)
    sat = read_ldr(out / p2.images.saturation)[..., 0] > 0.5
    assert psnr_ldr(read_ldr(out / p2.ldr), turned, sat) > PSNR_MIN_DB
    assert ts.inputs.labels_used >= 4 and ts.inputs.labels_sha256
    problems = validate_testset(out)
    assert [p.check for p in problems] == ["flags"] and "check" in problems[0].message
    assert validate_testset(out, allow_flagged=True) == []
    build_testset(camp, tmp_path / "again")  # re-rotated products are deterministic too
    assert _tree(tmp_path / "again") == _tree(out)
    # the changelog between the automatic and the reviewed version
    from solidkit.testset.diff import diff_testsets

    base = tmp_path / "base"
    build_testset(campaign[0], base)
    d = diff_testsets(base, out)
    changes = {(c["what"], c["where"]): c for c in d.changes}
    assert changes[("pixel", "sA/p01")]["distance_px"] == pytest.approx(math.hypot(10, 10))
    assert changes[("rotation", "sA/p02")]["angle_deg"] == pytest.approx(10.0, abs=1e-6)
    assert ("pixel", "sA/p02") not in changes and not d.scenes_added and not d.probes_removed
    assert "scenes/sA/probes/p02/ldr.png" in d.files_changed and "scenes/sB/photo.png" not in d.files_changed
    assert diff_testsets(out, tmp_path / "again").same


def _edit(root: Path, edit) -> None:
    p = root / "testset.json"
    data = json.loads(p.read_text())
    edit(data)
    p.write_text(json.dumps(data))


def _sky_pixel(data):
    p = data["scenes"][0]["probes"][0]
    p["pixel_full"] = [320.0, 30.0]
    p["pixel"] = [159.75, 14.75]


def _below_horizon(data):
    data["scenes"][0]["sun"].update(elevation_deg=-5.0, direction=None)


def _skew(data):
    data["scenes"][0]["probes"][1]["rotation"][0][1] += 0.05


def _outside_entry(data):
    entry = next(iter(data["files"].values()))
    data["files"]["scenes/sA/../../outside.txt"] = dict(entry)


def _twice(data):
    data["scenes"][0]["probes"].append(json.loads(json.dumps(data["scenes"][0]["probes"][0])))


def _link(root: Path) -> None:
    (root / "scenes/sA/photo.png").unlink()
    (root / "scenes/sA/photo.png").symlink_to("/etc/hostname")


FAULTS = {
    "a path leaving the set": (lambda r: _edit(r, _outside_entry), "files", "scenes/sA/../../outside.txt", "'..'"),
    "a link to a system file": (_link, "files", "scenes/sA/photo.png", "a link"),
    "a probe listed twice": (lambda r: _edit(r, _twice), "schema", "testset.json", "listed 2 times"),
    "missing file": (
        lambda r: (r / "scenes/sA/probes/p01/hdr.exr").unlink(),
        "files",
        "scenes/sA/probes/p01/hdr.exr",
        "missing",
    ),
    "flipped checksum": (lambda r: _flip(r / "scenes/sA/photo.png"), "files", "scenes/sA/photo.png", "checksum"),
    "probe on the sky": (lambda r: _edit(r, _sky_pixel), "geometry", "scenes/sA/photo_full.jpg", "on the sky"),
    "sun below the horizon": (lambda r: _edit(r, _below_horizon), "geometry", "testset.json", "not above the horizon"),
    "non-orthonormal rotation": (lambda r: _edit(r, _skew), "geometry", "testset.json", "not orthonormal"),
}


def _flip(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_validate_catches_each_fault(fault, built, tmp_path, cli):
    root = tmp_path / "ts"
    shutil.copytree(built, root)
    inject, check, file, words = FAULTS[fault]
    inject(root)
    problems = validate_testset(root)
    hits = [p for p in problems if p.check == check and p.file == file and words in p.message]
    assert hits and hits[0].scene == "sA", problems
    code, out, _ = cli("testset", "validate", root, "--json")
    assert code == 1 and not json.loads(out)["valid"]


@pytest.mark.parametrize(
    ("name", "text", "words"),
    [
        ("an absolute path", None, "not a relative path"),
        ("NaN in a float field", "NaN", "not a JSON number"),
        ("nesting 100,000 deep", "[" * 100_000 + "]" * 100_000, "nested too deep"),
    ],
)
def test_validate_reports_manifests_that_cannot_be_trusted(name, text, words, built, tmp_path, cli):
    """Each is a problem line (exit 1), never an internal error, and nothing outside the set is opened."""
    root = tmp_path / "ts"
    shutil.copytree(built, root)
    manifest = root / "testset.json"
    if text is None:
        _edit(root, lambda d: d["files"].update({"/etc/hostname": dict(next(iter(d["files"].values())))}))
    elif text == "NaN":
        manifest.write_text(manifest.read_text().replace('"uncertainty_deg": ', '"uncertainty_deg": NaN, "x": ', 1))
    else:
        manifest.write_text(text)
    problems = validate_testset(root)
    assert any(words in p.message for p in problems), problems
    code, out, err = cli("testset", "validate", root, "--json")
    assert code == 1 and not json.loads(out)["valid"], err


def test_validate_clean_cli_and_bad_input(built, tmp_path, cli):
    assert cli("testset", "validate", built)[0] == 0
    code, _, err = cli("testset", "validate", tmp_path)
    assert code == 2 and "not a test set" in err
    (tmp_path / "testset.json").write_text("{")
    assert "[schema]" in cli("testset", "validate", tmp_path)[2]


def test_show_writes_sheets_with_outline_and_sun(built, tmp_path, cli):
    import cv2

    from solidkit.testset.show import fov_outline

    code, out, _ = cli("testset", "show", built, "-o", tmp_path / "sheets")
    assert code == 0 and Path(out.strip()).name == "index.html"
    html = (tmp_path / "sheets" / "index.html").read_text()
    ts = load_testset(built)
    for s in ts.scenes:
        sheet = cv2.imread(str(tmp_path / "sheets" / f"{s.id}.png"))
        assert sheet is not None and sheet.shape[1] > 1000 and f"{s.id}.png" in html
    assert validate_testset(built) == []  # nothing written into the test set
    # the outline of a level camera with a 60 degree FOV spans +-30 degrees of azimuth about the centre
    s = ts.scenes[0]
    lines = fov_outline(np.asarray(s.K), (320, 240), 0.0, 0.0, 128)
    u = np.concatenate([ln[:, 0] for ln in lines])
    assert (u.min() + 0.5) == pytest.approx(128 - 128 * 30 / 180, abs=0.5) and (u.max() + 0.5) == pytest.approx(
        128 + 128 * 30 / 180, abs=0.5
    )
    code, _, err = cli("testset", "show", built, "-o", built / "sheets")
    assert code == 2 and "outside the test set" in err
    code, out, _ = cli("testset", "show", built, "-o", tmp_path / "sheets", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["output"] == str(tmp_path / "sheets") and Path(doc["index"]).name == "index.html"
    assert sorted(Path(p).name for p in doc["sheets"]) == sorted(f"{s.id}.png" for s in ts.scenes)


def test_sold_net_export_round_trips(built, tmp_path, cli):
    from solidkit.testset.sold_net import read_sold_net

    dest = tmp_path / "sold"
    code, _, err = cli("testset", "export", built, "--format", "sold-net", "-o", dest)
    assert code == 0 and "fewer than 2 probes: 002" in err
    items = read_sold_net(dest)
    ts = load_testset(built)
    assert [it.id for it in items] == ["001", "002"] and [it.loadable for it in items] == [True, False]
    for it, s in zip(items, ts.scenes):
        photo = read_ldr(built / s.photo)
        assert it.persp.shape == (240, 320, 3)
        assert 10 * math.log10(1 / np.mean((it.persp - photo) ** 2)) > 35  # JPEG q95
        assert it.local_pos.tolist() == [[round(p.pixel[1]), round(p.pixel[0])] for p in s.probes]
        for k, p in enumerate(s.probes):
            ref = resize(read_exr(built / p.hdr)[0], 64)
            rel = np.abs(it.local_pano[k] - ref) / np.maximum(ref, 1e-4)
            assert it.local_pano[k].shape == (64, 128, 3) and np.median(rel) < 0.01  # RGBE: 8-bit mantissa
        if s.sun.found:
            assert it.is_sunny and it.sun_deg == pytest.approx((s.sun.azimuth_deg, s.sun.elevation_deg), abs=1e-4)
            col, row = np.loadtxt(dest / f"{it.id}_sun_pos.txt")  # SOLD-Net's estimator_test_real.py, literally
            assert ((col - 63.5) / 64 * 180, (31.5 - row) / 64 * 180) == pytest.approx(
                (s.sun.azimuth_deg, s.sun.elevation_deg), abs=1e-4
            )
        else:
            assert not it.is_sunny and it.sun_deg is None
    code, out, _ = cli(
        "testset", "export", built, "--format", "sold-net", "-o", dest, "--json"
    )  # re-export over an earlier one
    doc = json.loads(out)
    assert code == 0 and doc["output"] == str(dest) and sorted(doc["items"]) == ["001", "002"]
    assert doc["skipped_by_sold_net_loader"] == ["002"] and doc["testset"] == ts.dataset_version
    assert cli("testset", "export", built, "--format", "laval", "-o", tmp_path / "x")[0] == 2
    assert cli("testset", "export", built, "--format", "sold-net", "-o", built / "scenes")[0] == 2
    code, _, err = cli("testset", "export", built, "--format", "sold-net", "-o", built / "sold")  # new, but inside
    assert code == 2 and "outside the test set" in err and not (built / "sold").exists()
    code, _, err = cli("testset", "export", built, "--format", "sold-net")
    assert code == 2 and "Missing option '-o' / '--out'" in err


def test_torch_dataset_keys_match_synth(built):
    import torch

    from solidkit.testset.dataset import TestsetDataset

    ds = TestsetDataset(built)
    ts = load_testset(built)
    assert len(ds) == len(ts.scenes) and ds.max_probes == 2
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=2)))
    assert batch["image"].shape == (2, 3, 240, 320) and batch["probes"].shape == (2, 2, 3, 128, 256)
    assert batch["probe_valid"].tolist() == [[1.0, 1.0], [1.0, 0.0]]
    s = ts.scenes[0]
    assert batch["probe_pixels"][0].tolist() == [list(p.pixel) for p in s.probes]
    np.testing.assert_allclose(batch["sun"][0].numpy(), s.sun.direction, atol=1e-6)
    assert batch["sun_found"].tolist() == [1.0, 0.0] and batch["sun"][1].abs().sum() == 0
    assert batch["sun_uncertainty_deg"][0].item() == pytest.approx(s.sun.uncertainty_deg or float("nan"), nan_ok=True)
    assert batch["pitch"][0].item() == pytest.approx(math.radians(s.pitch_deg))
    shared = {
        "image",
        "probes",
        "probe_pixels",
        "probe_valid",
        "global",
        "sun",
        "sun_found",
        "K",
        "pitch",
        "roll",
        "index",
    }
    assert shared <= set(batch)
    only = TestsetDataset(built, fields=["image"], scenes=["sB"])
    assert len(only) == 1 and "probes" not in only[0] and only[0]["scene"] == "sB"
    with pytest.raises(InputError):
        TestsetDataset(built, scenes=["nope"])


@pytest.mark.real
@pytest.mark.parametrize("name", ["city", "courtyard", "sunrise"])
def test_sky_mask_on_real_outdoor_views(real_data, name):
    """Pinhole views of real outdoor HDR panoramas (Poly Haven): sky found above the skyline, none on the ground."""
    from solidkit.envmap.coords import rotation_from_ypr
    from solidkit.envmap.io import srgb_encode
    from solidkit.envmap.perspective import intrinsics_from_fov, perspective_crop
    from solidkit.testset.sky import on_sky, sky_mask

    pano = read_exr(real_data / "hdr_panoramas" / f"{name}.exr")[0][..., :3]
    K = intrinsics_from_fov(math.radians(60), 640, 480)
    for yaw in (0, 120, 240):
        view = perspective_crop(
            pano, np.asarray(rotation_from_ypr(math.radians(yaw), math.radians(5), 0)), (640, 480), K=K
        )
        ldr = np.round(srgb_encode(np.clip(view * 0.8 / np.percentile(view, 90), 0, 1)) * 255).astype(np.uint8)
        mask = sky_mask(ldr, K, 5.0, 0.0)
        assert not mask[300:].any()  # rows below the horizon of a camera pitched up by 5 degrees (horizon ~ row 288)
        assert not on_sky(mask, 320, 420)
        if (name, yaw) != ("courtyard", 120) and (name, yaw) != ("courtyard", 240):  # views under a roof
            assert mask[:100].mean() > 0.15, (name, yaw)


def test_concurrent_build_refused_and_killed_build_leaves_old_set(campaign, built, tmp_path):
    import fcntl

    out = tmp_path / "ts"
    shutil.copytree(built, out)
    (tmp_path / ".ts.build-x").mkdir()  # what a killed build leaves beside OUT
    with open(tmp_path / ".ts.lock", "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(InputError, match="another testset build"):
            build_testset(campaign[0], out)
    assert _tree(out) == _tree(built)
    build_testset(campaign[0], out)
    assert not (tmp_path / ".ts.build-x").exists() and _tree(out) == _tree(built)


def test_each_products_exposure_is_recorded(campaign, built):
    """The LDR probe's shot (the protocol's 1/2500 s or the substitute nearest to it) and the sun frame's exposure
    are in the test set for every capture, so that the protocol can be checked."""
    from solidkit.align.captures import normal_shot_of
    from solidkit.capture.manifest import load_manifest

    manifest = load_manifest(campaign[0])
    ts = load_testset(built)
    for s in ts.scenes:
        mscene = next(sc for sc in manifest.scenes if sc.id == s.id)
        caps = [(p.id, p.capture) for p in s.probes] + ([(s.camera.id, s.camera.capture)] if s.camera else [])
        for pid, cap in caps:
            shot = normal_shot_of(manifest, next(p for p in mscene.probes if p.id == pid))
            assert shot is not None and cap.ldr_exposure is not None
            assert cap.ldr_exposure.exposure_time_s == shot.metadata["exposure_time"]
            assert cap.ldr_exposure.f_number == shot.metadata["f_number"]
            assert cap.sun_frame_exposure is not None and cap.sun_frame_exposure.exposure_time_s is not None
