"""The camera's side of I-Net's inputs: metered exposure of crops and photos, the sky-feature footprint
from the camera's field of view, pitch and roll, and the tuned sun-visibility threshold."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from solidkit.envmap import coords_from_angles, tonemap
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.errors import InputError
from solidkit.model import SolidNet
from solidkit.model.config import SolidNetConfig, preset
from solidkit.model.inet import camera_footprint_grid, flip_pad, image_footprint
from solidkit.model.trainer import best_visibility_threshold, set_visibility_threshold
from solidkit.synth.panocrops import CropConfig, CropSampler, Source, metered_gain

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _scene(height: int, scale: float = 1.0) -> np.ndarray:
    """Grey ground, a bluish sky brightening upward and a bright patch (the sun), times ``scale``."""
    from solidkit.envmap import direction_grid

    up = -direction_grid(height)[..., 1]
    sky = np.stack([0.3 + 0.3 * up, 0.5 + 0.4 * up, 0.9 + 0.5 * up], -1)
    img = np.where(up[..., None] > 0, sky, 0.05).astype(np.float32)
    img[height // 4 : height // 4 + 2, height // 3 : height // 3 + 2] = 5.0e3
    return img * np.float32(scale)


def test_metered_gain_brings_the_log_average_to_the_key_and_ignores_a_sun():
    rng = np.random.default_rng(0)
    view = rng.uniform(0.001, 0.02, (240, 320, 3)).astype(np.float32)
    from solidkit.envmap.sun import luminance

    g = metered_gain(view, 0.18)
    logavg = math.exp(float(np.mean(np.log(1e-4 + luminance(view * g)))))
    assert logavg == pytest.approx(0.18, rel=0.05)
    with_sun = view.copy()
    with_sun[100:102, 100:102] = 3.0e4  # four pixels of sun
    assert metered_gain(with_sun, 0.18) == pytest.approx(g, rel=0.01)
    assert metered_gain(np.zeros((8, 8, 3), np.float32), 0.18) == 2.0**10  # black: clipped, finite


def test_metered_crops_do_not_depend_on_the_stored_hdr_scale():
    # a source stored 16x darker gives the same image and the same target: the scale is the camera's
    light = _scene(64)
    a = CropSampler([Source("a", "real", None, _scene(256), light)], seed=3, config=CropConfig(exposure_key=0.18))
    b = CropSampler(
        [Source("b", "real", None, _scene(256, 1 / 16), light / 16)], seed=3, config=CropConfig(exposure_key=0.18)
    )
    fixed = CropSampler([Source("c", "real", None, _scene(256, 1 / 16), light / 16)], seed=3)
    for i in range(3):
        x, y, z = a(i), b(i), fixed(i)
        # equal up to the meter's 1e-4 floor inside the log (the darkened ground is 0.003)
        assert np.allclose(x["image"], y["image"], atol=1e-2)
        assert np.allclose(x["sky"], y["sky"], rtol=2e-2, atol=1e-6)
        assert y["gain"] == pytest.approx(16 * x["gain"], rel=2e-2)
        assert z["image"].mean() < 0.6 * y["image"].mean()  # the unmetered dark source stays dark


def _deg_at(grid: torch.Tensor, az: float, el: float, height: int) -> list[float]:
    x, y = coords_from_angles(math.radians(az), math.radians(el), height)
    return grid[int(y), int(x)].tolist()


def test_camera_footprint_follows_pitch_roll_and_field_of_view():
    H = 128
    K = torch.as_tensor(intrinsics_from_fov(math.radians(60.0), 320, 240), dtype=torch.float64)[None]
    z = torch.zeros(1, dtype=torch.float64)
    pitch = torch.tensor([math.radians(12.0)], dtype=torch.float64)
    g = camera_footprint_grid(H, K, pitch, z, (240, 320))[0]
    # the image centre looks 12 deg up; 20 deg to the right is 2/3 of the half width; up is the image top
    assert _deg_at(g, 0.0, 12.0, H) == pytest.approx([0.0, 0.0], abs=0.05)
    assert _deg_at(g, 20.0, 12.0, H)[0] == pytest.approx(20 / 30, abs=0.05)
    assert _deg_at(g, 0.0, 22.0, H)[1] < -0.3
    # a wider lens (hfov 90) puts the same direction nearer the image centre
    K90 = torch.as_tensor(intrinsics_from_fov(math.radians(90.0), 320, 240), dtype=torch.float64)[None]
    g90 = camera_footprint_grid(H, K90, pitch, z, (240, 320))[0]
    assert _deg_at(g90, 20.0, 12.0, H)[0] == pytest.approx(20 / 45, abs=0.05)
    # roll > 0 turns the right axis down: a horizon point to the right appears above the image centre
    roll = torch.tensor([math.radians(10.0)], dtype=torch.float64)
    assert _deg_at(camera_footprint_grid(H, K, z, roll, (240, 320))[0], 20.0, 0.0, H)[1] < -0.05
    # everything lands inside the image (mirror tiling), and a level camera gives the "level" box
    assert g.abs().max() <= 1.0 + 1e-9
    feats = torch.stack(torch.meshgrid(torch.linspace(-1, 1, 30), torch.linspace(-1, 1, 40), indexing="ij"))[None]
    cam = F.grid_sample(
        feats.double(), camera_footprint_grid(H, K, z, z, (240, 320)), align_corners=False, padding_mode="border"
    )
    cfg = preset("small")
    fh, fw, top, left = image_footprint(H, 60.0, cfg.vfov_deg)
    level = flip_pad(F.interpolate(feats, size=(fh, fw), mode="bilinear", align_corners=False), (H, 2 * H), top, left)
    assert float((cam.float() - level).abs().mean()) < 0.05


def test_sky_footprint_camera_uses_the_pitch_and_level_ignores_it():
    torch.manual_seed(0)
    image = torch.rand(1, 3, 60, 80)
    K = torch.as_tensor(intrinsics_from_fov(math.radians(60.0), 80, 60), dtype=torch.float32)[None]
    for footprint, differs in (("camera", True), ("level", False)):
        net = SolidNet(preset("tiny", image_size=(60, 80), pano_height=32, sky_footprint=footprint)).eval()
        with torch.no_grad():
            a = net.inet(image, intrinsics=False, K=K, pitch=torch.zeros(1), roll=torch.zeros(1))["sky_np_log"]
            b = net.inet(image, intrinsics=False, K=K, pitch=torch.tensor([0.25]), roll=torch.zeros(1))["sky_np_log"]
        assert (not torch.allclose(a, b)) == differs, footprint


def test_old_configs_keep_their_exposure_footprint_and_threshold():
    d = preset("small").to_dict()
    for k in ("exposure_key", "sky_footprint", "sun_visibility_threshold"):
        d.pop(k)
    old = SolidNetConfig.from_dict(d)
    assert (old.exposure_key, old.sky_footprint, old.sun_visibility_threshold) == (0.0, "level", 0.5)
    assert preset("small").sky_footprint == preset("small-paper").sky_footprint == "camera"
    with pytest.raises(Exception, match="sky_footprint"):
        preset("small", sky_footprint="tilted")


def test_visibility_threshold_is_tuned_stored_and_used(tmp_path):
    p = np.array([0.9, 0.8, 0.7, 0.65, 0.6, 0.3, 0.2, 0.1])
    t = np.array([1, 1, 1, 1, 0, 0, 0, 0], bool)
    r = best_visibility_threshold(p, t)
    assert 0.6 < r["threshold"] <= 0.65 and r["balanced_accuracy"] == 1.0 and r["balanced_accuracy_at_0.5"] == 0.875
    with pytest.raises(InputError):
        best_visibility_threshold(p, np.ones(8, bool))
    net = SolidNet(preset("tiny", image_size=(60, 80), pano_height=32)).eval()
    with torch.no_grad():
        net.inet.sun.visible.weight.zero_()
        net.inet.sun.visible.bias.fill_(math.log(0.7 / 0.3))  # p = 0.7 for every image
    image = torch.rand(1, 3, 60, 80)
    with torch.no_grad():
        at_half = net.inet(image, intrinsics=False)
    set_visibility_threshold(net, 0.8)
    net.save(tmp_path / "m.pt")
    back = SolidNet.from_checkpoint(tmp_path / "m.pt").eval()
    assert back.config.sun_visibility_threshold == 0.8
    with torch.no_grad():
        at_08 = back.inet(image, intrinsics=False)
    assert float(at_half["sky"].amax()) > 10 * float(at_08["sky"].amax())  # the sun is gone at 0.8
    assert torch.allclose(at_08["sky"], torch.expm1(at_08["sky_np_log"]), atol=1e-5)


def test_predict_reexposes_a_photo_and_returns_its_own_units():
    torch.manual_seed(2)
    net = SolidNet(preset("tiny", image_size=(60, 80), pano_height=32)).eval()
    rng = np.random.default_rng(1)
    hdr = rng.uniform(0.1, 0.5, (60, 80, 3)).astype(np.float32)
    bright = np.asarray(tonemap(hdr))
    dark = np.asarray(tonemap(hdr / 8.0))
    a = net.predict(bright, [(40, 30)], encoding="paper")
    b = net.predict(dark, [(40, 30)], encoding="paper")
    assert b.extra["exposure_gain"] == pytest.approx(8 * a.extra["exposure_gain"], rel=1e-2)
    # the same re-exposed input (up to the meter's floor): the prediction scales with the photo
    assert np.allclose(b.sky * 8.0, a.sky, rtol=2e-2, atol=1e-6)
    fixed = SolidNet(preset("tiny", image_size=(60, 80), pano_height=32, exposure_key=0.0)).eval()
    assert fixed.predict(dark, [(40, 30)], encoding="paper").extra["exposure_gain"] == 1.0


def test_predict_linearises_a_camera_photo_by_its_encoding_or_its_response():
    """A camera JPEG is sRGB: decoded by the paper's 2.2 power instead, a photo and one 3 stops darker
    are not 8x apart; a calibrated response curve is used as given."""
    from solidkit.envmap.io import srgb_decode, srgb_encode

    torch.manual_seed(2)
    net = SolidNet(preset("tiny", image_size=(60, 80), pano_height=32)).eval()
    hdr = np.random.default_rng(1).uniform(0.02, 0.6, (60, 80, 3)).astype(np.float32)
    bright, dark = np.asarray(srgb_encode(hdr)), np.asarray(srgb_encode(hdr / 8.0))
    ratio = {
        enc: net.predict(dark, [(40, 30)], encoding=enc).extra["exposure_gain"]
        / net.predict(bright, [(40, 30)], encoding=enc).extra["exposure_gain"]
        for enc in ("srgb", "paper")
    }
    assert ratio["srgb"] == pytest.approx(8.0, rel=0.02)
    assert abs(ratio["paper"] - 8.0) > 0.5
    curve = np.repeat(np.asarray(srgb_decode(np.arange(256) / 255.0), np.float32)[:, None], 3, axis=1)
    photo = np.round(bright * 255) / 255
    by_curve = net.predict(photo, [(40, 30)], encoding=curve)
    by_name = net.predict(photo, [(40, 30)], encoding="srgb")
    assert np.allclose(by_curve.sky, by_name.sky, rtol=1e-4, atol=1e-6)
    with pytest.raises(InputError, match="unknown LDR encoding"):
        net.predict(photo, [(40, 30)], encoding="gamma")
