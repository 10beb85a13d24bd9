"""Virtual objects under a light probe (solidkit.synth.relight): frames, determinism, differential compositing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit import metrics as M
from solidkit.envmap.coords import coords_from_direction, direction_from_angles
from solidkit.envmap.sun import luminance
from solidkit.synth.relight import OBJECTS, RelightView, composite, object_mesh, relight_view, render_objects

H = 32


def _sun(azimuth_deg: float, elevation_deg: float = 45.0) -> np.ndarray:
    """A faint sky and a small bright sun (3x3 pixels), (H, 2H, 3)."""
    pano = np.full((H, 2 * H, 3), 0.02, np.float32)
    x, y = coords_from_direction(
        np.asarray(direction_from_angles(math.radians(azimuth_deg), math.radians(elevation_deg))), H
    )
    pano[int(y) - 1 : int(y) + 2, int(x) - 1 : int(x) + 2] = 200.0
    return pano


VIEW = RelightView(azimuth=0.0, depression=math.radians(20.0), size=32)


@pytest.mark.parametrize("name", OBJECTS)
def test_object_meshes_stand_on_the_plane_about_one_unit_tall(name: str) -> None:
    v, n, f = object_mesh(name)
    assert v[:, 1].max() == pytest.approx(0.0, abs=0.02) and 0.9 < -v[:, 1].min() < 1.25  # y down
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    assert f.min() == 0 and f.max() == len(v) - 1


def test_the_same_probe_renders_the_same_and_scores_zero_error() -> None:
    probe = _sun(40.0)
    a = render_objects(probe, VIEW, ("diffuse_sphere",), spp=4)
    b = render_objects(probe, VIEW, ("diffuse_sphere",), spp=4)
    np.testing.assert_array_equal(a[0].with_object, b[0].with_object)
    mask = a[0].hit_mask
    assert mask.mean() > 0.5 and a[0].object_mask.mean() > 0.1
    assert M.si_rmse(a[0].with_object, b[0].with_object, mask) == 0.0
    assert M.render_ssim(a[0].with_object, b[0].with_object, mask) == pytest.approx(1.0, abs=1e-6)


def test_a_sun_on_the_right_lights_the_right_of_the_sphere_and_throws_its_shadow_left() -> None:
    """The probe's frame reaches the renderer unchanged: x right in the probe is right in the view; turning the
    sun from the right (+90°) to the left (-90°) swaps the lit side, and the two renders differ a lot."""
    right, left = (render_objects(_sun(az), VIEW, ("diffuse_sphere",), spp=16)[0] for az in (90.0, -90.0))
    half = VIEW.size // 2
    for r, lit in ((right, "right"), (left, "left")):
        y = luminance(r.with_object)
        obj, plane = r.object_mask, r.label == 0
        obj_l, obj_r = y[:, :half][obj[:, :half]].mean(), y[:, half:][obj[:, half:]].mean()
        shadow = (r.with_object - r.plane).sum(-1)  # negative where the sphere shades the plane
        sh_l, sh_r = shadow[:, :half][plane[:, :half]].sum(), shadow[:, half:][plane[:, half:]].sum()
        if lit == "right":
            assert obj_r > 1.5 * obj_l and sh_l < sh_r
        else:
            assert obj_l > 1.5 * obj_r and sh_r < sh_l
    assert M.si_rmse(right.with_object, left.with_object, right.hit_mask) > 0.3
    e = math.radians(90.0 - 180.0 * 8.5 / H)  # the suns' pixel row: 45° is the top edge of row 8 (42.2°)
    expected = math.degrees(math.acos(math.sin(e) ** 2 - math.cos(e) ** 2))  # azimuths +-90°: 95.6°
    assert M.shading_angle_deg(_sun(90.0), _sun(-90.0)) == pytest.approx(expected, abs=1.0)


def test_composite_puts_the_object_on_the_probe_pixel_and_leaves_the_rest_of_the_photo() -> None:
    K = np.array([[100.0, 0.0, 47.5], [0.0, 100.0, 35.5], [0.0, 0.0, 1.0]])
    view = relight_view((60.0, 55.0), K, 0.0, 0.0, size=32)
    assert view.depression == pytest.approx(math.atan((55.0 - 35.5) / math.hypot(100.0, 12.5)), abs=1e-6)
    r = render_objects(_sun(30.0), view, ("diffuse_sphere",), spp=4)[0]
    photo = np.full((72, 96, 3), 0.2, np.float32)
    out, scale = composite(photo, r, (60.0, 55.0))
    assert scale > 0
    changed = np.abs(out - photo).max(-1) > 1e-6
    ys, xs = np.nonzero(changed)
    assert abs(np.median(xs) - 60.0) < 6 and ys.max() <= 55 + 10 and ys.min() >= 55 - 32  # above the foot point
    assert not changed[:, :20].any() and not changed[:, 90:].any()
    # the object is exposed like the ground: the plane-alone render at the foot point, scaled, is the photo's 0.2
    bx, by = (int(round(c)) for c in view.base_pixel())
    assert scale * float(np.median(luminance(r.plane[by - 2 : by + 3, bx - 2 : bx + 3]))) == pytest.approx(
        0.2, rel=1e-4
    )
