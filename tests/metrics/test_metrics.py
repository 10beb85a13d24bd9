"""The evaluation metrics on hand-made cases (solidkit.metrics)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit import metrics as M
from solidkit.envmap.coords import direction_from_angles, direction_grid, rotation_from_ypr
from solidkit.envmap.resample import rotate
from solidkit.metrics.stats import _cluster_bootstrap

H = 64


def _sky(az_deg: float, el_deg: float, height: int = H) -> np.ndarray:
    """A sky with a bright, compact sun at (az, el) over a smooth gradient (linear radiance)."""
    d = direction_grid(height)
    sun = direction_from_angles(math.radians(az_deg), math.radians(el_deg))
    cos = d @ np.asarray(sun)
    up = np.clip(-d[..., 1], 0, None)
    sky = 0.5 + 0.5 * up + 3.0 * np.exp((cos - 1) / 0.02)  # a broad halo
    sky = sky + 5e3 * (cos > math.cos(math.radians(2.5)))  # the disk
    return np.repeat(sky[..., None], 3, axis=2).astype(np.float32) * np.array([0.8, 0.9, 1.0], np.float32)


@pytest.mark.parametrize("method", M.SUN_METHODS)
def test_sky_rotated_by_30_degrees_gives_30_degree_azimuth_error(method):
    truth = _sky(-40.0, 30.0)
    pred = rotate(truth, rotation_from_ypr(math.radians(30.0)))
    t = M.find_sun(truth, method)
    p = M.find_sun(pred, method)
    assert t.found and p.found
    true_sun = direction_from_angles(math.radians(-40.0), math.radians(30.0))
    err = M.sun_error(p.direction, true_sun)
    assert err.azimuth_deg == pytest.approx(30.0, abs=1.0)
    # a turn about the vertical keeps the elevation: only the recipe's own bias on the truth map remains
    assert err.elevation_deg == pytest.approx(M.sun_error(t.direction, true_sun).elevation_deg, abs=0.5)


def test_sun_error_wraps_across_the_seam_and_counts_no_sun():
    a = direction_from_angles(math.radians(175.0), math.radians(10.0))
    b = direction_from_angles(math.radians(-175.0), math.radians(25.0))
    e = M.sun_error(a, b)
    assert e.azimuth_deg == pytest.approx(10.0, abs=1e-6)
    assert e.elevation_deg == pytest.approx(15.0, abs=1e-6)
    stats = M.sun_statistics([e, M.sun_error(None, b), M.sun_error(None, b), e])
    assert stats["no_sun_rate"] == pytest.approx(0.5)
    assert stats["azimuth_deg"]["median"] == pytest.approx(10.0, abs=1e-6)


def test_direction_errors_by_hand_and_alike_in_numpy_and_torch():
    import torch

    # 10 deg up straight ahead against level 170 deg to the right: azimuth gap 170 deg, elevation 10 deg
    up10 = np.array([0.0, -math.sin(math.radians(10)), math.cos(math.radians(10))])
    right170 = np.array([math.sin(math.radians(170)), 0.0, math.cos(math.radians(170))])
    ang, az, el = (math.degrees(float(e)) for e in M.direction_errors(up10, right170))
    assert (az, el) == (pytest.approx(170.0, abs=1e-9), pytest.approx(10.0, abs=1e-9))
    assert ang == pytest.approx(math.degrees(math.acos(float(up10 @ right170))), abs=1e-9)
    # across the seam: -179 deg against +179 deg is 2 deg, and the lengths of the vectors do not matter
    a = 3.0 * np.array([math.sin(math.radians(-179)), 0.0, math.cos(math.radians(-179))])
    b = np.array([math.sin(math.radians(179)), 0.0, math.cos(math.radians(179))])
    assert math.degrees(float(M.direction_errors(a, b)[1])) == pytest.approx(2.0, abs=1e-9)
    batch = np.stack([up10, a]), np.stack([right170, b])
    got_np = M.direction_errors(*batch)
    got_t = M.direction_errors(*(torch.as_tensor(x) for x in batch))
    for n, t in zip(got_np, got_t):
        assert np.allclose(n, t.numpy(), atol=1e-12)


def test_core_detector_says_no_sun_on_an_overcast_map_where_the_paper_recipe_answers():
    d = direction_grid(H)
    overcast = np.repeat((0.6 + 0.4 * np.clip(-d[..., 1], 0, None))[..., None], 3, axis=2).astype(np.float32)
    assert not M.find_sun(overcast, "core").found
    assert M.find_sun(overcast, "paper").found


def test_global_mae_is_zero_for_identical_maps_and_ignores_the_units():
    sky = _sky(10.0, 40.0)
    assert M.global_mae(sky, sky) == 0.0
    assert M.global_mae(sky * 37.0, sky) == pytest.approx(0.0, abs=1e-6)
    assert M.global_mae(rotate(sky, rotation_from_ypr(math.radians(90))), sky) > 0.05


def _probe(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = np.linspace(0.05, 0.6, 2 * H)[None, :, None] * np.linspace(1.0, 0.3, H)[:, None, None]
    return np.clip(base + 0.05 * rng.standard_normal((H, 2 * H, 3)), 0.0, 1.0).astype(np.float32)


def test_identical_probes_give_ssim_1_and_mae_0():
    ldr = np.round(_probe() * 255) / 255
    from solidkit.envmap.io import srgb_decode

    hdr = srgb_decode(ldr) * 123.0  # the same image in other units: the exposure is found
    r = M.local_ldr_metrics(hdr, ldr)
    assert r["ssim"] == pytest.approx(1.0, abs=1e-4)
    assert r["mae"] == pytest.approx(0.0, abs=1e-4)
    assert r["scale"] == pytest.approx(1 / 123.0, rel=1e-3)


def test_a_saturated_probe_pixel_does_not_count():
    rng = np.random.default_rng(1)
    ldr = np.round(_probe(2) * 255) / 255
    ldr[10:14, 20:30] = 1.0  # the sun clipped by the camera
    from solidkit.envmap.io import srgb_decode

    hdr = srgb_decode(ldr).astype(np.float32)
    base = M.local_ldr_metrics(hdr, ldr)
    assert base["valid_fraction"] < 1.0
    other = hdr.copy()
    other[10:14, 20:30] = rng.uniform(0, 50, size=(4, 10, 3))  # anything at all where the probe saw white
    changed = M.local_ldr_metrics(other, ldr)
    assert changed["ssim"] == pytest.approx(base["ssim"], abs=1e-7)
    assert changed["mae"] == pytest.approx(base["mae"], abs=1e-7)
    # ... while a change on unsaturated pixels does count
    worse = hdr.copy()
    worse[30:40, 60:80] *= 5.0
    assert M.local_ldr_metrics(worse, ldr)["mae"] > base["mae"] + 1e-3


def test_an_external_saturation_mask_is_honoured():
    ldr = np.round(_probe(3) * 255) / 255
    mask = np.zeros(ldr.shape[:2], bool)
    mask[:, :10] = True
    assert M.saturation_mask(ldr, mask)[:, :10].all()
    from solidkit.envmap.io import srgb_decode

    hdr = srgb_decode(ldr).astype(np.float32)
    hdr2 = hdr.copy()
    hdr2[:, :10] = 0.0
    assert M.local_ldr_metrics(hdr2, ldr, mask)["mae"] == pytest.approx(
        M.local_ldr_metrics(hdr, ldr, mask)["mae"], abs=1e-7
    )


def test_a_constant_prediction_scores_below_a_correct_one():
    ldr = np.round(_probe(4) * 255) / 255
    from solidkit.envmap.io import srgb_decode

    good = M.local_ldr_metrics(srgb_decode(ldr), ldr)
    flat = M.local_ldr_metrics(np.full_like(ldr, 0.2), ldr)
    assert flat["ssim"] < good["ssim"] - 0.3
    assert flat["mae"] > good["mae"] + 0.02


def test_simulated_ldr_probe_is_8_bit_and_marks_the_clipped_sun():
    sky = _sky(0.0, 45.0)
    ldr, sat = M.simulate_ldr_probe(sky)
    assert np.allclose(ldr * 255, np.round(ldr * 255), atol=1e-4)
    assert sat.any() and sat.mean() < 0.05
    assert (ldr.max(axis=-1)[sat] >= M.SATURATION_LEVEL).all()
    assert M.local_ldr_metrics(sky, ldr, sat)["ssim"] > 0.98


def test_hdr_metrics_identical_and_different():
    sky = _sky(0.0, 45.0)
    r = M.local_hdr_metrics(sky, sky)
    assert r["ssim_tonemap"] == pytest.approx(1.0, abs=1e-5) and r["mae_log1p"] == 0.0
    assert M.local_hdr_metrics(sky * 3, sky)["mae_log1p"] > 0.1


def test_bootstrap_interval_contains_the_statistic_and_resamples_scenes():
    rng = np.random.default_rng(0)
    v = rng.normal(10.0, 2.0, size=60)
    lo, hi = M.bootstrap_ci(v, np.median)
    assert lo < np.median(v) < hi and hi - lo < 3.0
    # 3 scenes of 20 correlated values: the scene bootstrap is much wider than the per-value one
    g = np.repeat(["a", "b", "c"], 20)
    w = np.repeat([0.0, 10.0, 20.0], 20) + rng.normal(0, 0.1, 60)
    lo_v, hi_v = M.bootstrap_ci(w, np.mean)
    lo_g, hi_g = M.bootstrap_ci(w, np.mean, g)
    assert (hi_g - lo_g) > 2 * (hi_v - lo_v)
    s = M.summarise([1.0, float("nan"), 3.0])
    assert s["n"] == 2 and s["median"] == 2.0


def test_vectorised_cluster_bootstrap_matches_the_concatenated_statistic():
    rng = np.random.default_rng(3)
    v = rng.normal(size=17)
    gi = np.array([0, 0, 1, 2, 2, 2, 3, 4, 4, 5, 6, 6, 6, 6, 7, 8, 8])
    boot_rng = np.random.default_rng(11)
    for stat in (np.median, np.mean):
        got = _cluster_bootstrap(v, gi, 9, stat, 50, np.random.default_rng(11))
        idx = (
            boot_rng.integers(0, 9, size=(50, 9))
            if stat is np.median
            else np.random.default_rng(11).integers(0, 9, size=(50, 9))
        )
        want = [stat(np.concatenate([v[gi == k] for k in row])) for row in idx]
        assert np.allclose(got, want)


def test_global_mae_compares_the_sky_only_and_skips_invalid_pixels():
    sky = _sky(10.0, 40.0)
    ground = sky.copy()
    ground[H // 2 :] = 123.0  # a truth map taken at the camera position also holds the ground
    assert M.global_mae(sky, ground) == pytest.approx(0.0, abs=1e-6)
    assert M.global_mae(sky, ground, sky_only=False) > 0.1
    bad = sky.copy()
    bad[:4] = 0.0
    valid = np.ones(sky.shape[:2], bool)
    valid[:4] = False
    assert M.global_mae(bad, sky, valid) < M.global_mae(bad, sky)
