"""The low-resolution sun network (``model/sunnet.py``), its crops (``model/suncrops.py``) and the ``sun``
training stage: geometry against analytic cases, targets against the crop path's detector, an overfitting
proof, and a stage that trains the sun network alone and leaves it frozen afterwards."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from solidkit.envmap import angular_distance, detect_sun, direction_from_angles
from solidkit.envmap.coords import angles_from_direction, rotation_from_ypr, rotation_y
from solidkit.envmap.perspective import intrinsics_from_fov, project_to_pixels
from solidkit.envmap.resample import rotate
from solidkit.model.config import ConfigError, preset
from solidkit.model.losses import sun_terms
from solidkit.model.suncrops import CROP_SIZE, SunCropBank
from solidkit.model.sunhead import render_sun
from solidkit.model.sunnet import SunNet, image_grid_on_panorama, ray_directions
from solidkit.synth.panocrops import CropConfig, Source

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _sky(height: int, az_deg: float, el_deg: float, energy: float = 2.0) -> np.ndarray:
    """Gradient sky, grey ground, a sun of ``energy`` at ``(az, el)`` and a bright wall facing it (a hidden-sun cue)."""
    from solidkit.envmap import direction_grid

    d = direction_grid(height)
    up = -d[..., 1]
    sky = np.stack([0.4 + 0.3 * up, 0.6 + 0.4 * up, 1.0 + 0.5 * up], -1)
    sun_dir = np.asarray(direction_from_angles(math.radians(az_deg), math.radians(el_deg)))
    lit = 0.25 + 0.6 * np.clip(d @ sun_dir, 0.0, None)
    pano = np.where(up[..., None] > 0, sky, lit[..., None]).astype(np.float32)
    sun = render_sun(
        torch.as_tensor(sun_dir, dtype=torch.float32)[None],
        torch.full((1, 3), energy),
        torch.tensor([math.radians(0.3)]),
        height,
    )[0]
    return pano + sun.permute(1, 2, 0).numpy()


def _camera(b: int, hfov_deg: float, size: tuple[int, int], pitch: float = 0.0, roll: float = 0.0):
    K = torch.as_tensor(intrinsics_from_fov(math.radians(hfov_deg), size[1], size[0]), dtype=torch.float32)
    return K.expand(b, 3, 3), torch.full((b,), pitch), torch.full((b,), roll)


def test_ray_directions_match_the_crop_geometry():
    K, pitch, roll = _camera(1, 90.0, (6, 8), pitch=math.radians(10.0), roll=math.radians(-3.0))
    rays = ray_directions(K, pitch, roll, (6, 8))[0].permute(1, 2, 0).numpy()
    R = np.asarray(rotation_from_ypr(0.0, math.radians(10.0), math.radians(-3.0)))
    from solidkit.envmap.perspective import pixel_rays

    want = pixel_rays(K[0].numpy(), 8, 6) @ R.T
    want /= np.linalg.norm(want, axis=-1, keepdims=True)
    assert np.allclose(rays, want, atol=1e-5)
    assert np.allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-5)


def test_image_grid_puts_each_panorama_direction_on_its_pixel():
    pitch, roll = math.radians(8.0), math.radians(2.0)
    K, p, r = _camera(1, 60.0, (48, 64), pitch, roll)
    grid, inside = image_grid_on_panorama(32, K, p, r, (48, 64))
    assert grid.shape == (1, 32, 64, 2) and inside.shape == (1, 1, 32, 64)
    # the forward direction at the camera's pitch lands at the image centre; the back of the sphere is outside
    from solidkit.envmap import direction_grid

    dirs = direction_grid(32)
    cam = dirs @ np.asarray(rotation_from_ypr(0.0, pitch, roll))
    x, y, front = project_to_pixels(K[0].numpy(), cam)
    want_in = front & (x > -0.5) & (x < 63.5) & (y > -0.5) & (y < 47.5)
    assert (inside[0, 0].numpy() > 0.5).sum() == pytest.approx(want_in.sum(), abs=4)
    i, j = np.argwhere(want_in)[len(np.argwhere(want_in)) // 2]
    gx, gy = grid[0, i, j].tolist()
    assert (gx + 1) * 32 - 0.5 == pytest.approx(x[i, j], abs=1e-3) and (gy + 1) * 24 - 0.5 == pytest.approx(
        y[i, j], abs=1e-3
    )
    assert inside[0, 0, :, :10].sum() == 0  # azimuth near -180°: behind the camera


def test_sun_net_outputs_and_config_errors():
    net = SunNet((4, 8, 8), size=(24, 32), logit_height=16, coarse_height=8, hidden=16)
    K, p, r = _camera(2, 60.0, (48, 64))
    out = net(torch.rand(2, 3, 48, 64), K, p, r)
    assert out["sun_logits"].shape == (2, 1, 16, 32) and out["sun_dir"].shape == (2, 3)
    assert torch.allclose(out["sun_dir"].norm(dim=-1), torch.ones(2), atol=1e-5)
    assert out["sun_visible"].shape == (2,) and out["sun_energy"].shape == (2, 3)
    with pytest.raises(ConfigError, match="sun_net needs"):
        preset("tiny", sun_net=(4, 8))
    cfg = preset("small", sun_net=(4, 8, 8), sun_net_size=(24, 32))
    from solidkit.model import SolidNet

    model = SolidNet(cfg).eval()
    with torch.no_grad():
        o = model.inet(torch.rand(1, 3, 240, 320), intrinsics=False)
    assert (
        isinstance(model.inet.sun, SunNet)
        and o["sky"].shape == (1, 3, 128, 256)
        and o["sun_logits"].shape[-2:] == (64, 128)
    )


def _bank(*suns: tuple[float, float], scale: float = 1.0) -> SunCropBank:
    bank = SunCropBank(height=64)
    for k, (az, el) in enumerate(suns):
        bank.add(f"s{k}", Source(f"s{k}", "real", None, scale * _sky(128, az, el), scale * _sky(64, az, el)))
    return bank


def test_bank_targets_are_those_of_the_crop_path():
    """The sun of a bank crop is the detector's sun of the lighting turned by the crop's yaw (and mirrored by its
    flip), as CropSampler's targets are; in view, it is where the crop's brightest pixel is."""
    bank = _bank((40.0, 30.0), (-120.0, 12.0), scale=0.1)
    cfg = CropConfig(width=CROP_SIZE[1], height=CROP_SIZE[0], exposure_stops=(0.0, 0.0), white_balance=0.0)
    seen_in_view, flips = 0, set()
    for i in range(60):
        it = bank.crop(np.random.default_rng(i), cfg)
        src = _sky(64, *((40.0, 30.0) if it["source"] == "s0" else (-120.0, 12.0)))
        sky = np.asarray(rotate(src, np.asarray(rotation_y(float(it["yaw"]))).T))
        if it["flip"]:
            sky = np.ascontiguousarray(sky[:, ::-1])
        flips.add(it["flip"])
        assert math.degrees(float(angular_distance(it["sun_dir"], detect_sun(sky).direction))) < 1.0
        assert it["sun_visible"] == 1.0
        R = np.asarray(rotation_from_ypr(0.0, float(it["pitch"]), float(it["roll"])))
        x, y, front = project_to_pixels(it["K"], it["sun_dir"] @ R)
        if front and 30 < x < CROP_SIZE[1] - 31 and 30 < y < CROP_SIZE[0] - 31:
            seen_in_view += 1
            yy, xx = np.nonzero(it["image"].min(-1) >= 1.0)  # the sun's saturated blob, in a sky that is not
            assert 0 < len(xx) < 2000 and abs(xx.mean() - x) < 1.5 and abs(yy.mean() - y) < 1.5
    assert flips == {True, False}
    assert seen_in_view >= 1
    a, b = bank.batch(3, 7, 4, cfg), bank.batch(3, 7, 4, cfg)
    assert all(torch.equal(a[k], b[k]) for k in a) and a["image"].shape == (4, 3, *CROP_SIZE)


def test_overfitting_eight_crops_finds_each_sun_even_behind_the_camera():
    bank = _bank((40.0, 30.0), (-120.0, 12.0), (170.0, 45.0), (-60.0, 20.0))
    cfg = CropConfig(
        width=CROP_SIZE[1], height=CROP_SIZE[0], exposure_key=0.18, exposure_stops=(0.0, 0.0), white_balance=0.0
    )
    batch = bank.batch(1, 0, 8, cfg)
    torch.manual_seed(0)
    net = SunNet((8, 16, 32), size=(48, 64), logit_height=32, coarse_height=8, hidden=64)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(250):
        out = net(batch["image"], batch["K"], batch["pitch"], batch["roll"])
        loss = sum(
            sun_terms(
                out, batch["sun_dir"], batch["sun_visible"], batch["sun_energy"], batch["sun_size"], math.radians(4.0)
            ).values()
        )
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        out = net(batch["image"], batch["K"], batch["pitch"], batch["roll"])
    err = torch.rad2deg(torch.arccos((out["sun_dir"] * batch["sun_dir"]).sum(-1).clamp(-1, 1)))
    az = torch.rad2deg(angles_from_direction(batch["sun_dir"])[0]).abs()
    assert (az > 90).any(), "the test needs a sun behind a camera"
    assert float(err.max()) < 5.0, err
    ratio = out["sun_energy"].mean(-1) / batch["sun_energy"].mean(-1)
    assert bool(((ratio > 0.5) & (ratio < 2.0)).all()), ratio


def test_sun_stage_trains_the_sun_net_alone_and_inet_leaves_it_frozen(tmp_path, write_sources):
    root = write_sources(
        tmp_path / "sources", [(_sky(256, az, el), _sky(128, az, el)) for az, el in ((30.0, 40.0), (-100.0, 20.0))]
    )
    conf = tmp_path / "run.toml"
    conf.write_text(
        "\n".join(
            [
                f'out = "{tmp_path / "run"}"',
                'model = "tiny"',
                "model_overrides = {sun_head = true, sun_visibility = true, "
                'loss_variant = "located", sun_net = [4, 8, 8], sun_net_size = [24, 32]}',
                f'crops = ["{root}"]',
                f'val_crops = ["{root}"]',
                "val_samples = 4",
                "val_every = 2",
                "log_every = 1",
                "checkpoint_every = 1",
                "[sun]",
                "steps = 3",
                "batch_size = 4",
                "[inet]",
                "steps = 2",
                "batch_size = 2",
            ]
        )
        + "\n"
    )
    from solidkit.model.trainer import Trainer, load_train_config

    tr = Trainer(load_train_config(conf), progress=False)
    before = {k: v.clone() for k, v in tr.model.state_dict().items()}
    tr.run()
    after = tr.model.state_dict()
    sun_keys = [k for k in after if k.startswith("inet.sun.")]
    other = [k for k in after if k.startswith("inet.") and not k.startswith("inet.sun.") and "norm" not in k]
    assert sun_keys and any(not torch.equal(before[k], after[k]) for k in sun_keys)
    assert any(not torch.equal(before[k], after[k]) for k in other)  # I-Net trained in its own stage
    rows = (tmp_path / "run" / "metrics.csv").read_text().splitlines()
    assert any(r.split(",")[1] == "sun" and ",val," in r for r in rows) and (tmp_path / "run" / "best_sun.pt").is_file()
    # the sun net after both stages is the one the sun stage left: the inet stage froze it
    tr2 = Trainer(load_train_config(conf), progress=False)
    tr2.cfg.inet.steps = 0
    tr2.cfg.out = str(tmp_path / "run2")
    tr2.out = tmp_path / "run2"
    tr2.run()
    assert all(torch.equal(after[k], tr2.model.state_dict()[k]) for k in sun_keys)
