"""Panorama resampling: padding, sampling, rotation (NumPy and torch), energy-preserving resizing."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from solidkit.envmap import coords as C
from solidkit.envmap.resample import downsample, pad_panorama, resize, rotate, sample_panorama
from solidkit.errors import InputError, PanoramaError

H = 64
W = 2 * H
PITCH = math.pi / H  # angular pixel pitch (rad)


def smooth_field(d: np.ndarray, seed: int = 0, channels: int = 3) -> np.ndarray:
    """A smooth random function on the sphere (no seam or pole artefacts), range ~[-4, 4]."""
    rng = np.random.default_rng(seed)
    out = np.zeros((*d.shape[:-1], channels))
    for c in range(channels):
        for _ in range(4):
            a = rng.normal(size=3)
            a /= np.linalg.norm(a)
            out[..., c] += np.sin(rng.uniform(1.0, 3.0) * (d @ a) + rng.uniform(0, 2 * math.pi))
    return out


def smooth_pano(height: int = H, seed: int = 0) -> np.ndarray:
    return smooth_field(C.direction_grid(height), seed).astype(np.float32)


def blob(d: np.ndarray, centre: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian disk on the sphere around ``centre`` (angular sigma in rad)."""
    ang = C.angular_distance(d, np.broadcast_to(centre, d.shape))
    return np.exp(-0.5 * (ang / sigma) ** 2)


def spherical_centroid(pano: np.ndarray) -> np.ndarray:
    """Radiance x solid-angle weighted mean direction (unit) of a single-channel panorama."""
    h = pano.shape[0]
    w = pano * C.solid_angle(h)
    c = (w[..., None] * C.direction_grid(h)).sum((0, 1))
    return c / np.linalg.norm(c)


def to_torch(p: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(p)).permute(2, 0, 1)[None]


def to_numpy(t: torch.Tensor) -> np.ndarray:
    return t[0].detach().permute(1, 2, 0).numpy()


ROTATIONS = [
    C.rotation_from_ypr(0.7, 0.4, -0.3),
    C.rotation_from_ypr(-2.5, -1.1, 0.9),
    C.rotation_from_ypr(math.pi, 0.0, math.pi / 2),
]


# --- padding ---------------------------------------------------------------------------


def test_padding_continues_the_sphere_across_seam_and_poles():
    """Every padded pixel holds the value of the panorama in the direction of its centre."""
    p = smooth_pano()
    padded = pad_panorama(p, 3)
    assert padded.shape == (H + 6, W + 6, 3)
    ys, xs = np.meshgrid(np.arange(-3, H + 3) + 0.5, np.arange(-3, W + 3) + 0.5, indexing="ij")
    # the coords formulas extend past the poles (elevation beyond ±90° = the other side)
    d = C.direction_from_coords(xs, ys, H)
    np.testing.assert_allclose(padded, smooth_field(d), atol=1e-5)
    torch_padded = pad_panorama(to_torch(p), 3)
    np.testing.assert_array_equal(to_numpy(torch_padded), padded)


def test_sample_panorama_at_pixel_centres_is_exact():
    p = smooth_pano()
    rng = np.random.default_rng(1)
    u, v = rng.integers(0, W, 200), rng.integers(0, H, 200)
    d = C.direction_from_coords(u + 0.5, v + 0.5, H)
    np.testing.assert_allclose(sample_panorama(p, d), p[v, u], atol=1e-6)
    np.testing.assert_allclose(sample_panorama(p, d, "cubic"), p[v, u], atol=1e-5)
    t = sample_panorama(to_torch(p), torch.from_numpy(d))
    assert t.shape == (1, 3, 200)
    np.testing.assert_allclose(t[0].T.numpy(), p[v, u], atol=1e-4)


# --- rotation --------------------------------------------------------------------------


def test_rotation_matches_analytic_rotated_field_everywhere():
    """out(d) = in(Rᵀ d) against the analytic field, poles and seam included."""
    p = smooth_pano()
    d = C.direction_grid(H)
    rng = p.max() - p.min()
    for R in ROTATIONS:
        truth = smooth_field(d @ R)
        for interp, tol in (("linear", 2e-3), ("cubic", 5e-4)):
            err = np.abs(rotate(p, R, interp) - truth)
            assert err.mean() / rng < tol, (interp, err.mean() / rng)
            assert err.max() / rng < 20 * tol


