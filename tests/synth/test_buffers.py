"""Buffers against analytic geometry, shadow maps against a box blocking the sun, probes vs the global map."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from solidkit.envmap import coords_from_direction, direction_from_angles, direction_from_coords, read_exr  # noqa: E402
from solidkit.envmap.perspective import intrinsics_from_fov  # noqa: E402
from solidkit.synth.cameras import Camera  # noqa: E402
from solidkit.synth.lighting import HDR_DIR, Lighting, hdr, sunsky  # noqa: E402
from solidkit.synth.sample import pick_probe_pixels, render_buffers, render_panorama  # noqa: E402
from solidkit.synth.scene import CityBlock, box, city_block, quad, to_mitsuba  # noqa: E402

W, H = 48, 36
BOX_LO, BOX_HI = np.array([-1.0, -2.0, 6.0]), np.array([1.0, 0.0, 8.0])


def street() -> CityBlock:
    blk = CityBlock(seed=0)
    blk.add(quad(-200, 200, -200, 200, 0.0, "asphalt_new", "road"))  # label 0
    blk.add(box(BOX_LO, BOX_HI, "concrete_light", "building"))  # label 1
    return blk


def camera(pitch: float = -12.0, roll: float = 3.0, yaw: float = 4.0) -> Camera:
    return Camera(
        intrinsics_from_fov(math.radians(70.0), W, H),
        W,
        H,
        np.array([0.3, -1.55, 0.0]),
        math.radians(yaw),
        math.radians(pitch),
        math.radians(roll),
    )


def sun_only(sun: np.ndarray, height: int = 64) -> Lighting:
    pano = np.zeros((height, 2 * height, 3), np.float32)
    x, y = coords_from_direction(sun, height)
    pano[int(y), int(x)] = 1000.0
    d = np.asarray(direction_from_coords(np.floor(x) + 0.5, np.floor(y) + 0.5, height))
    return Lighting(pano, np.eye(3), d, {})


def test_buffers_agree_with_geometry() -> None:
    cam = camera()
    buf = render_buffers(to_mitsuba(street(), Lighting(np.ones((8, 16, 3), np.float32)).emitter()), cam, spp=2)
    ground, wall = buf["label"] == 0, buf["label"] == 1
    assert ground.sum() > 100 and wall.sum() > 20
    R, C = cam.rotation, cam.position
    v = cam.rays()
    P = buf["depth"][..., None] * v  # camera frame points
    Pw = P @ R.T + C
    # ground pixels: on the plane y = 0, normal = up in the camera frame, plane distance = camera height
    assert np.abs(Pw[ground][:, 1]).max() < 1e-3
    up_cam = R.T @ np.array([0.0, -1.0, 0.0])
    assert np.abs(buf["normal"][ground] - up_cam).max() < 1e-5
    assert np.allclose(buf["plane_distance"][ground], 1.55, atol=1e-3)
    # wall pixels: the visible face is z = 6 (normal -z, world), 6 m ahead of the camera along z
    face = wall & (np.abs(Pw[..., 2] - BOX_LO[2]) < 1e-3)
    assert face.sum() > 10
    assert np.abs(buf["normal_world"][face] - [0, 0, -1]).max() < 1e-5
    assert np.allclose(buf["plane_distance"][face], BOX_LO[2] - C[2], atol=1e-3)
    # normals are unit and perpendicular to in-plane directions (neighbouring points of the face)
    hit = buf["hit"]
    assert np.allclose(np.linalg.norm(buf["normal"][hit], axis=-1), 1.0, atol=1e-5)
    rows, cols = np.nonzero(face[:, :-1] & face[:, 1:])
    tangent = P[rows, cols + 1] - P[rows, cols]
    assert np.abs(np.sum(tangent * buf["normal"][rows, cols], -1)).max() < 1e-4
    # plane distance = -depth (n . v), and the paper's reprojection P = -p / (v . n) v recovers the point
    nv = np.sum(buf["normal"] * v, -1)
    assert np.allclose(buf["plane_distance"][hit], -(buf["depth"] * nv)[hit], atol=1e-5)
    Prec = -(buf["plane_distance"] / np.where(hit, nv, -1.0))[..., None] * v
    assert np.abs(Prec[hit] - P[hit]).max() < 1e-3
    # sky: zeros and label -1
    assert (buf["depth"][~hit] == 0).all() and (buf["label"][~hit] == -1).all()
    # albedo of the asphalt texture is that material's (~0.04 linear) and the box's concrete brighter
    assert 0.0 < buf["albedo"][ground].mean() < buf["albedo"][wall].mean() < 1.0


def box_blocks(points: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Slab test: does the ray ``p + s d`` (s > 0) hit the box?"""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - points) / d, (hi - points) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    return (tmax >= np.maximum(tmin, 0.0)) & (tmax > 0)


