"""testset import --format sold-net: SOLD-Net's real-set layout back into a test set, and eval on it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.envmap.io import read_exr, read_hdr, read_ldr
from solidkit.envmap.resample import resize
from solidkit.metrics.maps import simulate_ldr_probe
from solidkit.testset.build import build_testset, load_testset
from solidkit.testset.sold_net import export_sold_net
from solidkit.testset.sold_net_import import SUN_CELL_DEG, sun_cell_uncertainty_deg
from solidkit.testset.validate import validate_testset
from tests.support.testset_campaign import make_campaign


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("campaign") / "camp"
    make_campaign(root)
    out = tmp_path_factory.mktemp("ts") / "testset"
    build_testset(root, out)
    return out


def _angle_deg(a, b) -> float:
    return math.degrees(math.acos(min(1.0, float(np.dot(a, b)))))


def test_export_import_round_trip_and_eval(built, tmp_path, cli):
    sold, back = tmp_path / "sold", tmp_path / "back"
    export_sold_net(built, sold)
    code, out, err = cli("testset", "import", sold, back, "--format", "sold-net", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["ids_from"] == "solidkit_items.json" and report["skipped_by_sold_net_loader"] == ["002"]
    ts, got = load_testset(built), load_testset(back)
    assert [s.id for s in got.scenes] == [s.id for s in ts.scenes]
    for s, g in zip(ts.scenes, got.scenes):
        assert [p.id for p in g.probes] == [p.id for p in s.probes]
        xxx = f"{ts.scenes.index(s) + 1:03d}"
        # pixels: their integer (row, col) indices are our pixel centres, no offset (conventions §1)
        for p, q in zip(s.probes, g.probes):
            assert q.pixel == (round(p.pixel[0]), round(p.pixel[1])) and q.pixel_full == q.pixel
            assert max(abs(q.pixel[0] - p.pixel[0]), abs(q.pixel[1] - p.pixel[1])) <= 0.5
        # probes: hdr_full is their 128x64 map as stored; hdr is it at 256x128, radiance-preserving
        for k, (p, q) in enumerate(zip(s.probes, g.probes)):
            stored = read_hdr(sold / f"{xxx}_local_{k}.hdr")
            full = read_exr(back / q.images.hdr_full)[0][..., :3]
            assert np.array_equal(full, stored)
            big = read_exr(back / q.hdr)[0][..., :3]
            assert big.shape == (128, 256, 3)
            np.testing.assert_allclose(resize(big, 64), stored, rtol=1e-6, atol=1e-7)
            ref = resize(read_exr(built / p.hdr)[0][..., :3], 64)
            assert np.median(np.abs(full - ref) / np.maximum(ref, 1e-4)) < 0.01  # RGBE: 8-bit mantissa
            ldr, sat = read_ldr(back / q.ldr), read_ldr(back / q.images.saturation)[..., 0] > 0.5
            want_ldr, want_sat = simulate_ldr_probe(big)  # as eval makes a synthetic probe's LDR truth
            assert np.array_equal(np.round(ldr * 255), np.round(want_ldr * 255)) and np.array_equal(sat, want_sat)
        # the photo: JPEG q95 of the 320x240 model input
        photo, mine = read_ldr(built / s.photo), read_ldr(back / g.photo)
        assert 10 * math.log10(1 / np.mean((photo - mine) ** 2)) > 35
        # the sun: exact through their grid (we write sub-cell positions), with the grid's uncertainty
        assert g.sun.found == s.sun.found
        if s.sun.found:
            assert _angle_deg(g.sun.direction, s.sun.direction) < 1e-4
            assert g.sun.uncertainty_deg == pytest.approx(sun_cell_uncertainty_deg(g.sun.elevation_deg))
            assert g.sun.source == "annotator" and g.sun.annotator == "sold-net"
    problems = validate_testset(back)
    assert problems and {p.check for p in problems} == {"flags"}  # assumed K, pitch and roll: flagged, not wrong
    assert all("no_intrinsics" in g.flags[0] for g in got.scenes)

    # the second trip (import -> export -> import) is exact on everything both layouts hold
    sold2, back2 = tmp_path / "sold2", tmp_path / "back2"
    export_sold_net(back, sold2)
    assert cli("testset", "import", sold2, back2, "--format", "sold-net")[0] == 0
    again = load_testset(back2)
    for g, h in zip(got.scenes, again.scenes):
        assert (back / g.photo_full).read_bytes() == (back2 / h.photo_full).read_bytes()
        assert (g.sun.azimuth_deg, g.sun.elevation_deg) == (h.sun.azimuth_deg, h.sun.elevation_deg)
        for q, r in zip(g.probes, h.probes):
            assert q.pixel == r.pixel
            assert np.array_equal(read_exr(back / q.hdr)[0], read_exr(back2 / r.hdr)[0])

    code, out, err = cli("eval", "--testset", back, "-o", tmp_path / "eval", "--grids", "0", "--json")
    assert code == 0, err
    model = json.loads(out)["real"]["solidnet"]
    assert model["local_ssim"]["n"] == sum(len(g.probes) for g in got.scenes)
    assert model["angle_deg/paper"]["n"] == sum(g.sun.found for g in got.scenes)


def _write_item(
    folder: Path, xxx: str, pos: list[list[int]], sun: str | None, seed: int = 0, scale: float = 1.0
) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    folder.mkdir(exist_ok=True)
    photo = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    photo[120:] = (60, 90, 60)  # ground under the marked pixels (the sky check)
    cv2.imwrite(str(folder / f"{xxx}_persp.JPG"), photo)
    np.save(folder / f"{xxx}_local.npy", np.asarray(pos, dtype=np.int64))
    maps = []
    for k in range(len(pos)):
        hdr = (scale * rng.uniform(0.01, 3.0, (64, 128, 3))).astype(np.float32)
        cv2.imwrite(str(folder / f"{xxx}_local_{k}.hdr"), hdr[..., ::-1].copy())
        maps.append(read_hdr(folder / f"{xxx}_local_{k}.hdr"))
    if sun is not None:
        (folder / f"{xxx}_sun_pos.txt").write_text(sun)
    return maps


def test_their_conventions_cells_and_negative_positions(tmp_path, cli):
    """A folder written by hand in their layout: an integer sun cell, a negative (encoded) position, no sun."""
    src = tmp_path / "real"
    maps = _write_item(src, "001", [[150, 100], [-1 - 170, -1 - 200]], "63\n31\n")
    _write_item(src, "002", [[200, 40], [210, 300]], None, seed=1, scale=1000.0)  # our merges' units
    code, out, err = cli(
        "testset", "import", src, tmp_path / "ts", "--format", "sold-net", "--hfov-deg", "70", "--json"
    )
    assert code == 0, err
    assert json.loads(out)["ids_from"] == "layout"
    ts = load_testset(tmp_path / "ts")
    a, b = ts.scenes
    assert (a.id, [p.id for p in a.probes]) == ("001", ["p0", "p1"])
    assert [p.pixel for p in a.probes] == [(100.0, 150.0), (200.0, 170.0)]
    assert not a.probes[0].flags and a.probes[1].flags[0].startswith("sold_net_negative_position")
    # their estimator_test_real.py, literally: azimuth = (col - 63.5) / 64 * 180, elevation = (31.5 - row) / 64 * 180
    assert (a.sun.azimuth_deg, a.sun.elevation_deg) == pytest.approx(((63 - 63.5) / 64 * 180, (31.5 - 31) / 64 * 180))
    assert SUN_CELL_DEG == pytest.approx(2.8125)
    assert a.sun.uncertainty_deg == pytest.approx(
        2.8125 / math.sqrt(12) * math.sqrt(1 + math.cos(math.radians(1.40625)) ** 2)
    )
    assert not b.sun.found and b.sun.azimuth_deg is None
    # the LDR truth is exposed for the map whatever its scale (a fixed exposure would clip all of item 002)
    assert all(p.images.saturated_fraction < 0.01 for p in a.probes + b.probes)
    # K: an ideal pinhole of the given FOV; their maps kept as stored
    assert a.K[0][0] == pytest.approx(160 / math.tan(math.radians(35))) and a.K_source.startswith("assumed")
    for p, m in zip(a.probes, maps):
        assert np.array_equal(read_exr(tmp_path / "ts" / p.images.hdr_full)[0][..., :3], m)
        assert p.rotation == np.eye(3).tolist()
    assert {p.check for p in validate_testset(tmp_path / "ts")} == {"flags"}
    # refused: a format we do not read, and writing over something that is not a test set
    assert cli("testset", "import", src, tmp_path / "x", "--format", "laval")[0] == 2
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"x")
    code, _, err = cli("testset", "import", src, tmp_path / "photos", "--format", "sold-net")
    assert code == 2 and "not a solidkit test set" in err
    assert cli("testset", "import", tmp_path / "photos", tmp_path / "y", "--format", "sold-net")[0] == 2
    code, _, err = cli("testset", "import", src, src / "ts", "--format", "sold-net")
    assert code == 2 and "outside the SOLD-Net folder" in err and not (src / "ts").exists()
