"""Truth probes of the virtual campaign: noise falls with samples; re-rendering only the truth leaves the card alone."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from solidkit.errors import InputError

pytest.importorskip("mitsuba")

from solidkit.envmap import read_exr, tonemap  # noqa: E402
from solidkit.synth.campaign import CampaignConfig, generate_campaign, load_truth  # noqa: E402
from solidkit.synth.truth_probes import PASS_SAMPLES, needed_spp, pass_plan  # noqa: E402
from solidkit.synth.truth_rerender import rerender_truth  # noqa: E402

TINY = dict(
    photo_width=32,
    photo_height=24,
    photo_spp=1,
    pano_height=16,
    pano_spp=4,
    probe_height=8,
    probe_spp=4,
    fisheye_width=64,
    candidates=2,
    block_length=25.0,
    p_sunsky=1.0,
    glass_every=0,
    probe_noise_db=0.0,
)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("truth") / "camp"
    generate_campaign(out, 1, 1, seed=4, config=CampaignConfig(**TINY))
    return out


def _digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_pass_plan_splits_the_samples_into_passes_that_fit() -> None:
    assert pass_plan(128, 256) == [128, 128]  # fits one pass (8.4 M samples); two halves for the noise estimate
    assert pass_plan(128, 1) == [1]
    assert needed_spp(34.0, 256, 40.0, 4096) == 1020 and needed_spp(34.0, 256, 40.0, 512) == 512
    assert needed_spp(41.0, 256, 40.0, 4096) is None and needed_spp(30.0, 256, 0.0, 4096) is None
    plan = pass_plan(128, 1000)
    assert sum(plan) == 1000 and max(plan) * 2 * 128 * 128 <= PASS_SAMPLES and max(plan) - min(plan) <= 1
    assert len(plan) % 2 == 0
    with pytest.raises(ValueError):
        pass_plan(128, 0)


def test_campaign_truth_refuses_what_is_not_a_campaign(tmp_path: Path) -> None:
    (tmp_path / "card").mkdir()
    with pytest.raises(InputError, match="not a complete virtual campaign"):
        rerender_truth(tmp_path)


def test_truth_rerender_keeps_the_card_records_its_spp_and_is_idempotent(tiny: Path, tmp_path: Path) -> None:
    import shutil

    camp = tmp_path / "camp"
    shutil.copytree(tiny, camp)
    card = _digests(camp / "card")
    truth0 = load_truth(camp / "truth" / "truth.json")
    probe = next(c for c in truth0.scenes[0].captures if c.probe is not None)
    assert probe.probe.render["spp"] == 4 and probe.probe.render["version"] == 4  # new campaigns record theirs
    res = rerender_truth(camp, spp=12, noise_db=0.0)
    assert res["rendered"] == 1 and res["skipped"] == 0 and res["complete"]
    assert _digests(camp / "card") == card  # the captures are not touched
    truth = load_truth(camp / "truth" / "truth.json")
    rec = next(c for c in truth.scenes[0].captures if c.probe is not None).probe.render
    assert rec["spp"] == 12 and rec["previous"]["spp"] == 4 and rec["check_psnr_db"] >= 25.0
    assert rec["noise_psnr_db"] > rec["previous"]["noise_psnr_db"]
    assert truth.config.probe_spp == 12 and truth.renderer["truth_probes"]["probe_spp"] == 12
    assert json.loads((camp / "truth" / "campaign.json").read_text())["config"]["probe_spp"] == 12
    assert read_exr(camp / probe.probe.hdr_file)[1]["truth_spp"] == 12
    # everything but the truth probe and its records is the same truth
    strip = truth.model_dump(mode="json")
    old = truth0.model_dump(mode="json")
    for t in (strip, old):
        t["config"].pop("probe_spp"), t["config"].pop("probe_noise_db"), t["renderer"].pop("truth_probes", None)
        for sc in t["scenes"]:
            for c in sc["captures"]:
                if c["probe"]:
                    c["probe"].pop("render")
    assert strip == old
    # a second run changes nothing
    stamps = {p: p.stat().st_mtime_ns for p in camp.rglob("*") if p.is_file()}
    again = rerender_truth(camp, spp=12, noise_db=0.0)
    assert again["rendered"] == 0 and again["skipped"] == 1
    assert all(p.stat().st_mtime_ns == t for p, t in stamps.items())
    # a noise target the stored render meets keeps it; one it misses gets a fresh render with more samples
    pixels = read_exr(camp / probe.probe.hdr_file)[0]
    kept = rerender_truth(camp, spp=12, noise_db=1.0)
    assert kept["kept"] == 1 and np.array_equal(read_exr(camp / probe.probe.hdr_file)[0], pixels)
    more = rerender_truth(camp, spp=12, noise_db=80.0, max_spp=36)
    rec = more["probes"][0]
    assert more["rendered"] == 1 and rec["spp"] == 36 and rec["pilot"]["spp"] == 12  # capped at max_spp
    assert rec["noise_psnr_db"] > rec["pilot"]["noise_psnr_db"]


def test_truth_rerender_refuses_a_scene_it_cannot_rebuild(tiny: Path, tmp_path: Path) -> None:
    import shutil

    camp = tmp_path / "camp"
    shutil.copytree(tiny, camp)
    path = camp / "truth" / "scene01" / "scene.json"
    st = json.loads(path.read_text())
    st["lighting"]["turbidity"] = st["lighting"].get("turbidity", 3.0) + 1.0  # not the lighting this seed draws
    path.write_text(json.dumps(st))
    before = _digests(camp)
    with pytest.raises(InputError, match="does not rebuild the scene"):
        rerender_truth(camp, spp=2)
    assert _digests(camp) == before


def test_truth_probe_noise_falls_with_samples(tiny: Path) -> None:
    """Two independent renders at 2 and at 32 spp: their difference (pure Monte Carlo noise) shrinks ~sqrt(16)."""
    from solidkit.align.evaluate import psnr
    from solidkit.synth.campaign_truth import load_truth as lt
    from solidkit.synth.mitsuba_variant import mitsuba
    from solidkit.synth.sample import Generator, SampleConfig
    from solidkit.synth.truth_probes import render_truth_probe
    from solidkit.synth.truth_rerender import _rebuild

    t = lt(tiny / "truth" / "truth.json")
    cfg = t.config
    gen = Generator(
        t.seed,
        SampleConfig(
            width=cfg.photo_width,
            height=cfg.photo_height,
            hfov_deg=cfg.hfov_deg,
            candidates=cfg.candidates,
            p_sunsky=cfg.p_sunsky,
            block_length=cfg.block_length,
        ),
    )
    st = t.scenes[0]
    built = _rebuild(mitsuba(), gen, st, t.seed, cfg)
    pos = np.asarray(next(c for c in st.captures if c.probe is not None).position)

    def noise(spp: int) -> tuple[float, float]:
        """(rms difference of two independent renders, the renders' own split-half noise PSNR)."""
        (a, ra), (b, rb) = (
            render_truth_probe(built["scene"], pos, built["cam"].pano_rotation, 32, spp, seed=seed, firefly_k=0.0)
            for seed in (1, 2)
        )
        pair_db = psnr(np.asarray(tonemap(a)), np.asarray(tonemap(b))) + 10.0 * np.log10(2.0)  # one render's noise
        if spp >= 32:  # the split-half estimate linearises the tonemap: not at 1 sample per half
            assert abs(ra["noise_psnr_db"] - pair_db) < 2.0 and abs(rb["noise_psnr_db"] - pair_db) < 2.0
        return float(np.sqrt(np.mean((np.asarray(tonemap(a)) - np.asarray(tonemap(b))) ** 2))), pair_db

    (low, low_db), (high, high_db) = noise(2), noise(32)
    assert 0.0 < high < low / 2.5  # sqrt(16) = 4 in expectation
    assert high_db > low_db + 8.0  # 12 dB in expectation


@pytest.mark.slow
def test_a_new_campaign_gets_a_truth_clean_to_its_noise_target(tmp_path: Path) -> None:
    """Default truth recipe at full probe size (128 px): the measured noise reaches ~40 dB and an independent
    render of the same recipe (another seed) agrees with the stored truth to within that noise."""
    from solidkit.align.evaluate import psnr
    from solidkit.synth.campaign_truth import load_truth as lt
    from solidkit.synth.mitsuba_variant import mitsuba
    from solidkit.synth.sample import Generator, SampleConfig
    from solidkit.synth.truth_probes import clean_truth_probe
    from solidkit.synth.truth_rerender import _rebuild

    cfg = CampaignConfig(
        photo_width=64,
        photo_height=48,
        photo_spp=2,
        pano_height=64,
        pano_spp=16,
        fisheye_width=256,
        candidates=2,
        block_length=25.0,
        p_sunsky=1.0,
        glass_every=0,
    )
    generate_campaign(tmp_path / "c", 1, 1, seed=6, config=cfg)
    t = lt(tmp_path / "c" / "truth" / "truth.json")
    st = t.scenes[0]
    ct = next(c for c in st.captures if c.probe is not None)
    rec = ct.probe.render
    assert rec["version"] == 4 and rec["base_spp"] == 256 and rec["firefly_spp"] == 16
    assert rec["noise_psnr_db"] >= 38.0 or rec["spp"] == rec["max_spp"], rec
    gen = Generator(
        t.seed,
        SampleConfig(
            width=cfg.photo_width,
            height=cfg.photo_height,
            hfov_deg=cfg.hfov_deg,
            candidates=cfg.candidates,
            p_sunsky=cfg.p_sunsky,
            block_length=cfg.block_length,
        ),
    )
    built = _rebuild(mitsuba(), gen, st, t.seed, cfg)
    other, orec = clean_truth_probe(
        built["scene"],
        np.asarray(ct.position),
        built["cam"].pano_rotation,
        128,
        256,
        seed=12345,
        noise_target_db=40.0,
        max_spp=2048,
        sun=built["light"].sun,
        firefly_k=cfg.firefly_k,
        firefly_spp=16,
    )
    stored = read_exr(tmp_path / "c" / ct.probe.hdr_file)[0][..., :3]
    # two independent estimates: their difference carries both noises (~3 dB under one's noise PSNR)
    assert psnr(tonemap(stored), tonemap(other)) > min(rec["noise_psnr_db"], orec["noise_psnr_db"]) - 5.0
