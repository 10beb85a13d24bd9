"""align.sky (relative yaw from the skies of two level panoramas) and align.links (yaws from relative links):
known answers on drawn sun-sky panoramas and on small link graphs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit.align.links import GROUND, Link, solve_links
from solidkit.align.sky import relative_sky_yaw, sky_layer, without_sun_drift
from solidkit.envmap.coords import angles_grid, direction_from_angles, direction_grid


def _panorama(
    sun_az_deg: float,
    *,
    h: int = 256,
    sun_el_deg: float = 35.0,
    seed: int = 0,
    uniform: bool = False,
    walls: tuple[tuple[float, float, float], ...] = ((-20.0, 70.0, 40.0), (150.0, 230.0, 25.0)),
) -> np.ndarray:
    """A level linear RGB panorama: a clear sky whose radiance rises toward the sun (hidden behind a
    wall) and toward the horizon (a Perez-like gradient), under noisy brownish walls
    ``(azimuth from, azimuth to, top elevation)`` in the capture's frame, and a grey ground."""
    rng = np.random.default_rng(seed)
    d = direction_grid(h)
    az, el = angles_grid(h)
    sun = np.asarray(direction_from_angles(math.radians(sun_az_deg), math.radians(sun_el_deg)))
    gamma = np.arccos(np.clip(d @ sun, -1.0, 1.0))
    zen = np.clip(np.pi / 2 - el, 0.0, np.pi / 2 - 0.02)
    grad = 1.0 - np.exp(-0.35 / np.cos(zen))
    lum = grad * (1.0 if uniform else (1.0 + 6.0 * np.exp(-2.5 * gamma) + 0.6 * np.cos(gamma) ** 2))
    img = np.stack([0.55 * lum, 0.75 * lum, 1.0 * lum], axis=-1).astype(np.float32) * 100.0
    below = el < 0
    img[below] = rng.uniform(8.0, 12.0, (int(below.sum()), 1)) * np.array([1.0, 1.0, 1.0], np.float32)
    for a0, a1, top in walls:
        span = ((np.degrees(az) - a0) % 360.0) <= (a1 - a0) % 360.0
        wall = span & (el >= 0) & (el <= np.radians(top))
        img[wall] = rng.uniform(10.0, 30.0, (int(wall.sum()), 1)) * np.array([1.0, 0.7, 0.5], np.float32)
    return img


def test_sky_gives_the_relative_yaw_of_two_panoramas_seeing_a_hidden_sun_sky():
    # photo frame: the sun at azimuth 40; capture a has yaw 10, capture b yaw -57.3: the sun at 30 and 97.3 in them
    a = sky_layer(_panorama(40.0 - 10.0, seed=1))
    b = sky_layer(_panorama(40.0 + 57.3, seed=2, walls=((0.0, 60.0, 30.0), (200.0, 260.0, 45.0))))
    r, why = relative_sky_yaw(a, b)
    assert r is not None, why
    assert abs(r.yaw_deg - (-57.3 - 10.0)) < 0.3
    assert 0.0 < r.sigma_deg < 1.0
    # swapping the two gives the opposite yaw
    r2, _ = relative_sky_yaw(b, a)
    assert abs(r2.yaw_deg + r.yaw_deg) < 0.3


def test_the_sun_drift_between_two_captures_is_taken_out_of_the_sky_shift():
    # world: the sun at azimuth 100 at capture a's time, 101.5 three minutes later at b's; headings 60 and 130.2
    a = sky_layer(_panorama(100.0 - 60.0, seed=8))
    b = sky_layer(_panorama(101.5 - 130.2, seed=9))
    r, why = relative_sky_yaw(a, b)
    assert r is not None, why
    assert abs(r.yaw_deg - (130.2 - 60.0 - 1.5)) < 0.3  # the raw shift carries the drift
    assert abs(without_sun_drift(r.yaw_deg, 100.0, 101.5) - (130.2 - 60.0)) < 0.3


def test_sky_layer_keeps_the_sky_and_drops_walls_and_ground():
    img = _panorama(30.0, seed=3)
    lay = sky_layer(img)
    _, el = angles_grid(256)
    az = np.degrees(angles_grid(256)[0])
    wall = (((az + 20.0) % 360.0) <= 90.0) & (el > 0.05) & (el < np.radians(38.0))
    assert not lay.mask[wall].any()
    assert not lay.mask[el < 0].any()
    assert lay.fraction > 0.3


def test_a_sky_without_azimuthal_structure_is_refused():
    a = sky_layer(_panorama(30.0, seed=4, uniform=True))
    b = sky_layer(_panorama(80.0, seed=5, uniform=True))
    r, why = relative_sky_yaw(a, b)
    assert r is None
    assert "uniform" in why or "ambiguous" in why or "curvature" in why