@pytest.mark.parametrize("interp", ["linear", "cubic"])
def test_rotate_then_inverse_returns_the_panorama_numpy_and_torch(interp):
    p = smooth_pano(seed=3)
    rng = p.max() - p.min()
    away_from_poles = np.abs(C.angles_grid(H)[1]) < np.deg2rad(80)
    for R in ROTATIONS:
        back = rotate(rotate(p, R, interp), R.T, interp)
        assert np.abs(back - p)[away_from_poles].mean() / rng < 1e-3
        tback = to_numpy(rotate(rotate(to_torch(p), R, interp), R.T, interp))
        assert np.abs(tback - p)[away_from_poles].mean() / rng < 1e-3


@pytest.mark.parametrize("interp", ["nearest", "linear", "cubic"])
def test_numpy_and_torch_paths_agree(interp):
    p = smooth_pano(seed=5)
    for R in ROTATIONS:
        a = rotate(p, R, interp)
        b = to_numpy(rotate(to_torch(p), torch.from_numpy(R), interp))
        if interp == "nearest":  # ties may round differently: compare the fraction that differ
            assert (np.abs(a - b).max(-1) > 1e-4).mean() < 2e-3
        else:
            assert np.abs(a - b).max() < 5e-4


@pytest.mark.parametrize("centre_ae", [(30.0, 10.0), (179.0, -20.0), (-100.0, 84.0), (60.0, -70.0)])
def test_marker_lands_at_rotated_direction(centre_ae):
    """A small disk at d goes to R d (within 0.5 px), including across the seam and near a pole."""
    d0 = C.direction_from_angles(*np.deg2rad(centre_ae))
    grid = C.direction_grid(H)
    p = blob(grid, d0, 1.5 * PITCH).astype(np.float32)
    for R in ROTATIONS + [C.rotation_from_ypr(0.0, 0.3, 0.0)]:
        target = R @ d0
        out = rotate(p, R)
        err = float(C.angular_distance(spherical_centroid(out), target))
        assert err < 0.5 * PITCH, (centre_ae, err / PITCH)
        # and the whole disk matches the analytic one rendered at R d
        assert np.abs(out - blob(grid, target, 1.5 * PITCH)).max() < 0.12
        tout = to_numpy(rotate(to_torch(p[..., None]), R))[..., 0]
        assert float(C.angular_distance(spherical_centroid(tout), target)) < 0.5 * PITCH


def test_single_bright_pixel_moves_to_rotated_direction():
    u, v = 37, 20
    p = np.zeros((H, W), np.float32)
    p[v, u] = 1000.0
    d0 = C.direction_from_coords(np.array(u + 0.5), np.array(v + 0.5), H)
    for R in ROTATIONS:
        out = rotate(p, R)
        assert float(C.angular_distance(spherical_centroid(out), R @ d0)) < 0.5 * PITCH


def test_yaw_rotation_content_moves_right():
    """conventions §4: rotate --yaw 30 moves the content (e.g. the sun) 30° to the right."""
    d0 = C.direction_from_angles(np.deg2rad(10.0), np.deg2rad(20.0))
    p = blob(C.direction_grid(H), d0, 2 * PITCH).astype(np.float32)
    out = rotate(p, C.rotation_from_ypr(np.deg2rad(30.0)))
    az, el = C.angles_from_direction(spherical_centroid(out))
    assert np.rad2deg(az) == pytest.approx(40.0, abs=0.5 * np.rad2deg(PITCH))
    assert np.rad2deg(el) == pytest.approx(20.0, abs=0.5 * np.rad2deg(PITCH))