def test_shadow_map_is_zero_where_the_box_blocks_the_sun() -> None:
    sun = np.asarray(direction_from_angles(np.float64(math.radians(20.0)), np.float64(math.radians(40.0))))
    light = sun_only(sun, 256)  # Mitsuba filters the map bilinearly: the sun spreads over ~0.7°
    cam = camera(pitch=-20.0, roll=0.0, yaw=0.0)
    buf = render_buffers(to_mitsuba(street(), light.emitter()), cam, spp=8)
    s = buf["shadow"]
    assert s.min() >= 0.0 and s.max() <= 1.0
    ground = buf["label"] == 0
    Pw = (buf["depth"][..., None] * cam.rays()) @ cam.rotation.T + cam.position
    blocked = box_blocks(Pw, light.sun, BOX_LO, BOX_HI)
    # away from shadow edges (penumbra of the filtered sun: ~0.7° x 10 m), so pixel sampling does not matter
    shrink = np.ones_like(blocked)
    for dx in (-0.15, 0.15):
        for dz in (-0.15, 0.15):
            shrink &= box_blocks(Pw + np.array([dx, 0, dz]), light.sun, BOX_LO, BOX_HI) == blocked
    in_shadow, lit = ground & blocked & shrink, ground & ~blocked & shrink
    assert in_shadow.sum() > 20 and lit.sum() > 100
    assert s[in_shadow].max() < 0.02
    assert s[lit].min() > 0.98


def test_shadow_map_in_unit_range_with_a_real_sky() -> None:
    light = sunsky(np.asarray(direction_from_angles(np.float64(0.3), np.float64(0.6))), 3.0, height=64)
    buf = render_buffers(to_mitsuba(street(), light.emitter()), camera(), spp=4)
    s = buf["shadow"]
    assert np.isfinite(s).all() and s.min() >= 0.0 and s.max() <= 1.0
    assert s[buf["label"] == 0].mean() > 0.5  # the open ground is mostly lit


