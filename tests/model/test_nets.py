"""I-Net, P-Net, SolidNet and baselines: shapes, dtypes, gradients, overfitting one toy sample."""

from __future__ import annotations

import pytest
import torch

from solidkit.model.baselines import BASELINES, LENetReg, build_baseline
from solidkit.model.config import ConfigError, SolidNetConfig, preset
from solidkit.model.fit import fit, toy_batch
from solidkit.model.inet import flip_pad
from solidkit.model.losses import solidnet_losses
from solidkit.model.solidnet import SolidNet

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _batch(cfg, b, n=2, seed=0):
    return toy_batch(cfg, b, n, seed)


@pytest.mark.parametrize("b", [1, 4])
def test_solidnet_shapes_and_dtypes(b):
    torch.manual_seed(0)
    cfg = preset("tiny")  # full-size input (240 x 320) and panoramas (128 x 256)
    model = SolidNet(cfg).eval()
    batch = _batch(cfg, b)
    with torch.no_grad():
        out = model(batch["image"], batch["K"], batch["pixels"], batch["pitch"], batch["roll"])
    expect = {
        "albedo": (b, 3, 240, 320),
        "normal": (b, 3, 240, 320),
        "distance": (b, 1, 240, 320),
        "shadow": (b, 1, 240, 320),
        "sh": (b, 3, 9),
        "sky_log": (b, 3, 128, 256),
        "sky": (b, 3, 128, 256),
        "rotation": (b, 3, 3),
        "warped_image": (b, 2, 3, 128, 256),
        "warped_shadow": (b, 2, 1, 128, 256),
        "warped_mask": (b, 2, 1, 128, 256),
        "centres": (b, 2, 3),
        "probe_valid": (b, 2),
        "local_log": (b, 2, 3, 128, 256),
        "local": (b, 2, 3, 128, 256),
        # the sun head (tiny has it, like the shipped small preset)
        "sun_logits": (b, 1, 64, 128),  # the sky decoder's last stage (sky_stages = 3)
        "sun_dir": (b, 3),
        "sun_energy": (b, 3),
        "sun_log_energy": (b, 3),
        "sun_sigma": (b,),
        "sun_visible": (b,),  # the probability that a sun is visible, and its logit
        "sun_visible_logit": (b,),
        "sky_np_log": (b, 3, 128, 256),
        # evaluation only: the sun moved onto a clipped image blob, and its 68 % / 90 % cones (degrees)
        "sun_on_blob": (b,),
        "sun_cone_radius_deg": (b, 2),
        "sun_cone_deg": (b, 2),
    }
    assert set(out) == set(expect)
    for k, shape in expect.items():
        assert tuple(out[k].shape) == shape, k
        assert out[k].dtype == (torch.bool if k in ("probe_valid", "sun_on_blob") else torch.float32), k
        assert torch.isfinite(out[k]).all(), k
    assert ((out["albedo"] >= 0) & (out["albedo"] <= 1)).all()
    assert torch.allclose(out["normal"].norm(dim=1), torch.ones(b, 240, 320), atol=1e-4)
    assert (out["distance"] >= 0).all() and (out["sky"] >= 0).all() and (out["local"] >= 0).all()
    assert torch.allclose(torch.expm1(out["local_log"]), out["local"])
    assert out["warped_mask"].sum() > 0


@pytest.mark.parametrize("b", [1, 4])
def test_lenet_reg_shapes(b):
    out = LENetReg(preset("tiny")).eval()(torch.rand(b, 3, 240, 320))
    assert out["sky"].shape == (b, 3, 128, 256) and out["sky"].dtype == torch.float32


@pytest.mark.parametrize("name", ["full", "col+sh", "lenet_reg"])
def test_gradients_reach_every_parameter(name):
    torch.manual_seed(1)
    cfg = preset("tiny", image_size=(60, 80), pano_height=32)
    model = build_baseline(name, cfg)
    batch = _batch(cfg, 2)
    if isinstance(model, LENetReg):
        out = model(batch["image"])
    else:
        out = model(batch["image"], batch["K"], batch["pixels"], batch["pitch"], batch["roll"])
    losses = solidnet_losses(out, batch)
    losses["total"].backward()
    # the sun logits' 1x1-convolution bias shifts every logit alike: the softmax-based sun losses are
    # invariant to it, so its gradient is zero up to rounding
    shift_invariant = {"inet.sun.fine.bias"}
    missing = [
        n
        for n, p in model.named_parameters()
        if n not in shift_invariant and (p.grad is None or not torch.isfinite(p.grad).all() or p.grad.abs().sum() == 0)
    ]
    assert not missing, missing
    expected = (
        {"sky"}
        if name == "lenet_reg"
        else {"albedo", "normal", "distance", "shadow", "sky", "dif", "rec", "local", "tom"}
    )
    assert expected <= set(losses)


def test_baselines_have_the_papers_pnet_inputs():
    assert set(BASELINES) == {"lenet_reg", "col", "col+sha", "col+sh", "col+sky", "full"}
    chans = {n: build_baseline(n, "tiny").pnet.in_channels for n in BASELINES if n != "lenet_reg"}
    assert chans == {"col": 4, "col+sha": 5, "col+sh": 7, "col+sky": 7, "full": 8}
    with pytest.raises(ConfigError):
        build_baseline("nope")


def test_config_validation_and_round_trip():
    cfg = preset("paper")
    assert SolidNetConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError):
        preset("small", pnet_inputs=("sky",))
    with pytest.raises(ConfigError):
        preset("small", pano_height=100)
    with pytest.raises(ConfigError):
        SolidNetConfig.from_dict({**cfg.to_dict(), "bogus": 1})


def test_flip_pad_mirrors_around_the_placed_copy():
    x = torch.arange(6.0).view(1, 1, 2, 3)
    out = flip_pad(x, (4, 9), 1, 3)
    assert torch.equal(out[0, 0, 1:3, 3:6], x[0, 0])
    assert torch.equal(out[0, 0, 1:3, 0:3], x[0, 0].flip(-1))  # left neighbour is the flipped copy
    assert torch.equal(out[0, 0, 1:3, 6:9], x[0, 0].flip(-1))
    assert torch.equal(out[0, 0, 0], out[0, 0, 1]) and torch.equal(out[0, 0, 3], out[0, 0, 2])


def test_small_model_overfits_one_sample():
    """Tiny widths at reduced resolution, the paper's losses; ~80 Adam steps, about 15 s on one shared core."""
    torch.manual_seed(0)
    cfg = preset("tiny-paper", image_size=(60, 80), pano_height=32)
    model = SolidNet(cfg)
    batch = _batch(cfg, 1)
    history = fit(model, batch, steps=80, lr=2e-2)
    first, last = history[0]["total"], min(h["total"] for h in history[-5:])
    assert first / last >= 10.0, (first, last)
    # every term of L_I and L_P took part
    assert {"albedo", "normal", "distance", "shadow", "sky", "dif", "rec", "local", "tom"} <= set(history[0])
