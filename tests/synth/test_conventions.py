"""solidkit.synth <-> docs/conventions.md: Mitsuba's envmap axes, our sensors, sunsky's zenith.

A bright spot put into an environment panorama at a known direction (our equirect mapping)
must appear, in a render through the ``sk_equirect`` sensor, at the pixel that
:func:`solidkit.envmap.coords_from_direction` gives for that direction after the lighting's
rotation and the sensor's frame; a small box at a known 3D point must appear where
:meth:`Camera.project` puts it. Small sizes, low spp.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from solidkit.envmap import coords_from_direction, direction_from_angles, rotation_from_ypr, rotation_y  # noqa: E402
from solidkit.envmap.perspective import intrinsics_from_fov  # noqa: E402
from solidkit.synth.cameras import Camera  # noqa: E402
from solidkit.synth.lighting import Lighting, find_sun, horizontal_irradiance, sunsky  # noqa: E402
from solidkit.synth.sample import render_buffers, render_panorama  # noqa: E402
from solidkit.synth.scene import CityBlock, box, quad, to_mitsuba  # noqa: E402

H = 32


def spot_panorama(d: np.ndarray, height: int = H) -> np.ndarray:
    pano = np.full((height, 2 * height, 3), 0.01, np.float32)
    x, y = coords_from_direction(d, height)
    pano[int(y), int(x)] = 1000.0
    return pano


def brightest(img: np.ndarray) -> tuple[int, int]:
    y, x = np.unravel_index(np.argmax(img.sum(-1)), img.shape[:2])
    return int(x), int(y)


@pytest.mark.parametrize(
    "az,el,light_yaw,sensor_yaw",
    [(50.0, 20.0, 0.0, 0.0), (-120.0, 35.0, 30.0, 0.0), (10.0, -40.0, 45.0, -70.0), (170.0, 60.0, 0.0, 100.0)],
)
def test_envmap_spot_lands_where_conventions_say(az: float, el: float, light_yaw: float, sensor_yaw: float) -> None:
    d = np.asarray(direction_from_angles(np.float64(math.radians(az)), np.float64(math.radians(el))))
    # put the spot on a pixel centre so the expected pixel is unambiguous
    x, y = coords_from_direction(d, H)
    from solidkit.envmap import direction_from_coords

    d = np.asarray(direction_from_coords(np.floor(x) + 0.5, np.floor(y) + 0.5, H))
    R = np.asarray(rotation_y(math.radians(light_yaw)))
    light = Lighting(spot_panorama(d), R, None, {})
    scene = to_mitsuba(None, light.emitter())
    S = np.asarray(rotation_y(math.radians(sensor_yaw)))
    img = render_panorama(scene, np.zeros(3), S, H, spp=16, seed=1)
    expected = S.T @ (R @ d)  # scene direction seen in the sensor's frame
    ex, ey = coords_from_direction(expected, H)
    gx, gy = brightest(img)
    dx = min(abs(gx + 0.5 - ex), 2 * H - abs(gx + 0.5 - ex))
    assert dx <= 1.0 and abs(gy + 0.5 - ey) <= 1.0, (gx, gy, ex, ey)


def test_pinhole_projects_like_opencv() -> None:
    blk = CityBlock(seed=0)
    target = np.array([1.2, -2.0, 8.0])
    blk.add(box(target - 0.1, target + 0.1, "plastic_orange", "bin"))
    K = intrinsics_from_fov(math.radians(60.0), 64, 48)
    cam = Camera(K, 64, 48, np.array([0.0, -1.5, 0.0]), math.radians(8.0), math.radians(-5.0), math.radians(4.0))
    light = Lighting(np.ones((8, 16, 3), np.float32))
    buf = render_buffers(to_mitsuba(blk, light.emitter()), cam, spp=1, shadows=False)
    ys, xs = np.nonzero(buf["label"] == 0)
    assert len(xs) > 0
    px = cam.project(target)
    assert abs(xs.mean() - px[0]) < 0.75 and abs(ys.mean() - px[1]) < 0.75
    # the camera's rotation is the conventions' R(yaw, pitch, roll)
    assert np.allclose(cam.rotation, rotation_from_ypr(cam.yaw, cam.pitch, cam.roll))


def test_sunsky_zenith_and_sun_direction() -> None:
    sun = np.asarray(direction_from_angles(np.float64(math.radians(-60.0)), np.float64(math.radians(30.0))))
    light = sunsky(sun, 3.0, height=64)
    pano = light.panorama
    assert pano[40:].max() == 0.0  # below the horizon: nothing (the sky's zenith is up, -y)
    found = find_sun(pano)
    assert found is not None
    assert math.degrees(math.acos(np.clip(found @ sun, -1, 1))) < 3.0  # within one 2.8° pixel
    assert 0.6 * math.pi - 1e-3 <= horizontal_irradiance(pano) <= 1.2 * math.pi + 1e-3  # exposure normalisation
    assert light.meta["sun_elevation_deg"] == pytest.approx(30.0, abs=1e-6)


def test_ground_and_sky_sit_where_they_should_in_a_probe() -> None:
    blk = CityBlock(seed=0)
    blk.add(quad(-100, 100, -100, 100, 0.0, "asphalt_new", "road"))
    light = Lighting(np.ones((8, 16, 3), np.float32))
    scene = to_mitsuba(blk, light.emitter())
    img = render_panorama(scene, np.array([0.0, -1.0, 0.0]), np.eye(3), 8, spp=4)
    # sky (radiance 1) in the upper half, darker ground (albedo < 1) in the lower half
    assert np.allclose(img[:4], 1.0, atol=1e-3)
    assert img[5:].mean() < 0.6
