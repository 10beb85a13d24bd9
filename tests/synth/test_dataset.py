"""Samples, sharded/resumable dataset generation, the torch Dataset, the colour filter and the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from solidkit.envmap import read_exr, write_ldr  # noqa: E402
from solidkit.errors import InputError  # noqa: E402
from solidkit.synth.dataset import SynthDataset, build_index, generate, parse_shard, rescore, shard_range  # noqa: E402
from solidkit.synth.filter import ReferenceSet, colour_histogram, histogram_intersection  # noqa: E402
from solidkit.synth.sample import FILES, Generator, SampleConfig  # noqa: E402

TINY = SampleConfig(
    width=32,
    height=24,
    spp=2,
    buffer_spp=2,
    env_height=8,
    env_spp=2,
    probe_height=8,
    probe_spp=2,
    candidates=2,
    item_size=(16, 12),
    light_height=64,
    tex_size=8,
    block_length=25.0,
)


def arrays(folder: Path) -> dict[str, np.ndarray]:
    out = {}
    for name in ("image", "albedo", "normal", "depth", "plane_distance", "shadow", "global"):
        out[name] = read_exr(folder / FILES[name])[0]
    for k, p in enumerate(FILES["probes"]):
        out[f"probe{k}"] = read_exr(folder / p)[0]
    return out


def test_same_seed_same_sample(tmp_path: Path) -> None:
    a = Generator(11, TINY).render(3, tmp_path / "a")
    b = Generator(11, TINY).render(3, tmp_path / "b")
    for key in ("camera", "lighting", "sun", "probes", "view_selection"):
        assert a[key] == b[key]
    other_block, (other_cam, _) = Generator(12, TINY).block_and_view(0, 3)
    assert other_cam.to_json() != a["camera"]
    A, B = arrays(tmp_path / "a"), arrays(tmp_path / "b")
    for name in A:
        assert np.array_equal(A[name], B[name]), name


def test_sample_record(tmp_path: Path) -> None:
    rec = Generator(2, TINY).render(0, tmp_path / "s")
    assert json.loads((tmp_path / "s" / FILES["meta"]).read_text()) == rec
    cam = rec["camera"]
    assert 1.50 - 1e-9 <= -cam["position"][1] - (0.15 if cam["position"][1] < -1.6 else 0.0) <= 1.60 + 1e-9
    assert abs(cam["pitch_deg"]) <= 10.0 and 0 <= rec["sector"] < 6
    assert -180.0 + 60 * rec["sector"] <= cam["yaw_deg"] < -120.0 + 60 * rec["sector"]
    assert len(rec["probes"]) == 4
    img = read_exr(tmp_path / "s" / FILES["image"])[0]
    assert img.shape == (24, 32, 3) and np.isfinite(img).all()
    glob = read_exr(tmp_path / "s" / FILES["global"])[0]
    assert glob.shape == (8, 16, 3)
    for p in rec["probes"]:
        # the probe centre is 10 cm off the surface point along its normal, and the point projects to its pixel
        pt, c, n = (np.asarray(p[k]) for k in ("point_scene", "centre_scene", "normal_scene"))
        assert np.allclose(c - pt, 0.10 * n, atol=1e-6)
        from solidkit.synth.cameras import Camera

        px = Camera.from_json(cam).project(pt)
        assert np.allclose(px, p["pixel"], atol=1e-3)
    if rec["sun"]["found"]:
        assert -90 <= rec["sun"]["elevation_deg"] <= 90
    assert rec["renderer"]["spp"] == 2 and rec["conventions_version"] == 1


def test_shards_partition_indices() -> None:
    n = 23
    got = sorted(i for s in range(4) for i in shard_range(n, s, 4))
    assert got == list(range(n))
    assert parse_shard("2/5") == (2, 5) and parse_shard(None) == (0, 1)
    for bad in ("5/5", "a/b", "1", "-1/3"):
        with pytest.raises(InputError):
            parse_shard(bad)


def test_generate_resume_index_and_torch_dataset(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    c1 = generate(root, 2, seed=4, shard=(1, 2), config=TINY)  # index 1
    assert c1 == {"rendered": 1, "skipped": 0, "kept": 0}
    c2 = generate(root, 2, seed=4, shard=(0, 2), config=TINY)  # index 0
    assert c2["rendered"] == 1
    c3 = generate(root, 2, seed=4, config=TINY)  # everything is there: resumes by skipping
    assert c3 == {"rendered": 0, "skipped": 2, "kept": 0}
    with pytest.raises(InputError):
        generate(root, 2, seed=5, config=TINY)
    index = json.loads((root / "index.json").read_text())
    assert [e["index"] for e in index["samples"]] == [0, 1]
    ds = SynthDataset(root)
    assert len(ds) == 2
    item = ds[1]
    assert item["image"].shape == (3, 24, 32) and item["probes"].shape == (4, 3, 8, 16)
    assert item["normal"].shape == (3, 24, 32) and item["shadow"].shape == (1, 24, 32)
    assert float(item["image"].min()) >= 0 and float(item["image"].max()) <= 1
    if float(item["sun_found"]):
        assert math.isclose(float(item["sun"].norm()), 1.0, rel_tol=1e-5)
    import torch

    batch = next(iter(torch.utils.data.DataLoader(SynthDataset(root, fields=("image", "global")), batch_size=2)))
    assert batch["image"].shape == (2, 3, 24, 32) and batch["global"].shape == (2, 3, 8, 16)
    # the colour filter marks samples; keep_only drops rejected ones
    ref = ReferenceSet(np.stack([colour_histogram(np.zeros((4, 4, 3)))]), ["black"])
    generate(tmp_path / "f", 1, seed=4, config=TINY, reference=ref, threshold=0.99)
    build_index(tmp_path / "f")
    assert len(SynthDataset(tmp_path / "f")) == 0 and len(SynthDataset(tmp_path / "f", keep_only=False)) == 1
    # re-scoring (`solidkit synth filter`) updates the same record in place and rebuilds the index
    meta = next((tmp_path / "f" / "samples").glob("*/sample.json"))
    before = json.loads(meta.read_text())["filter"]
    assert rescore(tmp_path / "f", ref, threshold=0.0) == {"samples": 1, "kept": 1, "references": 1}
    assert json.loads(meta.read_text())["filter"] == {**before, "threshold": 0.0, "keep": True}
    assert len(SynthDataset(tmp_path / "f")) == 1


def test_histogram_intersection(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    a, b = rng.random((20, 30, 3)), rng.random((20, 30, 3)) ** 3
    ha, hb = colour_histogram(a), colour_histogram(b)
    assert ha.shape == (512,) and ha.sum() == pytest.approx(1.0)
    assert histogram_intersection(ha, ha) == pytest.approx(1.0)
    assert histogram_intersection(ha, hb) == pytest.approx(histogram_intersection(hb, ha))
    assert 0.0 <= histogram_intersection(ha, hb) < 1.0
    # disjoint colours do not intersect; a half-overlap intersects by half
    black, white = np.zeros((4, 4, 3)), np.ones((4, 4, 3))
    half = np.concatenate([black[:2], white[:2]])
    assert histogram_intersection(colour_histogram(black), colour_histogram(white)) == 0.0
    assert histogram_intersection(colour_histogram(black), colour_histogram(half)) == pytest.approx(0.5)
    write_ldr(tmp_path / "ref" / "a.png", a.astype(np.float32))
    write_ldr(tmp_path / "ref" / "b.jpg", white.astype(np.float32))
    ref = ReferenceSet.from_dir(tmp_path / "ref")
    assert ref.score(white) == pytest.approx(1.0) and ref.score(black) == 0.0
    with pytest.raises(InputError):
        ReferenceSet.from_dir(tmp_path / "nothing")


def test_cli_errors_are_one_line(tmp_path: Path, cli) -> None:
    code, _, err = cli("synth", "dataset", "--n", "2", "--out", str(tmp_path), "--shard", "3/2")
    assert code == 2 and "need 0 <= i < N" in err and "Traceback" not in err
    code, _, err = cli("synth", "filter", str(tmp_path), "--reference", str(tmp_path / "none"))
    assert code == 2 and "no samples (not a dataset" in err and len(err.strip().splitlines()) == 1  # checked first


def test_cli_holds_out_hdr_maps(tmp_path: Path, cli, monkeypatch) -> None:
    import solidkit.synth.dataset as ds

    seen = {}

    def fake_generate(out, n, *, config, **kw):  # the renderer is tested above; this checks what the CLI passes
        seen["config"] = config
        return {"rendered": 0, "skipped": n, "kept": 0}

    monkeypatch.setattr(ds, "generate", fake_generate)
    code, _, err = cli("synth", "dataset", "--n", "1", "--out", str(tmp_path / "d"), "--exclude-hdr", "city")
    assert code == 0, err
    assert seen["config"].exclude_hdr == ("city",) and seen["config"].to_json()["exclude_hdr"] == ["city"]