def test_probe_upper_hemisphere_matches_global_map() -> None:
    light = hdr(HDR_DIR / "courtyard.exr", 25.0, rng=np.random.default_rng(0))
    blk = CityBlock(seed=0)
    blk.add(quad(-300, 300, -300, 300, 0.0, "asphalt_old", "road"))
    frame = Camera(np.eye(3), 1, 1, np.zeros(3), math.radians(37.0), 0.0).pano_rotation
    hp = 16
    glob = render_panorama(to_mitsuba(None, light.emitter()), np.zeros(3), frame, hp, spp=64, seed=1)
    probe = render_panorama(to_mitsuba(blk, light.emitter()), np.array([3.0, -0.10, -2.0]), frame, hp, spp=64, seed=2)
    glob2 = render_panorama(to_mitsuba(None, light.emitter()), np.zeros(3), frame, hp, spp=64, seed=3)
    up = slice(0, hp // 2)

    def rel(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(a[up] - b[up]).mean() / b[up].mean())

    # as close to the global map as a second render of the global map itself (same noise level)
    assert rel(probe, glob) < 1.5 * rel(glob2, glob) + 0.005, (rel(probe, glob), rel(glob2, glob))
    # and in 4x4-pixel block means (less noise: a wrong frame or an occluder would show here)
    blocks = lambda a: a[up].reshape(hp // 8, 4, hp // 2, 4, 3).mean(axis=(1, 3))  # noqa: E731
    err = np.abs(blocks(probe) - blocks(glob)).mean() / blocks(glob).mean()
    assert err < 1.5 * np.abs(blocks(glob2) - blocks(glob)).mean() / blocks(glob).mean() + 0.005 and err < 0.08
    # while the lower hemisphere sees the street's ground, not the map's own ground
    low = slice(hp // 2 + 1, hp)
    assert np.abs(probe[low] - glob[low]).mean() > 0.2 * glob[low].mean()


def test_probe_pixels_one_per_quadrant_inside_the_border() -> None:
    rng = np.random.default_rng(0)
    hit = np.zeros((240, 320), bool)
    hit[60:, :] = True  # sky on top
    px = pick_probe_pixels(hit, rng, 0.05)
    assert [p["quadrant"] for p in px] == [0, 1, 2, 3]
    for p in px:
        x, y = p["pixel"]
        assert hit[y, x] and 16 <= x < 304 and 12 <= y < 228
        assert (x >= 160) == (p["quadrant"] in (1, 3)) and (y >= 120) == (p["quadrant"] >= 2)
    hit[:120] = False  # no surface in the upper quadrants: borrowed from the valid area
    px = pick_probe_pixels(hit, rng, 0.05)
    assert [p["quadrant"] for p in px] == [-1, -1, 2, 3] and all(hit[p["pixel"][1], p["pixel"][0]] for p in px)


def test_city_block_is_seeded() -> None:
    a, b, c = city_block(5), city_block(5), city_block(6)
    assert len(a.parts) == len(b.parts) and all(
        np.array_equal(p.vertices, q.vertices) for p, q in zip(a.parts, b.parts)
    )
    assert len(a.parts) != len(c.parts) or not all(
        np.array_equal(p.vertices, q.vertices) for p, q in zip(a.parts, c.parts)
    )
    cats = {p.category for p in a.parts}
    assert {"road", "sidewalk", "building"} <= cats and len(cats) >= 6
    # every box is closed with outward faces: signed volume > 0
    for p in a.parts[1:30]:
        v, f = p.vertices.astype(np.float64), p.faces
        vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
        assert vol > 0 or p.category == "marking"


def test_hdr_assets_present() -> None:
    files = sorted(HDR_DIR.glob("*.exr"))
    assert len(files) >= 3
    img, _ = read_exr(files[0])
    assert img.shape[1] == 2 * img.shape[0]


def test_firefly_suppression_keeps_the_sun() -> None:
    from solidkit.synth.sample import sun_mask_panorama, suppress_fireflies

    rng = np.random.default_rng(0)
    img = (0.5 + 0.05 * rng.random((32, 64, 3))).astype(np.float32)
    img[5, 7] = 500.0  # a firefly
    img[0, 63] = 300.0  # another, on the seam
    sun = np.asarray(direction_from_coords(np.float64(40.5), np.float64(10.5), 32))
    img[10, 40] = 1e4  # the sun
    out, n = suppress_fireflies(img, sun_mask_panorama(sun, np.eye(3), 32), 10.0, wrap=True)
    assert n == 2 and out[10, 40, 0] == 1e4
    assert np.all(out[5, 7] < 0.6) and np.all(out[0, 63] < 0.6)
    untouched = np.ones((32, 64), bool)
    untouched[5, 7] = untouched[0, 63] = False
    assert np.array_equal(out[untouched], img[untouched])
