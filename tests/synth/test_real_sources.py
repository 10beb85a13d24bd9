"""Real HDR panoramas as crop sources: Radiance files, a catalogue's sun, the split by whole panorama, weights."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.envmap.coords import angles_from_direction, coords_from_direction, direction_from_angles
from solidkit.envmap.io import read_hdr, read_image, read_panorama
from solidkit.errors import InputError, PanoramaError
from solidkit.model.suncrops import SunCropBank
from solidkit.synth.panocrops import SPLIT_FILE, CropConfig, CropSampler, load_sources, read_catalog, real_split

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "hdr_outdoor"


def _sky_with_sun(h: int, az_deg: float, el_deg: float, peak: float = 5.0e4) -> np.ndarray:
    pano = np.full((h, 2 * h, 3), 0.2, np.float32)
    pano[h // 2 :] = 0.05
    x, y = coords_from_direction(direction_from_angles(math.radians(az_deg), math.radians(el_deg)), h)
    c, r = int(x), int(y)
    pano[r - 1 : r + 2, c - 1 : c + 2] = peak
    return pano


def _write_hdr(path: Path, pano: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), np.ascontiguousarray(pano[..., ::-1]))
    return path


def test_a_radiance_file_reads_back_as_linear_rgb_within_rgbe_precision(tmp_path):
    pano = _sky_with_sun(32, 40.0, 20.0)
    pano[..., 0] *= 2.0  # red twice green: channel order must survive
    img = read_hdr(_write_hdr(tmp_path / "sky.hdr", pano))
    assert img.shape == (32, 64, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img, pano, rtol=1 / 128)
    np.testing.assert_allclose(read_image(tmp_path / "sky.hdr")[0], img)
    np.testing.assert_allclose(read_panorama(tmp_path / "sky.hdr"), img)


def test_a_file_that_is_not_radiance_is_a_one_line_error(tmp_path):
    bad = tmp_path / "bad.hdr"
    bad.write_bytes(b"P6 not a radiance file")
    with pytest.raises(InputError, match="not a Radiance HDR"):
        read_hdr(bad)
    cv2.imwrite(str(tmp_path / "wide.hdr"), np.ones((8, 8, 3), np.float32))
    with pytest.raises(PanoramaError, match="equirectangular"):
        read_panorama(tmp_path / "wide.hdr")


def _folder(tmp_path: Path) -> Path:
    root = tmp_path / "real"
    root.mkdir()
    _write_hdr(root / "sunny.hdr", _sky_with_sun(128, 36.0, 25.0))
    _write_hdr(root / "grey.hdr", np.full((128, 256, 3), 0.3, np.float32))
    (root / "catalog.json").write_text(
        json.dumps(
            [
                {"file": "sunny.hdr", "sun_visible": True, "sun_azimuth_deg": 36.0, "sun_elevation_deg": 25.0},
                {"file": "grey.hdr", "sun_visible": False},
            ]
        )
    )
    return root


def test_the_catalogue_sun_is_the_crop_target_turned_with_the_crop(tmp_path):
    srcs = load_sources(_folder(tmp_path))
    by = {s.name: s for s in srcs}
    assert by["sunny"].sun.visible and not by["grey"].sun.visible
    az, el = angles_from_direction(by["sunny"].sun.direction)
    assert math.degrees(az) == pytest.approx(36.0) and math.degrees(el) == pytest.approx(25.0)
    sampler = CropSampler([by["sunny"]], seed=3, config=CropConfig(exposure_key=0.18))
    bank = SunCropBank(height=128)
    bank.add("sunny", by["sunny"])
    for i in range(6):
        it = sampler(i)
        # the target sky carries the sun where the catalogue's direction, turned by the crop, says
        x, y = coords_from_direction(it["sun_dir"], 128)
        peak = np.unravel_index(np.argmax(it["sky"].sum(-1)), it["sky"].shape[:2])
        assert abs(peak[0] - y) <= 1.5 and min(abs(peak[1] - x), 256 - abs(peak[1] - x)) <= 1.5
        crop = bank.crop(np.random.default_rng(i), CropConfig(exposure_key=0.18))
        assert crop["sun_visible"] == 1.0 and np.linalg.norm(crop["sun_dir"]) == pytest.approx(1.0, abs=1e-5)
    grey = SunCropBank(height=128)
    grey.add("grey", by["grey"])
    assert not grey.sun("grey").visible


def test_the_shipped_split_covers_the_shared_catalogue_once_and_splits_keep_panoramas_apart():
    table = real_split()
    data = json.loads(SPLIT_FILE.read_text())
    names = data["train"] + data["val"] + data["test"]
    assert len(names) == len(set(names)) == len(table)
    if (REAL / "catalog.json").is_file():
        assert set(read_catalog(REAL)) == set(table)


def test_a_panorama_the_split_file_does_not_list_trains_only(tmp_path, monkeypatch):
    import solidkit.synth.panocrops as pc

    root = _folder(tmp_path)
    monkeypatch.setattr(pc, "real_split", lambda: {"sunny": "test"})
    assert [s.name for s in load_sources(root, split="test")] == ["sunny"]
    assert [s.name for s in load_sources(root, split="train")] == ["grey"]
    with pytest.raises(InputError, match="'val' split"):
        load_sources(root, split="val")
    monkeypatch.setattr(pc, "real_split", lambda: {"elsewhere": "test"})  # a folder the split does not cover
    assert len(load_sources(root, split="val")) == 2


@pytest.mark.real
def test_real_outdoor_splits_are_disjoint_and_every_split_has_suns_and_negatives():
    if not REAL.is_dir():
        pytest.skip("no ../shared/data/real/hdr_outdoor")
    seen: dict[str, set[str]] = {}
    for split in ("train", "val", "test"):
        srcs = load_sources(REAL, split=split)
        seen[split] = {s.name for s in srcs}
        assert any(s.sun.visible for s in srcs) and any(not s.sun.visible for s in srcs)
    assert not (seen["train"] & seen["val"]) and not (seen["train"] & seen["test"]) and not (seen["val"] & seen["test"])


def test_an_unknown_split_and_a_bad_catalogue_are_one_line_errors(tmp_path):
    root = _folder(tmp_path)
    with pytest.raises(InputError, match="unknown split"):
        load_sources(root, split="holdout")
    (root / "catalog.json").write_text('[{"file": "sunny.hdr"}]')
    with pytest.raises(InputError, match="not a panorama catalogue"):
        load_sources(root)


def test_bank_weights_set_the_share_of_crops_per_source(tmp_path):
    srcs = load_sources(_folder(tmp_path))
    bank = SunCropBank(height=128)
    bank.sync([s.name for s in srcs], srcs)
    bank.weights = np.array([0.9, 0.1]) if bank.names[0] == "sunny" else np.array([0.1, 0.9])
    picks = [bank.crop(np.random.default_rng(i), CropConfig())["source"] for i in range(200)]
    assert 0.8 < picks.count("sunny") / 200 < 0.97


def test_eval_sun_crops_reports_the_model_beside_its_baselines(tmp_path, cli):
    from solidkit.model.config import preset
    from solidkit.model.solidnet import SolidNet

    root = _folder(tmp_path)
    import torch

    torch.manual_seed(0)
    SolidNet(preset("small-sun")).save(tmp_path / "m.pt", {"what": "untrained (test)"})
    code, out, err = cli("eval", "--model", tmp_path / "m.pt", "--sun-crops", root, "-o", tmp_path / "rep", "--json")
    assert code == 0, err
    res = json.loads((tmp_path / "rep" / "results.json").read_text())["sun_crops"]
    figs = res[f"{root.name} (test)"]["figures"]
    assert set(figs) >= {"model", "constant", "brightest column"}
    assert figs["constant"]["suns"] == 6 and figs["constant"]["sunless"] == 6 and figs["constant"]["false_suns"] == 6
    assert "brightest column" in (tmp_path / "rep" / "report.md").read_text()
    code, _, err = cli("eval", "--sun-crops", tmp_path / "nope", "-o", tmp_path / "rep2")
    assert code == 2 and "not a folder" in err


@pytest.mark.real
def test_the_shipped_checkpoint_puts_real_in_view_suns_on_the_sun_and_beats_its_baselines():
    if not REAL.is_dir():
        pytest.skip("no ../shared/data/real/hdr_outdoor")
    from solidkit.model import suneval
    from solidkit.model.solidnet import SolidNet

    srcs = [s for s in load_sources(REAL, split="test") if s.sun.visible]
    crops = suneval.protocol_crops(srcs)
    model = SolidNet.from_checkpoint()
    pred = suneval.predict_model(model, crops)
    f = suneval.sun_figures(crops, pred)
    base = suneval.sun_figures(crops, suneval.predict_brightest_column(crops))
    assert f["in_view_n"] >= 4 and f["in_view_max_deg"] < 8.0  # found in-view suns sit on the sun
    assert f["angular_deg"] < 0.5 * base["angular_deg"]
    assert f["found_rate"] >= 0.75


def test_real_maps_light_rendered_scenes_with_their_catalogued_sun(tmp_path, monkeypatch):
    import solidkit.synth.panocrops as pc
    from solidkit.synth.panocrops import SourceConfig, lighting_files, source_setup

    root = _folder(tmp_path)
    cfg = SourceConfig(p_sunsky=0.0, exclude_hdr=("city",), real_lighting=(str(root),))
    files, suns = lighting_files(cfg)
    assert {"sunny", "grey"} <= {f.stem for f in files} and set(suns) == {"sunny", "grey"}
    monkeypatch.setattr(pc, "real_split", lambda: {"sunny": "test"})  # the same rule as load_sources'
    test_cfg = SourceConfig(exclude_hdr=("city",), real_lighting=(str(root),), real_lighting_split="test")
    files, _ = lighting_files(test_cfg)
    assert "sunny" in {f.stem for f in files} and "grey" not in {f.stem for f in files}
    with pytest.raises(InputError, match="'val' split"):  # a panorama the split file does not list only trains
        lighting_files(SourceConfig(real_lighting=(str(root),), real_lighting_split="val"))
    monkeypatch.undo()
    with pytest.raises(InputError, match="unknown split"):
        lighting_files(SourceConfig(real_lighting=(str(root),), real_lighting_split="dev"))
    seen = set()
    for i in range(40):
        _, _, light = source_setup(5, i, cfg)
        name = Path(light.meta["file"]).stem
        assert name != "city"
        if name == "grey":  # the catalogue says no sun, whatever the map's brightest spot
            assert light.sun is None and light.meta["sun_from"] == "catalogue"
        elif name == "sunny":
            want = light.rotation @ suns["sunny"].direction
            assert float(np.dot(light.sun, want)) == pytest.approx(1.0, abs=1e-6)
        seen.add(name)
        if {"grey", "sunny"} <= seen:
            break
    assert {"grey", "sunny"} <= seen
    assert "real_lighting" in cfg.to_json() and "real_lighting" not in SourceConfig().to_json()


def test_a_rendered_source_lit_by_a_catalogued_map_keeps_its_sun_for_the_sun_stage(tmp_path):
    root = tmp_path / "sources"
    for name, sun in (("000000", None), ("000001", [0.0, -0.6, 0.8]), ("000002", [0.6, -0.8, 0.0])):
        (root / name).mkdir(parents=True)
        lighting = {"kind": "hdr", "file": "x.hdr"} | ({"sun_from": "catalogue"} if name != "000002" else {})
        (root / name / "source.json").write_text(json.dumps({"lighting": lighting, "sun_scene": sun}))
    by = {s.name: s for s in load_sources(root)}
    assert not by["000000"].sun.visible
    assert by["000001"].sun.visible and np.allclose(by["000001"].sun.direction, [0.0, -0.6, 0.8])
    assert by["000002"].sun is None  # detected from its lighting, as before
    (root / "000000" / "source.json").write_text(json.dumps({"lighting": {"sun_from": "catalogue"}}))
    with pytest.raises(InputError, match="not a rendered source"):
        load_sources(root)