def test_a_panorama_without_sky_is_refused():
    img = _panorama(30.0, seed=6, walls=((0.0, 359.9, 89.0),))
    a, b = sky_layer(img), sky_layer(_panorama(30.0, seed=7))
    r, why = relative_sky_yaw(a, b)
    assert r is None and "overlap" in why


def test_links_reject_a_wrong_link_and_fix_yaws_from_an_anchor():
    true = {"p1": 10.0, "p2": -40.0, "p4": 100.0}
    rel = lambda a, b, err=0.0: true[b] - true[a] + err  # noqa: E731
    links = [
        Link("p1", "p2", rel("p1", "p2", 0.2), 2.0, "features"),
        Link("p1", "p4", rel("p1", "p4", -0.1), 0.4, "features"),
        Link("p2", "p4", rel("p2", "p4", 0.1), 2.0, "features"),
        Link(GROUND, "p2", true["p2"] + 0.1, 0.5, "features_via_p3"),
        Link(GROUND, "p1", true["p1"] - 15.0, 0.5, "features_via_p3"),  # repeated facade: 15 deg off
        Link(GROUND, "p4", true["p4"] - 21.0, 2.0, "features_via_p3"),  # 21 deg off, few inliers
        Link(GROUND, "p1", true["p1"] - 1.7, 5.0, "compass"),
        Link(GROUND, "p2", true["p2"] - 1.1, 5.0, "compass"),
        Link(GROUND, "p4", true["p4"] - 13.4, 5.0, "compass"),
    ]
    out = solve_links(["p1", "p2", "p4"], links)
    for n, y in true.items():
        assert abs(out[n].yaw_deg - y) < 1.0, (n, out[n])
    assert {e.yaw_deg for e in out["p1"].rejected} == {true["p1"] - 15.0, true["p4"] - 21.0}


def test_links_without_an_anchor_average_the_group_compasses_leaving_each_own_out():
    true = {"a": 0.0, "b": 50.0, "c": -120.0}
    compass_err = {"a": 2.4, "b": -1.1, "c": -3.2}
    links = [Link("a", "b", 50.0, 0.3, "features"), Link("b", "c", -170.0, 0.3, "features")]
    links += [Link(GROUND, n, true[n] + compass_err[n], 5.0, "compass") for n in true]
    out = solve_links(list(true), links)
    for n in true:
        others = [compass_err[m] for m in true if m != n]
        assert out[n].yaw_deg == pytest.approx(true[n] + np.mean(others), abs=0.05)
        assert out[n].sigma_deg == pytest.approx(5.0 / math.sqrt(2.0), rel=0.05)
        assert out[n].anchors == ()
    # a node linked to nothing gets no entry (its yaw would be its own compass)
    lone = solve_links(
        ["a", "d"],
        [
            Link(GROUND, "a", 0.0, 5.0, "compass"),
            Link(GROUND, "d", 3.0, 5.0, "compass"),
            Link(GROUND, "a", 1.0, 0.5, "sky_via_cam"),
        ],
    )
    assert "d" not in lone and lone["a"].yaw_deg == pytest.approx(1.0)
    # a node nothing ties to the ground (no compass, no link) does not stop the others
    free = solve_links(["a", "e"], [Link(GROUND, "a", 0.0, 5.0, "compass"), Link(GROUND, "a", 1.0, 0.5, "sky_via_cam")])
    assert list(free) == ["a"] and free["a"].yaw_deg == pytest.approx(1.0)


@pytest.mark.real
def test_a_real_cloudy_sky_gives_a_known_yaw(real_data):
    """city.exr (real clouds) against a copy turned by 37.3 deg, tilted 0.14 deg, half the exposure, with new walls."""
    from solidkit.envmap.coords import rotation_from_ypr
    from solidkit.envmap.io import read_exr
    from solidkit.envmap.resample import rotate

    img = read_exr(real_data / "hdr_panoramas" / "city.exr")[0][..., :3].astype(np.float32)
    a = rotate(img, np.eye(3), "linear", 512)
    b = 0.5 * rotate(
        img, np.asarray(rotation_from_ypr(math.radians(-37.3), math.radians(0.1), math.radians(-0.1))), "linear", 512
    )
    az, el = angles_grid(512)
    for a0, top in ((10.0, 30.0), (150.0, 40.0)):
        b[(((np.degrees(az) - a0) % 360.0) <= 40.0) & (el < np.radians(top))] = (0.1, 0.08, 0.06)
    r, why = relative_sky_yaw(sky_layer(a), sky_layer(b))
    assert r is not None, why
    assert abs(r.yaw_deg - 37.3) < 0.2
    assert r.sigma_deg < 0.5
