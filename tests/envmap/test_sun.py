"""Sun detection (solidkit.envmap.sun): rendered suns at known directions, "no sun" cases, the
paper's recipe on an analytic case, real HDR panoramas, and the ``solidkit envmap sun`` command.

Measured on the real panoramas (1024 x 512, ``../shared/data/real/hdr_panoramas``):

============  ===================  ======================  =====================================
file          reference            default ("core")        paper recipe (geometric / luminance)
============  ===================  ======================  =====================================
sunrise.exr   35.84°, 8.07°        0.007° off              5.73° / 0.72° off
city.exr      35.93°, 47.77°       0.029° off              4.24° / 1.36° off
courtyard     sun occluded         found=False (4.2x sky)  found=False
============  ===================  ======================  =====================================
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from solidkit.envmap.coords import (
    angles_grid,
    angular_distance,
    coords_from_direction,
    direction_from_angles,
    direction_from_coords,
    direction_grid,
)
from solidkit.envmap.io import srgb_decode, srgb_encode, write_exr
from solidkit.envmap.sun import (
    SunDetection,
    detect_sun,
    label_spherical,
    luminance,
    spherical_centroid,
)
from solidkit.errors import InputError, PanoramaError

SUN_RADIUS = math.radians(0.53 / 2)
SOLIDKIT = Path(sys.executable).with_name("solidkit")


# --------------------------------------------------------------------------------------------
# a tiny renderer: sky gradient + sun disk integrated over each pixel


def sky(h: int, zenith: float = 1.0, horizon: float = 4.0, ground: float = 0.3) -> np.ndarray:
    """Smooth clear-sky-like radiance ``(h, 2h, 3)``: brighter toward the horizon, dim ground."""
    phi, theta = angles_grid(h)
    s = np.where(theta > 0, horizon + (zenith - horizon) * np.sin(np.clip(theta, 0, None)), ground)
    s = s * (1 + 0.2 * np.cos(phi))
    return (s[..., None] * np.array([0.8, 0.9, 1.2])).astype(np.float32)


def add_sun(img, az, el, radius=SUN_RADIUS, radiance=1e5, psf=0.0, ss=8):
    """Add a sun at (az, el) radians: a disk of ``radius``, optionally blurred by an angular
    Gaussian PSF of sigma ``psf`` (approximated as one Gaussian of the combined variance); each
    pixel gets the solid-angle-weighted mean radiance of ``ss x ss`` sub-samples (box filter).
    Every profile is rotationally symmetric about the sun direction, so its energy centroid on
    the sphere is exactly that direction."""
    h = img.shape[0]
    d0 = direction_from_angles(np.float64(az), np.float64(el))
    reach = radius + 4 * psf + 1.5 * math.pi / h
    rows, cols = np.nonzero(angular_distance(direction_grid(h), d0) < reach)
    o = (np.arange(ss) + 0.5) / ss
    oy, ox = np.meshgrid(o, o, indexing="ij")
    d = direction_from_coords(cols[:, None] + ox.ravel(), rows[:, None] + oy.ravel(), h)
    g = angular_distance(d, d0)
    if psf > 0:
        prof = np.exp(-0.5 * g**2 / (psf**2 + radius**2 / 4))
    else:
        prof = (g <= radius).astype(np.float64)
    cos_el = np.sqrt(np.clip(1 - d[..., 1] ** 2, 0, None))
    out = img.copy()
    out[rows, cols] += (radiance * (prof * cos_el).sum(1) / cos_el.sum(1))[:, None].astype(np.float32)
    return out


def error_deg(result: SunDetection, az: float, el: float) -> float:
    assert result.found, result.reason
    return math.degrees(float(angular_distance(result.direction, direction_from_angles(az, el))))


# --------------------------------------------------------------------------------------------
# pieces


def test_label_spherical_joins_seam_and_poles():
    h = 16
    mask = np.zeros((h, 2 * h), bool)
    mask[5:7, :2] = True  # left of the seam
    mask[6:8, -2:] = True  # right of the seam, overlapping rows: one blob on the sphere
    mask[0, 5] = mask[0, 20] = True  # two pixels of the top row: they meet at the zenith
    mask[10, 10:12] = True  # an isolated blob
    mask[15, 3] = True  # nadir row, alone
    labels, n = label_spherical(mask)
    assert n == 4
    assert len(set(labels[5:8, [0, 1, -2, -1]][mask[5:8, [0, 1, -2, -1]]])) == 1
    assert labels[0, 5] == labels[0, 20] != 0
    assert len({labels[5, 0], labels[0, 5], labels[10, 10], labels[15, 3]}) == 4
    # diagonal contact across the seam counts (8-connectivity), two rows apart does not
    m2 = np.zeros((h, 2 * h), bool)
    m2[5, 0] = m2[6, -1] = m2[9, 0] = m2[11, -1] = True
    assert label_spherical(m2)[1] == 3


def test_spherical_centroid_of_a_cap_is_its_centre():
    h = 64
    centre = direction_from_angles(np.float64(math.radians(179.0)), np.float64(math.radians(80.0)))
    cap = direction_grid(h) @ centre > math.cos(math.radians(12.0))  # crosses the seam and the pole
    d = spherical_centroid(np.ones((h, 2 * h)), cap)
    # a pixelated cap is symmetric only up to its pixel boundary: within a fraction of a pixel
    assert math.degrees(float(angular_distance(d, centre))) < 0.3
    assert spherical_centroid(np.zeros((h, 2 * h))) is None


# --------------------------------------------------------------------------------------------
# rendered suns at known directions


CASES = [
    # (H, PSF sigma in pixels, azimuth deg, elevation deg)
    (512, 0.0, 35.0, 20.0),
    (512, 0.0, -123.4, 2.5),
    (512, 0.0, 179.9, 30.0),  # disk straddles the +-180 seam
    (512, 0.0, -180.0, 45.0),  # centred on the seam
    (512, 0.0, 60.0, 86.0),  # near the zenith
    (512, 0.0, -20.0, 89.85),  # disk covers the zenith
    (128, 1.0, 35.0, 20.0),
    (128, 1.0, 179.7, 10.0),
    (128, 1.0, 100.0, 85.5),
    (128, 1.0, -179.6, 88.0),
]


@pytest.mark.parametrize("h,psf_px,az,el", CASES)
def test_core_finds_rendered_sun_within_0p1_deg(h, psf_px, az, el):
    az, el = math.radians(az), math.radians(el)
    img = add_sun(sky(h), az, el, psf=psf_px * math.pi / h)
    r = detect_sun(img)
    assert error_deg(r, az, el) < 0.1
    assert r.method == "core" and 0.9 < r.confidence <= 1.0
    # sub-pixel coordinates agree with the direction
    x, y = coords_from_direction(r.direction, h)
    assert (r.x, r.y) == pytest.approx((float(x), float(y)))
    assert -math.pi <= r.azimuth < math.pi


def test_subpixel_disk_without_blur_is_within_its_pixel():
    """At 256 x 128 a box-filtered 0.53° disk is 0.37 px wide: a disk inside one pixel has no
    recoverable sub-pixel position, so only 'within the pixel' can be asked (documented limit)."""
    h, rng = 128, np.random.default_rng(3)
    base = sky(h)
    for _ in range(5):
        az, el = rng.uniform(-math.pi, math.pi), rng.uniform(0.0, 1.3)
        r = detect_sun(add_sun(base, az, el))
        assert error_deg(r, az, el) < 0.75 * 180 / h  # half a pixel diagonal is 0.71 px


def test_ldr_low_exposure_frame_saturated_blob():
    """A Theta-like 1/25000 s frame: only the sun clips; 8-bit sRGB, decoded to linear."""
    h, rng = 512, np.random.default_rng(1)
    base = sky(h)
    cases = [(math.pi - 1e-3, 0.4, 5e-4), (rng.uniform(-3, 3), rng.uniform(0, 1.4), 1e-4), (0.3, 1.45, 3e-5)]
    for az, el, exposure in cases:
        hdr = add_sun(base, az, el, psf=1.2 * math.pi / h)
        ldr = srgb_decode(np.round(srgb_encode(hdr * exposure) * 255) / 255).astype(np.float32)
        assert ldr.max() == 1.0 and (ldr.min(axis=2) >= 0.98).sum() < 400  # a small saturated blob
        r = detect_sun(ldr)
        assert "saturated" in r.reason
        assert error_deg(r, az, el) < 0.1


def test_overcast_is_no_sun():
    h = 256
    phi, theta = angles_grid(h)
    # smooth bright overcast sky (brighter at the zenith, CIE-overcast-like), dim ground
    lum = np.where(theta > 0, 30 * (1 + 2 * np.sin(np.clip(theta, 0, None))) / 3, 5.0)
    img = np.repeat(lum[..., None], 3, axis=2).astype(np.float32)
    for method in ("core", "paper"):
        r = detect_sun(img, method=method)
        assert not r.found and r.confidence == 0.0
        assert r.direction is None and r.azimuth is None and r.elevation is None
        assert r.to_json() == {"found": False, "azimuth_deg": None, "elevation_deg": None, "confidence": 0.0}
    # the same sky with a sun is found (the sky alone is what made it 'no sun')
    assert detect_sun(add_sun(img, 0.5, 0.5, psf=math.pi / h)).found


def test_bright_cloud_only_is_no_sun():
    h = 256
    centre = direction_from_angles(np.float64(1.0), np.float64(0.5))
    ang = angular_distance(direction_grid(h), centre)
    base = sky(h)
    cloud = 100.0 * np.exp(-0.5 * (ang / math.radians(4.0)) ** 2)  # 25x the sky's brightest part
    r = detect_sun(base + cloud[..., None].astype(np.float32))
    assert not r.found and r.confidence == 0.0
    assert "not a sun disk" in r.reason or "bright sky" in r.reason
    # with a sun beside the cloud, the sun (not the cloud) is found
    az, el = -0.5, 0.3
    r = detect_sun(add_sun(base + cloud[..., None].astype(np.float32), az, el, psf=math.pi / h))
    assert error_deg(r, az, el) < 0.1


def test_black_and_bad_input():
    assert not detect_sun(np.zeros((8, 16, 3), np.float32)).found
    with pytest.raises(PanoramaError):
        detect_sun(np.ones((8, 17, 3), np.float32))
    bad = np.ones((8, 16, 3), np.float32)
    bad[2, 3, 1] = np.nan
    with pytest.raises(PanoramaError):
        detect_sun(bad)
    with pytest.raises(InputError):
        detect_sun(np.ones((8, 16, 3), np.float32), method="nope")
    with pytest.raises(InputError, match="float"):
        detect_sun(np.full((8, 16, 3), 255, np.uint8))
    # RGBA: the alpha channel is ignored; single-channel and 2-D luminance maps work
    img = add_sun(sky(64), 0.4, 0.2, psf=math.pi / 64)
    rgba = np.concatenate([img, np.zeros_like(img[..., :1])], axis=2)
    for variant in (rgba, luminance(img), luminance(img)[..., None]):
        assert error_deg(detect_sun(variant), 0.4, 0.2) < 0.1


# --------------------------------------------------------------------------------------------
# the paper's recipe


def _patch_centroid(az0, az1, el0, el1):
    """Exact solid-angle centroid of the region az in [az0, az1], el in [el0, el1] (radians)."""
    cc = (el1 - el0) / 2 + (math.sin(2 * el1) - math.sin(2 * el0)) / 4  # int cos^2
    sc = (math.sin(el1) ** 2 - math.sin(el0) ** 2) / 2  # int sin cos
    v = np.array([cc * (math.cos(az0) - math.cos(az1)), -sc * (az1 - az0), cc * (math.sin(az1) - math.sin(az0))])
    return v / np.linalg.norm(v)


def test_paper_recipe_on_an_analytic_case():
    """Dim uniform sky (1.0), a large bright region (50) straddling the seam and a small sun (1e5)
    elsewhere: both together are < 2 % of the pixels, so the 98th percentile is the sky and
    'the largest component above it' is the bright region; its centroid is known in closed form
    (the seam-wrapped, solid-angle-weighted region). The default method finds the sun instead."""
    h = 256
    w = 2 * h
    img = np.ones((h, w, 3), np.float32)
    # pixel-aligned patch: columns [w-14, w) + [0, 10) (azimuth 170.16 .. -172.97 deg), rows 100..119
    cols = np.r_[w - 14 : w, 0:10]
    img[100:120, cols] = 50.0
    sun_az, sun_el = -1.0, 0.6
    img = add_sun(img, sun_az, sun_el, psf=math.pi / h)
    assert (luminance(img) > 1.0).mean() < 0.02

    r = detect_sun(img, method="paper")
    az0, az1 = math.pi - 14 * 2 * math.pi / w, math.pi + 10 * 2 * math.pi / w
    el0, el1 = math.pi / 2 - 120 * math.pi / h, math.pi / 2 - 100 * math.pi / h
    expected = _patch_centroid(az0, az1, el0, el1)
    assert math.degrees(float(angular_distance(r.direction, expected))) < 1e-3
    assert r.n_pixels == 20 * 24
    # luminance weighting of a constant region is the same centroid
    r_lum = detect_sun(img, method="paper", weighting="luminance")
    assert math.degrees(float(angular_distance(r_lum.direction, expected))) < 1e-3
    # the default method ignores the big bright region and finds the sun
    assert error_deg(detect_sun(img), sun_az, sun_el) < 0.1


def test_paper_largest_component_by_solid_angle_and_luminance_weighting():
    """Luminance weighting pulls the centroid to the bright end of a graded region."""
    h = 128
    img = np.ones((h, 2 * h, 3), np.float32)
    grad = np.linspace(20, 80, 12, dtype=np.float32)
    img[60:64, 40:52] = grad[None, :, None]
    img[30:32, 100:103] = 1000.0  # brighter but smaller: not the largest
    geo = detect_sun(img, method="paper")
    lum = detect_sun(img, method="paper", weighting="luminance")
    mask = np.zeros((h, 2 * h), bool)
    mask[60:64, 40:52] = True
    expected_geo = spherical_centroid(np.ones((h, 2 * h)), mask)
    expected_lum = spherical_centroid(luminance(img), mask)
    assert np.allclose(geo.direction, expected_geo) and np.allclose(lum.direction, expected_lum)
    assert lum.azimuth > geo.azimuth  # toward the brighter (larger-u) end


# --------------------------------------------------------------------------------------------
# real HDR panoramas (Poly Haven, CC0)

REFERENCE = {"sunrise.exr": (35.84, 8.07), "city.exr": (35.93, 47.77)}


def _read(real_data, name):
    from solidkit.envmap.io import read_image

    return read_image(real_data / "hdr_panoramas" / name)[0]


@pytest.mark.real
@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_real_core_within_0p3_deg_of_saturated_core(real_data, name):
    img = _read(real_data, name)
    az, el = map(math.radians, REFERENCE[name])
    r = detect_sun(img)
    assert error_deg(r, az, el) < 0.3  # measured: sunrise 0.007 deg, city 0.029 deg
    assert r.confidence > 0.9
    lum = luminance(img)
    v, u = np.unravel_index(int(np.argmax(lum)), lum.shape)
    brightest = direction_from_coords(u + 0.5, v + 0.5, img.shape[0])
    assert math.degrees(float(angular_distance(r.direction, brightest))) < 0.5  # measured 0.22, 0.15


@pytest.mark.real
@pytest.mark.parametrize("name,min_err", [("sunrise.exr", 5.0), ("city.exr", 3.5)])
def test_real_paper_recipe_lands_in_the_sky(real_data, name, min_err):
    """The paper's recipe (geometric centroid of the largest top-2 % component) is pulled into the
    bright sky around the sun: measured 5.73° (sunrise) and 4.24° (city) off; luminance-weighted
    0.72° and 1.36°. The issue measured 5.6° and 3.1° (presumably a pixel-space centroid)."""
    img = _read(real_data, name)
    az, el = map(math.radians, REFERENCE[name])
    r = detect_sun(img, method="paper")
    assert min_err < error_deg(r, az, el) < min_err + 1.5
    assert r.confidence < 0.05  # little of the component's light is near its centroid
    r_lum = detect_sun(img, method="paper", weighting="luminance")
    assert 0.3 < error_deg(r_lum, az, el) < 2.0


@pytest.mark.real
def test_real_courtyard_sun_is_occluded(real_data):
    """courtyard.exr: a sunny day (hard shadows on the paving), but the sun is behind the
    carport roof. Its brightest pixels (luminance 52 at azimuth 156°, elevation 14.6°) are a sunlit
    roof edge across the yard, only ~4x the bright sky (the visible suns in sunrise/city are
    ~1e4x), so the documented answer is 'no sun' for both methods: the sun is not in the
    panorama, and neither a reflection nor a patch of sky is reported as one."""
    img = _read(real_data, "courtyard.exr")
    r = detect_sun(img)
    assert not r.found and r.confidence == 0.0
    assert 2.0 < r.contrast < 10.0  # measured 4.19
    assert not detect_sun(img, method="paper").found


# --------------------------------------------------------------------------------------------
# the command


def _run(*args):
    """The installed ``solidkit`` entry point, in a subprocess."""
    return subprocess.run([str(SOLIDKIT), "envmap", "sun", *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="module")
def sun_exr(tmp_path_factory):
    h = 128
    img = add_sun(sky(h), math.radians(-179.8), math.radians(30.0), psf=math.pi / h)
    return write_exr(tmp_path_factory.mktemp("sun") / "sun.exr", img), img


def test_cli_json_entry_point(sun_exr):
    path, img = sun_exr
    out = _run(path, "--json")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert set(data) == {"found", "azimuth_deg", "elevation_deg", "confidence"}
    assert data == pytest.approx(detect_sun(img).to_json())
    assert data["found"] is True
    assert abs(data["elevation_deg"] - 30.0) < 0.1 and abs(abs(data["azimuth_deg"]) - 179.8) < 0.1
    bad = _run(path.with_name("missing.exr"))
    assert bad.returncode != 0 and bad.stdout == "" and "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_cli_summary_and_paper_method(sun_exr, cli):
    path, img = sun_exr
    code, out, _ = cli("envmap", "sun", path)
    assert code == 0 and len(out.strip().splitlines()) == 1
    assert "azimuth" in out and "elevation" in out
    expected = detect_sun(img)
    assert f"{expected.azimuth_deg:.2f}" in out and f"{expected.elevation_deg:.2f}" in out
    code, out, _ = cli("envmap", "sun", path, "--json", "--method", "paper")
    assert code == 0
    assert json.loads(out) == pytest.approx(detect_sun(img, method="paper").to_json())


def test_cli_no_sun(tmp_path, cli):
    path = write_exr(tmp_path / "overcast.exr", sky(32))
    code, out, _ = cli("envmap", "sun", path, "--json")
    assert code == 0
    assert json.loads(out) == {"found": False, "azimuth_deg": None, "elevation_deg": None, "confidence": 0.0}
    code, out, _ = cli("envmap", "sun", path)
    assert code == 0 and out.startswith("no sun")


@pytest.mark.parametrize("kind", ["missing", "not_image", "not_exr", "wrong_shape", "nan"])
def test_cli_bad_input_is_one_line(tmp_path, cli, kind):
    if kind == "missing":
        path = tmp_path / "missing.exr"
    elif kind == "not_image":
        path = tmp_path / "notes.txt"
        path.write_text("hello")
    elif kind == "not_exr":
        path = tmp_path / "fake.exr"
        path.write_bytes(b"not an exr at all" * 20)
    elif kind == "wrong_shape":
        path = write_exr(tmp_path / "wide.exr", np.ones((16, 48, 3), np.float32))
    else:
        img = np.ones((16, 32, 3), np.float32)
        img[3, 4, 0] = np.inf
        img[5, 6, 2] = np.nan
        path = write_exr(tmp_path / "nan.exr", img)
    code, out, err = cli("envmap", "sun", path, "--json")
    assert code != 0
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "Traceback" not in err
    expected = {
        "missing": "no such file",
        "not_image": "unknown image type",
        "not_exr": "not a readable EXR",
        "wrong_shape": "width must be 2",
        "nan": "NaN or Inf",
    }
    assert expected[kind] in lines[0]
