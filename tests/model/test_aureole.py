"""The sun's aureole: the global map's sun spread over its own direction uncertainty."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from solidkit.envmap import angular_distance, direction_from_angles, solid_angle
from solidkit.metrics import find_sun
from solidkit.model.config import ConfigError, preset
from solidkit.model.sunhead import CONE68_PER_SIGMA, aureole_sigma, render_sun, render_sun_with_aureole

H = 64


def _sun(az_deg: float = 40.0, el_deg: float = 30.0) -> torch.Tensor:
    return torch.as_tensor(np.asarray(direction_from_angles(math.radians(az_deg), math.radians(el_deg))))[None].float()


def test_cone68_per_sigma_holds_68_percent_of_a_2d_gaussian():
    r = np.random.default_rng(0).normal(size=(200_000, 2))
    assert np.mean(np.hypot(r[:, 0], r[:, 1]) <= CONE68_PER_SIGMA) == pytest.approx(0.68, abs=0.005)


def test_aureole_keeps_the_energy_and_puts_68_percent_of_its_part_in_the_cone():
    d, e, s = _sun(), torch.tensor([[3.0, 2.0, 1.0]]), torch.tensor([math.radians(0.5)])
    omega = solid_angle(2 * H, torch).float()
    cone = torch.tensor([15.0])
    sun = render_sun_with_aureole(d, e, s, cone, 0.8, 2 * H)
    assert torch.allclose((sun * omega).sum(dim=(2, 3)), e, rtol=1e-4)
    wide = render_sun(d, e, aureole_sigma(cone, s), 2 * H)[0, 0]
    from solidkit.envmap.coords import direction_grid

    inside = torch.as_tensor(direction_grid(2 * H)).float() @ d[0] >= math.cos(math.radians(15.0))
    frac = float((wide * omega)[inside].sum() / (wide * omega).sum())
    assert frac == pytest.approx(0.68, abs=0.03)
    assert torch.equal(render_sun_with_aureole(d, e, s, cone, 0.0, 2 * H), render_sun(d, e, s, 2 * H))


def test_aureole_is_never_sharper_than_the_sun():
    s = torch.tensor([math.radians(2.0), math.radians(0.5)])
    got = aureole_sigma(torch.tensor([1.0, 30.0]), s)
    assert float(got[0]) == pytest.approx(math.radians(2.0))
    assert float(got[1]) == pytest.approx(math.radians(30.0) / CONE68_PER_SIGMA)


def test_with_an_aureole_the_papers_recipe_finds_the_sun_a_bright_horizon_band_hides():
    """A sharp sun is too small to be the largest top-2 % component beside a bright horizon band; its
    aureole makes the sun's surroundings that component, so both recipes name one sun."""
    h = H
    sky = np.full((h, 2 * h, 3), 1.0, np.float32)
    phi = (np.arange(2 * h) + 0.5) / (2 * h) * 2 * math.pi - math.pi
    sky[h // 2 - 4 : h // 2] = (4.0 + 2.0 * np.cos(phi - math.radians(60.0)))[None, :, None]  # a haze band
    d, e, s = _sun(-120.0, 35.0), torch.tensor([[20.0, 20.0, 20.0]]), torch.tensor([math.radians(0.6)])
    truth = d[0].numpy()
    for fraction, agrees in ((0.0, False), (0.8, True)):
        sun = render_sun_with_aureole(d, e, s, torch.tensor([12.0]), fraction, h)[0].permute(1, 2, 0).numpy()
        pano = sky + sun
        core, paper = find_sun(pano, "core"), find_sun(pano, "paper")
        assert core.found and math.degrees(float(angular_distance(core.direction, truth))) < 1.5
        off = math.degrees(float(angular_distance(paper.direction, truth)))
        assert (off < 3.0) is agrees, (fraction, off)


def test_config_checks_the_aureole():
    with pytest.raises(ConfigError, match="sun_aureole must be"):
        preset("small-sun").replace(sun_aureole=1.0)
    with pytest.raises(ConfigError, match="needs the direction cones"):
        preset("small").replace(sun_aureole=0.5)
    assert preset("small-sun").replace(sun_aureole=0.8).sun_aureole == 0.8


def test_recalibrated_cones_leave_the_global_map_as_the_aureole_was_tuned():
    from solidkit.model import SolidNet

    torch.manual_seed(0)
    model = SolidNet(preset("small-sun").replace(sun_aureole=0.8, sun_cone_scale=(1.0, 1.1))).eval()
    image = torch.rand(1, 3, 240, 320)
    with torch.no_grad():
        a = model.inet(image, intrinsics=False)
        model.reconfigure(sun_cone_scale=(1.3, 1.4))
        b = model.inet(image, intrinsics=False)
    assert (b["sun_cone_deg"] > a["sun_cone_deg"]).all()  # an untrained network: wide cones, capped at 180°
    assert torch.equal(a["sky"], b["sky"])
