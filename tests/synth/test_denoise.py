"""Denoising of renders with Open Image Denoise: guides, the error against a many-sample reference, records."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from solidkit.envmap import tonemap  # noqa: E402
from solidkit.synth.cameras import pinhole_sensor  # noqa: E402
from solidkit.synth.campaign_truth import CampaignConfig  # noqa: E402
from solidkit.synth.panocrops import SourceConfig  # noqa: E402
from solidkit.synth.render import render_rgb  # noqa: E402
from solidkit.synth.sample import Generator, SampleConfig, render_clean, sun_mask_image, suppress_fireflies  # noqa: E402
from solidkit.synth.scene import to_mitsuba  # noqa: E402


def tiny_scene() -> tuple[object, object, np.ndarray | None]:
    gen = Generator(5, SampleConfig(width=48, height=36, candidates=2, item_size=(16, 12), block_length=25.0))
    block, (cam, _) = gen.block_and_view(0, 1)
    light = gen.lighting(1)
    return to_mitsuba(block, light.emitter(), tex_size=8), cam, sun_mask_image(light.sun, cam)


def psnr(x: np.ndarray, ref: np.ndarray) -> float:
    return -10.0 * math.log10(float(np.mean((np.asarray(tonemap(x)) - np.asarray(tonemap(ref))) ** 2)))


def test_denoising_brings_a_few_samples_closer_to_the_reference() -> None:
    pytest.importorskip("pyoidn")
    from solidkit.synth.denoise import render_guides

    scene, cam, sun = tiny_scene()
    ref, _ = render_clean(scene, pinhole_sensor(cam, spp=512, seed=3), 512, seed=3, protect=sun)
    noisy, _ = render_clean(scene, pinhole_sensor(cam, spp=4, seed=4), 4, seed=4, protect=sun)
    clean, _ = render_clean(scene, pinhole_sensor(cam, spp=4, seed=4), 4, seed=4, protect=sun, denoise=True)
    assert clean.shape == noisy.shape == (36, 48, 3) and clean.dtype == np.float32
    assert np.isfinite(clean).all() and clean.min() >= 0.0
    assert psnr(clean, ref) > psnr(noisy, ref) + 3.0
    if sun is not None:
        assert np.array_equal(clean[sun], noisy[sun])  # the sun kept as rendered
    assert not np.array_equal(clean, noisy)
    albedo, normal = render_guides(scene, pinhole_sensor(cam, spp=4, seed=4), 4, seed=4)
    assert 0.0 <= albedo.min() and albedo.max() <= 1.0 + 1e-6
    length = np.linalg.norm(normal, axis=-1)
    surface = albedo.sum(-1) > 0
    assert surface.any() and (~surface).any()  # street and sky in view
    assert np.all(length[~surface] < 1e-6)  # no normal where rays see the sky
    assert np.median(length[surface]) > 0.99


def test_without_denoise_the_render_is_the_plain_one() -> None:
    scene, cam, sun = tiny_scene()
    plain, n = suppress_fireflies(render_rgb(scene, pinhole_sensor(cam, spp=2, seed=8), 2, seed=8), sun, 10.0)
    again, m = render_clean(scene, pinhole_sensor(cam, spp=2, seed=8), 2, seed=8, protect=sun)
    assert np.array_equal(plain, again) and n == m


def test_the_setting_is_recorded_only_when_on() -> None:
    assert "denoise" not in SampleConfig().to_json() and SampleConfig(denoise=True).to_json()["denoise"] is True
    assert "denoise" not in SourceConfig().to_json() and SourceConfig(denoise=True).to_json()["denoise"] is True
    assert "denoise" not in CampaignConfig().model_dump(mode="json")
    assert CampaignConfig(denoise=True).model_dump(mode="json")["denoise"] is True
    assert CampaignConfig.model_validate(CampaignConfig(denoise=True).model_dump(mode="json")).denoise
