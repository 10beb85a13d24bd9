"""The sun in the image: sun-like blobs, the network's sun put on one, calibrated cones, the crop protocol."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from solidkit.envmap.coords import (
    angles_from_direction,
    angular_distance,
    coords_from_direction,
    direction_from_angles,
    wrap_angle,
)
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.model import suneval
from solidkit.model.imagesun import image_sun_blobs, put_sun_on_blob
from solidkit.model.sununcertainty import calibrate_cone_scales, cone_radii, conformal_quantile, coverage
from solidkit.synth.panocrops import CatalogSun, Source

W, H = 320, 240
K = intrinsics_from_fov(math.radians(60.0), W, H)


def _image_with_disc(cx: float, cy: float, r: float) -> np.ndarray:
    img = np.full((H, W, 3), 0.55, np.float32)
    yy, xx = np.mgrid[:H, :W]
    img[(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r] = 1.0
    return img


def test_a_clipped_disc_is_found_at_its_ray_and_strips_and_sparkles_are_not():
    img = _image_with_disc(200.0, 60.0, 8.0)
    img[200:203, :] = 1.0  # a clipped strip (a roofline of sky): not compact
    img[30, 30] = img[30, 31] = 1.0  # a sparkle: two pixels
    blobs = image_sun_blobs(img, K, 0.0, 0.0)
    assert len(blobs) == 1
    ray = np.linalg.inv(K) @ np.array([200.0, 60.0, 1.0])
    assert math.degrees(float(angular_distance(blobs[0].direction, ray / np.linalg.norm(ray)))) < 0.3
    # the camera's pitch turns the blob's direction into the level frame: 10° up raises it by 10°
    up = image_sun_blobs(img, K, math.radians(10.0), 0.0)[0]
    assert math.degrees(
        float(angles_from_direction(up.direction)[1] - angles_from_direction(blobs[0].direction)[1])
    ) == pytest.approx(10.0, abs=0.5)


def test_the_network_sun_moves_onto_a_blob_only_when_it_says_sun_and_agrees():
    img = torch.as_tensor(_image_with_disc(160.0, 50.0, 7.0)).permute(2, 0, 1)[None].repeat(3, 1, 1, 1)
    Kt = torch.as_tensor(K, dtype=torch.float32)[None].repeat(3, 1, 1)
    z = torch.zeros(3)
    blob = image_sun_blobs(img[0].permute(1, 2, 0).numpy(), K, 0.0, 0.0)[0].direction
    near = torch.as_tensor(direction_from_angles(math.radians(20.0), math.radians(20.0)), dtype=torch.float32)
    behind = torch.as_tensor(direction_from_angles(math.radians(170.0), math.radians(20.0)), dtype=torch.float32)
    dirs = torch.stack([near, behind, near])
    vis = torch.tensor([0.9, 0.9, 0.1])
    out, on, promoted = put_sun_on_blob(dirs, vis, img, Kt, z, z, threshold=0.5)
    assert not promoted.any()
    assert on.tolist() == [True, False, False]
    assert math.degrees(float(angular_distance(out[0].double(), torch.as_tensor(blob).double()))) < 1e-4
    assert torch.equal(out[1:], dirs[1:])
    # a distribution that finds the blob as likely as its mode moves even a far soft-argmax onto it
    logits = torch.zeros(3, 1, 64, 128)
    x, y = coords_from_direction(blob.astype(np.float64), 64)
    logits[1, 0, int(y), int(x)] = 5.0
    _, on, _ = put_sun_on_blob(dirs, vis, img, Kt, z, z, threshold=0.5, logits=logits)
    assert on.tolist() == [True, True, False]


def test_a_blob_makes_an_unlikely_sun_visible_only_from_the_promote_level():
    img = torch.as_tensor(_image_with_disc(160.0, 50.0, 7.0)).permute(2, 0, 1)[None].repeat(3, 1, 1, 1)
    img[2] = torch.as_tensor(_image_with_disc(160.0, 50.0, 0.0)).permute(2, 0, 1)  # no blob
    Kt = torch.as_tensor(K, dtype=torch.float32)[None].repeat(3, 1, 1)
    z = torch.zeros(3)
    blob = image_sun_blobs(img[0].permute(1, 2, 0).numpy(), K, 0.0, 0.0)[0].direction
    behind = torch.as_tensor(direction_from_angles(math.radians(170.0), math.radians(20.0)), dtype=torch.float32)
    dirs = behind[None].repeat(3, 1)
    vis = torch.tensor([0.2, 0.05, 0.2])
    out, on, promoted = put_sun_on_blob(dirs, vis, img, Kt, z, z, threshold=0.5, promote=0.1)
    assert promoted.tolist() == [True, False, False] and on.tolist() == [True, False, False]
    assert math.degrees(float(angular_distance(out[0].double(), torch.as_tensor(blob).double()))) < 1e-4
    _, on, promoted = put_sun_on_blob(dirs, vis, img, Kt, z, z, threshold=0.5)
    assert not promoted.any() and not on.any()
    two = torch.as_tensor(np.maximum(_image_with_disc(160.0, 50.0, 7.0), _image_with_disc(60.0, 150.0, 7.0)))
    assert len(image_sun_blobs(two.numpy(), K, 0.0, 0.0)) == 2
    _, on, promoted = put_sun_on_blob(
        dirs[:1], vis[:1], two.permute(2, 0, 1)[None], Kt[:1], z[:1], z[:1], 0.5, promote=0.1
    )
    assert not promoted.any()  # two "suns": lamps or a canopy, not a sun


def test_cone_radii_grow_with_the_spread_and_hold_their_mass():
    h = 64
    from solidkit.envmap.coords import direction_grid

    grid = torch.as_tensor(direction_grid(h), dtype=torch.float32)
    d = torch.as_tensor(direction_from_angles(0.3, 0.4), dtype=torch.float32)
    radii = []
    for sigma_deg in (4.0, 12.0):
        cos = grid @ d
        logits = ((cos - 1.0) / math.radians(sigma_deg) ** 2)[None, None]
        r = cone_radii(logits, d[None])[0]
        assert r[0] < r[1]
        radii.append(r)
    assert radii[1][0] > 2.0 * radii[0][0]
    # a 2-D Gaussian of sigma holds 68 % within 1.51 sigma and 90 % within 2.15 sigma
    assert float(radii[1][0]) == pytest.approx(1.51 * 12.0, rel=0.15)
    assert float(radii[1][1]) == pytest.approx(2.15 * 12.0, rel=0.15)


def test_conformal_scales_cover_new_draws_at_the_stated_rate():
    rng = np.random.default_rng(0)
    radii = rng.uniform(5.0, 30.0, (2000, 2)) * np.array([1.0, 1.6])
    errors = radii[:, 0] * np.abs(rng.normal(0.0, 1.3, 2000))  # over-confident radii
    scales = calibrate_cone_scales(errors[:1000], radii[:1000])
    cov = coverage(errors[1000:], radii[1000:] * np.asarray(scales))
    assert abs(cov[0] - 0.68) < 0.04 and abs(cov[1] - 0.90) < 0.03
    assert conformal_quantile(np.arange(3.0), 0.9) == math.inf


def test_weighted_conformal_scales_let_each_domain_count_equally():
    rng = np.random.default_rng(1)
    scores = rng.uniform(0.0, 1.0, 50)
    assert conformal_quantile(scores, 0.68, np.full(50, 0.3)) == conformal_quantile(scores, 0.68)
    assert conformal_quantile(scores, 0.9, np.full(50, 2.0)) == conformal_quantile(scores, 0.9)
    # many well-predicted rendered crops, a few badly predicted real ones: pooled cones miss the real domain
    radii = np.full((440, 2), 10.0) * np.array([1.0, 1.6])
    err = np.concatenate([10.0 * np.abs(rng.normal(0, 0.8, 400)), 10.0 * np.abs(rng.normal(0, 2.5, 40))])
    real = np.arange(440) >= 400
    w = np.where(real, 1.0 / 40, 1.0 / 400)
    pooled = np.asarray(calibrate_cone_scales(err, radii))
    balanced = np.asarray(calibrate_cone_scales(err, radii, weights=w))
    assert (balanced > pooled).all()
    cov_real = coverage(err[real], radii[real] * balanced)
    cov_pooled = coverage(err[real], radii[real] * pooled)
    assert cov_real[0] > cov_pooled[0] + 0.05
    with pytest.raises(ValueError):
        conformal_quantile(scores, 0.5, np.zeros(50))


def _sunny_source(az_deg: float, el_deg: float) -> Source:
    h = 128
    pano = np.full((h, 2 * h, 3), 0.3, np.float32)
    pano[h // 2 :] = 0.08
    d = np.asarray(direction_from_angles(math.radians(az_deg), math.radians(el_deg)))
    x, y = coords_from_direction(d, h)
    pano[int(y) - 1 : int(y) + 2, int(x) - 1 : int(x) + 2] = 2.0e4
    light = pano[::1]
    return Source("sunny", "real", None, pano, light, CatalogSun(True, d.astype(np.float32)))


def test_the_protocol_puts_the_sun_where_asked_and_the_baselines_read_it():
    crops = suneval.protocol_crops([_sunny_source(40.0, 12.0)], size=(120, 160))
    assert [c.relative_azimuth_deg for c in crops] == list(suneval.RELATIVE_AZIMUTHS_DEG)
    for c in crops:
        az = math.degrees(float(angles_from_direction(c.sun)[0]))
        assert wrap_angle(az - c.relative_azimuth_deg, 360.0) == pytest.approx(0.0, abs=1e-3)
    assert [c.in_view for c in crops] == [True, True, True, False, False, False]
    f = suneval.sun_figures(crops, suneval.predict_brightest_column(crops))
    assert f["suns"] == 6 and f["found"] == 6 and f["in_view_n"] == 3
    assert f["in_view_max_deg"] < 10.0  # elevation is fixed at 20°, the sun is at 12°
    const = suneval.sun_figures(crops, suneval.predict_constant(crops))
    assert const["behind_deg"] > 100.0


def test_calibration_picks_settings_from_its_grids_and_leaves_the_model_as_it_was():
    from solidkit.model.config import preset
    from solidkit.model.solidnet import SolidNet

    torch.manual_seed(0)
    model = SolidNet(preset("small-sun")).eval()
    before = model.config
    srcs = [_sunny_source(az, 15.0) for az in (0.0, 90.0)]
    grey = Source(
        "grey",
        "real",
        None,
        np.full((128, 256, 3), 0.3, np.float32),
        np.full((128, 256, 3), 0.3, np.float32),
        CatalogSun(False, np.zeros(3, np.float32)),
    )
    domains = {
        "a": suneval.protocol_crops(srcs + [grey], size=(120, 160)),
        "b": suneval.protocol_crops(srcs[:1] + [grey], size=(120, 160)),
    }
    cal = suneval.calibrate_sun(model, domains)
    assert 0.05 <= cal["threshold"] <= 0.99 and 0.0 <= cal["balanced_accuracy"] <= 1.0
    assert cal["gate_deg"] in suneval.GATE_GRID_DEG or not cal["sun_in_image"]
    assert len(cal["trials"]) == 1 + len(suneval.GATE_GRID_DEG)
    assert cal["n"]["a"] == {"crops": 18, "suns": 12}
    assert model.config == before and model.inet.config == before