@pytest.mark.parametrize("shift", [1, 5, -17, W // 2])
def test_yaw_by_pixel_multiple_is_exact_column_roll(shift):
    p = smooth_pano(seed=7)
    R = C.rotation_from_ypr(2 * math.pi * shift / W)
    for interp in ("linear", "cubic"):
        np.testing.assert_array_equal(rotate(p, R, interp), np.roll(p, shift, axis=1))
    t = to_numpy(rotate(to_torch(p), R))
    np.testing.assert_allclose(t, np.roll(p, shift, axis=1), atol=1e-4)


def test_rotate_identity_and_output_size_and_dtypes():
    p = smooth_pano()
    np.testing.assert_array_equal(rotate(p, np.eye(3)), p)
    assert rotate(p, np.eye(3), height=32).shape == (32, 64, 3)
    assert rotate(p[..., 0], np.eye(3)).shape == (H, W)
    assert rotate(p[..., :1], np.eye(3)).shape == (H, W, 1)
    assert rotate(p.astype(np.float64), np.eye(3)).dtype == np.float64
    assert rotate(p.astype(np.float16), np.eye(3)).dtype == np.float16
    img8 = (np.clip(p, 0, 1) * 255).astype(np.uint8)
    np.testing.assert_array_equal(rotate(img8, np.eye(3)), img8)
    five = np.concatenate([p, p[..., :2]], axis=-1)
    np.testing.assert_array_equal(rotate(five, np.eye(3)), five)


def test_torch_batched_rotations_and_unbatched_input():
    p = smooth_pano()
    t = to_torch(p)
    Rs = torch.from_numpy(np.stack(ROTATIONS[:2]))
    out = rotate(torch.cat([t, t]), Rs)
    assert out.shape == (2, 3, H, W)
    for i in range(2):
        np.testing.assert_allclose(to_numpy(out[i : i + 1]), rotate(p, ROTATIONS[i]), atol=5e-4)
    single = rotate(t[0], torch.from_numpy(ROTATIONS[0]))
    assert single.shape == (3, H, W)
    np.testing.assert_allclose(single.numpy(), out[0].numpy(), atol=1e-6)


def test_gradients_flow_through_torch_rotate():
    """d/dR and d/dpano exist, and gradient descent recovers a rotation angle."""
    p = to_torch(smooth_pano(24)).double()
    yaw_true, pitch_true = 0.3, -0.2
    zero = torch.zeros((), dtype=torch.float64)
    R_true = C.rotation_from_ypr(torch.tensor(yaw_true, dtype=torch.float64), torch.tensor(pitch_true).double(), zero)
    target = rotate(p, R_true)
    params = torch.tensor([0.15, 0.0], dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([params], lr=0.03)
    for _ in range(60):
        opt.zero_grad()
        loss = ((rotate(p, C.rotation_from_ypr(params[0], params[1], zero)) - target) ** 2).mean()
        loss.backward()
        opt.step()
    assert abs(params[0].item() - yaw_true) < 5e-3 and abs(params[1].item() - pitch_true) < 5e-3
    img = p.clone().requires_grad_()
    rotate(img, torch.from_numpy(ROTATIONS[0]))[:, :, 10, 20].sum().backward()
    assert img.grad.abs().sum() > 0 and torch.isfinite(img.grad).all()


def test_bad_input_raises_solidkit_errors():
    with pytest.raises(PanoramaError):
        rotate(np.zeros((10, 30, 3), np.float32), np.eye(3))
    with pytest.raises(InputError):
        rotate(smooth_pano(), np.eye(4))
    with pytest.raises(InputError):
        rotate(smooth_pano(), np.eye(3), interp="lanczos")
    with pytest.raises(InputError):
        downsample(smooth_pano(), 3)


# --- energy-preserving resizing ---------------------------------------------------------


def integral(p: np.ndarray) -> np.ndarray:
    """sum over pixels of radiance x solid angle, per channel."""
    omega = C.solid_angle(p.shape[0])
    return (p.astype(np.float64) * omega[..., None]).sum((0, 1))


def hdr_sky(height: int) -> np.ndarray:
    """A positive HDR panorama with a bright disk high in the sky (where rows differ most in solid angle)."""
    d = C.direction_grid(height)
    sun = C.direction_from_angles(np.deg2rad(40.0), np.deg2rad(85.0))
    p = 0.5 + 0.4 * smooth_field(d, seed=2) / 4 + 500.0 * blob(d, sun, np.deg2rad(3.0))[..., None]
    return p.astype(np.float32)


@pytest.mark.parametrize("factor", [2, 4, 8])
def test_downsample_preserves_integral_but_box_filter_does_not(factor):
    p = hdr_sky(128)
    ref = integral(p)
    ours = downsample(p, factor)
    assert ours.shape == (128 // factor, 256 // factor, 3) and ours.dtype == np.float32
    assert np.abs(integral(ours) / ref - 1).max() < 1e-6
    box = cv2.resize(p, (256 // factor, 128 // factor), interpolation=cv2.INTER_AREA)
    assert np.abs(integral(box) / ref - 1).max() > 5e-3  # a plain box filter is biased (0.8-20 %)


@pytest.mark.parametrize("height", [64, 50, 37, 13, 100, 200])
def test_resize_preserves_integral_for_any_size(height):
    p = hdr_sky(96)
    out = resize(p, height)
    assert out.shape == (height, 2 * height, 3)
    assert np.abs(integral(out) / integral(p) - 1).max() < 1e-6


def test_resize_equals_downsample_for_integer_factors_and_keeps_constants():
    p = hdr_sky(64)
    np.testing.assert_allclose(resize(p, 16), downsample(p, 4), rtol=1e-6)
    const = np.full((64, 128, 3), 2.5, np.float32)
    np.testing.assert_allclose(resize(const, 23), 2.5, rtol=1e-6)
    np.testing.assert_allclose(downsample(const, 8), 2.5, rtol=1e-6)


def test_torch_resizing_matches_numpy_and_is_differentiable():
    p = hdr_sky(64)
    t = to_torch(p).double().requires_grad_()
    np.testing.assert_allclose(to_numpy(downsample(t, 4)), downsample(p, 4), rtol=1e-5)
    np.testing.assert_allclose(to_numpy(resize(t, 27)), resize(p, 27), rtol=1e-5)
    resize(t, 27).sum().backward()
    assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0
    ref = integral(p)
    omega = C.solid_angle(27, torch, dtype=torch.float64)
    assert torch.allclose((resize(t, 27)[0] * omega).sum((-2, -1)), torch.from_numpy(ref), rtol=1e-6)


# --- CLI: solidkit envmap rotate / crop ---------------------------------------------------


def _cli(*args: str):
    from typer.testing import CliRunner

    from solidkit.cli import app

    return CliRunner().invoke(app, ["envmap", *args])


def test_cli_rotate_writes_the_rotated_exr_with_provenance(tmp_path):
    from solidkit.envmap.io import read_exr, write_exr

    src = tmp_path / "in.exr"
    p = np.abs(smooth_pano(32)) + 0.1
    write_exr(src, p, {"exposure_time": 0.01})
    res = _cli("rotate", str(src), "-o", str(tmp_path / "out.exr"), "--yaw", "-30", "--pitch", "10", "--roll", "5")
    assert res.exit_code == 0, res.output
    out, meta = read_exr(tmp_path / "out.exr")
    R = C.rotation_from_ypr(math.radians(-30), math.radians(10), math.radians(5))
    np.testing.assert_allclose(out, rotate(p, R), atol=1e-6)
    assert meta["exposure_time"] == 0.01 and meta["provenance"]["yaw_deg"] == -30.0
    res = _cli("rotate", str(src), "-o", str(tmp_path / "cubic.exr"), "--yaw", "12", "--interp", "cubic")
    assert res.exit_code == 0 and read_exr(tmp_path / "cubic.exr")[0].min() >= 0


def test_cli_crop_writes_exr_and_tonemapped_png(tmp_path):
    from solidkit.envmap.io import read_exr, read_ldr, tonemap, write_exr

    src = tmp_path / "in.exr"
    p = np.abs(smooth_pano(64)) + 0.1
    write_exr(src, p)
    args = ["--hfov-deg", "80", "--yaw", "35", "--pitch", "-5", "--roll", "3", "--size", "64x48"]
    assert _cli("crop", str(src), "-o", str(tmp_path / "c.exr"), *args).exit_code == 0
    assert _cli("crop", str(src), "-o", str(tmp_path / "c.png"), *args).exit_code == 0
    from solidkit.envmap.perspective import perspective_crop

    R = C.rotation_from_ypr(math.radians(35), math.radians(-5), math.radians(3))
    expected = perspective_crop(p, R, (64, 48), fov=math.radians(80))
    exr, _ = read_exr(tmp_path / "c.exr")
    assert exr.shape == (48, 64, 3)
    np.testing.assert_allclose(exr, expected, atol=1e-6)
    png = read_ldr(tmp_path / "c.png")
    assert np.abs(png - tonemap(expected)).max() <= 1 / 255 + 1e-6


def test_cli_ldr_round_trip_keeps_srgb(tmp_path):
    from solidkit.envmap.io import read_ldr, write_ldr

    src = tmp_path / "in.png"
    img = (np.clip(smooth_pano(32) / 8 + 0.5, 0, 1) * 255).round().astype(np.uint8)
    write_ldr(src, img)
    assert _cli("rotate", str(src), "-o", str(tmp_path / "out.png"), "--yaw", str(360 / 64 * 3)).exit_code == 0
    np.testing.assert_allclose(read_ldr(tmp_path / "out.png"), np.roll(img, 3, axis=1) / 255, atol=1 / 255 + 1e-6)


@pytest.mark.parametrize(
    "args",
    [
        ["rotate", "{bad}", "-o", "{out}.exr"],  # W != 2H
        ["rotate", "{missing}", "-o", "{out}.exr"],
        ["rotate", "{good}", "-o", "{out}.txt"],  # unknown output type
        ["rotate", "{good}", "-o", "{good}"],  # would overwrite the input
        ["crop", "{good}", "-o", "{out}.exr", "--hfov-deg", "90", "--size", "64"],
        ["crop", "{good}", "-o", "{out}.exr", "--hfov-deg", "190", "--size", "64x48"],
        ["crop", "{nan}", "-o", "{out}.exr", "--hfov-deg", "90", "--size", "64x48"],
    ],
)
def test_cli_bad_input_is_a_solidkit_error(tmp_path, args):
    from solidkit.envmap.io import write_exr
    from solidkit.errors import SolidkitError

    good, bad, nan = tmp_path / "good.exr", tmp_path / "bad.exr", tmp_path / "nan.exr"
    write_exr(good, np.ones((16, 32, 3), np.float32))
    write_exr(bad, np.ones((16, 30, 3), np.float32))
    pix = np.ones((16, 32, 3), np.float32)
    pix[3, 4, 1] = np.nan
    write_exr(nan, pix)
    names = {"good": good, "bad": bad, "nan": nan, "missing": tmp_path / "none.exr", "out": tmp_path / "out"}
    res = _cli(*[a.format(**names) for a in args])
    assert res.exit_code != 0 and isinstance(res.exception, SolidkitError), res.output
    assert not (tmp_path / "out.exr").exists()
    assert good.stat().st_size > 0


def test_cli_error_is_one_line_and_exit_code_2(tmp_path):
    import subprocess
    import sys

    bad = tmp_path / "bad.exr"
    from solidkit.envmap.io import write_exr

    write_exr(bad, np.ones((16, 30, 3), np.float32))
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "solidkit.cli",
            "envmap",
            "crop",
            str(bad),
            "-o",
            str(tmp_path / "o.png"),
            "--hfov-deg",
            "60",
            "--size",
            "32x24",
        ],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2
    assert run.stderr.strip().count("\n") == 0 and "width must be 2 x height" in run.stderr
    assert "Traceback" not in run.stderr + run.stdout


def test_torch_paths_stay_on_the_input_device():
    """Every torch op runs on the input's device (checked on 'meta': mixing devices would raise)."""
    from solidkit.envmap.cubemap import cube_from_equirect, equirect_from_cube
    from solidkit.envmap.perspective import embed_perspective, intrinsics_from_fov, perspective_crop

    dev = "meta"
    p = torch.empty(2, 3, 16, 32, device=dev)
    R = torch.as_tensor(ROTATIONS[0], dtype=torch.float32, device=dev)
    K = intrinsics_from_fov(1.0, 8, 6)
    outs = [
        rotate(p, R),
        rotate(p, torch.stack([R, R])),
        perspective_crop(p, R, (8, 6), K=K),
        embed_perspective(torch.empty(2, 3, 6, 8, device=dev), K, R, 16)[1],
        cube_from_equirect(p, 8),
        equirect_from_cube(torch.empty(2, 6, 3, 8, 8, device=dev), 16),
        resize(p, 7),
        downsample(p, 2),
    ]
    assert all(o.device.type == dev for o in outs)
