"""Second-order SH (the paper's basis), projection, Lambertian filtering and the diffuse convolution D."""

import math

import numpy as np
import pytest
import torch

from solidkit.envmap import coords as C
from solidkit.envmap import sh
from solidkit.errors import InputError, PanoramaError


@pytest.fixture
def rng():
    """A fresh generator per test: results do not depend on test order (pytest-xdist)."""
    return np.random.default_rng(7)


def unit(n):
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def nchw(pano_hwc):
    """NumPy (H, W, C) -> torch float64 (1, C, H, W)."""
    return torch.from_numpy(np.ascontiguousarray(np.moveaxis(pano_hwc, -1, 0)))[None]


def naive_diffuse(pano, normals, height):
    """The paper's eq. 6 written out directly, one normal at a time (independent of sh.py)."""
    d = C.direction_grid(height).reshape(-1, 3)
    s = C.solid_angle(height).reshape(-1)
    h = pano.reshape(-1, pano.shape[-1])
    out = []
    for n in normals.reshape(-1, 3):
        cos = d @ n
        inside = cos > 1e-6
        tie = np.abs(cos) <= 1e-6  # boundary pixels count half in K_i (see sh._TIE)
        k_i = s[inside].sum() + 0.5 * s[tie].sum()
        out.append((h[inside] * (s[inside] * cos[inside])[:, None]).sum(0) / k_i)
    return np.array(out).reshape(normals.shape[:-1] + (pano.shape[-1],))


# ---------------------------------------------------------------------------------------- basis


def test_basis_matches_paper_formula_numpy_and_torch(rng):
    n = unit(rng.normal(size=(50, 3)))
    x, y, z = n.T
    expected = np.stack([np.ones_like(x), x, y, z, 3 * z**2 - 1, x * y, x * z, y * z, x**2 - y**2], -1)
    np.testing.assert_allclose(sh.sh_basis(n), expected, atol=1e-15)
    np.testing.assert_allclose(sh.sh_basis(torch.from_numpy(n)).numpy(), expected, atol=1e-15)
    assert sh.sh_basis(n.reshape(5, 10, 3)).shape == (5, 10, 9)


def test_orthonormal_scale_matches_ramamoorthi_hanrahan_and_integrates_to_identity():
    # RH01 eq. 3 constants, in the paper's order [1, x, y, z, 3z^2-1, xy, xz, yz, x^2-y^2]
    rh = [0.282095, 0.488603, 0.488603, 0.488603, 0.315392, 1.092548, 1.092548, 1.092548, 0.546274]
    np.testing.assert_allclose(sh.SH_ORTHONORMAL_SCALE, rh, atol=1e-6)
    h = 256
    y = sh.sh_basis(C.direction_grid(h)).reshape(-1, 9) * sh.SH_ORTHONORMAL_SCALE
    w = C.solid_angle(h).reshape(-1, 1)
    np.testing.assert_allclose(y.T @ (w * y), np.eye(9), atol=1e-4)
    b = y / sh.SH_ORTHONORMAL_SCALE
    np.testing.assert_allclose(b.T @ (w * b), sh.SH_GRAM, atol=1e-3 * sh.SH_GRAM.max())
    assert sh.SH_GRAM[0, 0] == pytest.approx(4 * math.pi) and sh.SH_GRAM[4, 4] == pytest.approx(16 * math.pi / 5)
    assert sh.SH_BANDS == (0, 1, 1, 1, 2, 2, 2, 2, 2)


# ----------------------------------------------------------------------------- projection/render


@pytest.mark.parametrize("h", [8, 32])
def test_projection_recovers_coefficients_numpy(h, rng):
    L = rng.normal(size=(3, 9))
    pano = sh.sh_render(L, C.direction_grid(h))  # (H, W, 3)
    assert pano.shape == (h, 2 * h, 3)
    Lp = sh.sh_project(pano)
    assert Lp.shape == (3, 9)
    assert np.abs(Lp - L).max() / np.abs(L).max() < 1e-6


def test_projection_recovers_coefficients_torch_batched_and_matches_numpy(rng):
    h = 32
    L = rng.normal(size=(2, 3, 9))
    d = C.direction_grid(h)
    panos = np.stack([sh.sh_render(L[i], d) for i in range(2)])  # (B, H, W, C)
    np.testing.assert_allclose(sh.sh_project(panos), L, rtol=0, atol=1e-9)  # NumPy batch (..., H, W, C)
    t = torch.from_numpy(np.ascontiguousarray(np.moveaxis(panos, -1, 1)))  # (B, C, H, W)
    Lt = sh.sh_project(t)
    assert Lt.shape == (2, 3, 9) and Lt.dtype == torch.float64
    np.testing.assert_allclose(Lt.numpy(), L, atol=1e-9)
    L32 = sh.sh_project(t.float())
    assert L32.dtype == torch.float32
    assert (L32.double() - torch.from_numpy(L)).abs().max() < 1e-4


def test_projection_of_smooth_map_is_stable_under_area_downsampling(rng):
    h = 64
    L = rng.normal(size=(3, 9))
    pano = sh.sh_render(L, C.direction_grid(h))
    np.testing.assert_allclose(sh.sh_project(pano, height=16), L, atol=2e-2 * np.abs(L).max())


def test_working_height_matches_resize_for_batched_numpy_and_torch(rng):
    from solidkit.envmap.resample import resize

    h = 32
    panos = rng.random((2, h, 2 * h, 3)) ** 4  # NumPy batch (B, H, W, C)
    ref = np.stack([sh.sh_project(resize(p, 8)) for p in panos])
    np.testing.assert_allclose(sh.sh_project(panos, height=8), ref, rtol=1e-12)
    t = torch.from_numpy(np.ascontiguousarray(np.moveaxis(panos, -1, 1)))
    np.testing.assert_allclose(sh.sh_project(t, height=8).numpy(), ref, rtol=1e-12)
    with pytest.raises(InputError):
        sh.sh_project(panos, height=0)


def test_render_and_lambertian_sphere(rng):
    h = 16
    L = rng.normal(size=(3, 9))
    d = C.direction_grid(h)
    sphere = sh.lambertian_sphere(L, h)
    assert sphere.shape == (h, 2 * h, 3)
    np.testing.assert_allclose(sphere, sh.sh_render(L, d), atol=1e-12)
    expected = sh.sh_basis(d) @ L.T
    np.testing.assert_allclose(sphere, expected, atol=1e-12)
    albedo = np.array([0.2, 0.5, 1.0])
    np.testing.assert_allclose(sh.lambertian_sphere(L, h, albedo), expected * albedo, atol=1e-12)
    t = sh.lambertian_sphere(torch.from_numpy(np.stack([L, 2 * L])), h)  # (B, C, H, W)
    assert t.shape == (2, 3, h, 2 * h)
    np.testing.assert_allclose(t[1].permute(1, 2, 0).numpy(), 2 * expected, atol=1e-12)


# --------------------------------------------------------------------------------- irradiance


def test_sh_irradiance_of_constant_environment_is_analytic(rng):
    c = np.array([0.3, 1.0, 2.5])
    pano = np.broadcast_to(c, (32, 64, 3)).copy()
    L = sh.sh_project(pano)
    n = unit(rng.normal(size=(20, 3)))
    np.testing.assert_allclose(
        sh.sh_render(sh.sh_irradiance(L, "irradiance"), n), np.tile(math.pi * c, (20, 1)), rtol=1e-9
    )
    np.testing.assert_allclose(sh.sh_render(sh.sh_irradiance(L, "radiance"), n), np.tile(c, (20, 1)), rtol=1e-9)
    np.testing.assert_allclose(sh.sh_render(sh.sh_irradiance(L), n), np.tile(c / 2, (20, 1)), rtol=1e-9)
    with pytest.raises(InputError):
        sh.sh_irradiance(L, "bogus")


def test_sh_irradiance_of_linear_environment_is_analytic(rng):
    a = rng.normal(size=3)
    L = np.zeros((1, 9))
    L[0, 1:4] = a  # H(w) = a . w
    n = unit(rng.normal(size=(20, 3)))
    np.testing.assert_allclose(
        sh.sh_render(sh.sh_irradiance(L, "irradiance"), n)[:, 0], 2 * math.pi / 3 * n @ a, rtol=1e-12
    )
    np.testing.assert_allclose(sh.sh_render(sh.sh_irradiance(L), n)[:, 0], n @ a / 3, rtol=1e-12)


# -------------------------------------------------------------------------- diffuse convolution


def test_diffuse_convolution_of_constant_map_is_half_the_constant():
    h = 64
    c = np.array([1.0, 4.0])
    D = sh.diffuse_convolution(np.broadcast_to(c, (h, 2 * h, 2)).copy())
    assert D.shape == (h, 2 * h, 2)
    # K_i is the pixels' solid angle (paper): c/2 up to the quadrature error, O(1/H^2)
    np.testing.assert_allclose(D, np.broadcast_to(c / 2, D.shape), rtol=2e-4)


def test_diffuse_convolution_of_linear_map_is_a_dot_n_over_three():
    h = 64
    a = np.array([0.4, -1.3, 0.8])
    d = C.direction_grid(h)
    D = sh.diffuse_convolution((d @ a)[..., None])[..., 0]
    # int_{w.n>0} (a.w)(w.n) dw = (2 pi / 3) a.n, divided by K = 2 pi
    assert np.abs(D - (d @ a) / 3).max() < 2e-4 * np.abs(a).max()


def test_diffuse_convolution_of_point_light():
    h = 32
    pano = np.zeros((h, 2 * h, 1))
    u, v = 40, 9
    pano[v, u, 0] = 1.0 / C.solid_angle(h)[v, u]  # unit power from one direction
    w = C.direction_from_coords(np.array(u + 0.5), np.array(v + 0.5), h)
    d = C.direction_grid(h)
    D = sh.diffuse_convolution(pano)[..., 0]
    np.testing.assert_allclose(D, np.maximum(d @ w, 0) / (2 * math.pi), atol=2e-3 / (2 * math.pi))


def test_full_grid_operator_equals_naive_sum_and_explicit_normals(rng):
    h = 8
    pano = rng.random((h, 2 * h, 3)) ** 3
    d = C.direction_grid(h)
    naive = naive_diffuse(pano, d, h)
    np.testing.assert_allclose(sh.diffuse_convolution(pano), naive, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(sh.diffuse_convolution(pano, d), naive, rtol=1e-12, atol=1e-14)
    n = unit(rng.normal(size=(4, 5, 3)))
    Dn = sh.diffuse_convolution(pano, n)
    assert Dn.shape == (4, 5, 3)
    np.testing.assert_allclose(Dn, naive_diffuse(pano, n, h), rtol=1e-12)


def test_sh_irradiance_agrees_with_diffuse_convolution_on_band_limited_maps(rng):
    h = 64
    L = rng.normal(size=(3, 9))
    d = C.direction_grid(h)
    pano = sh.sh_render(L, d)
    D = sh.diffuse_convolution(pano)
    S = sh.lambertian_sphere(sh.sh_irradiance(sh.sh_project(pano)), h)
    assert np.abs(D - S).max() / np.abs(S).max() < 1e-3


def test_sh_irradiance_approximates_diffuse_convolution_of_a_sky():
    # a smooth sky (bright zenith, dark ground, a soft sun): order-2 SH of the cosine lobe is a
    # known few-percent approximation (RH01: < 3% average error)
    h = 64
    d = C.direction_grid(h)
    sun = unit(np.array([0.5, -0.6, 0.6]))
    pano = (1.0 + np.maximum(-d[..., 1], 0) + 3 * np.exp(4 * (d @ sun - 1)))[..., None]
    D = sh.diffuse_convolution(pano)
    S = sh.lambertian_sphere(sh.sh_irradiance(sh.sh_project(pano)), h)
    assert np.abs(D - S).mean() / D.mean() < 0.03


def test_downsampled_source_error_is_small():
    h = 64
    d = C.direction_grid(h)
    sun = unit(np.array([-0.2, -0.8, 0.4]))
    pano = (0.5 + 20 * np.exp(50 * (d @ sun - 1)))[..., None]
    full = sh.diffuse_convolution(pano)
    coarse = sh.diffuse_convolution(pano, d, height=16)  # source area-downsampled 4x
    assert np.abs(coarse - full).max() / full.max() < 0.01
    assert sh.diffuse_convolution(pano, height=16).shape == (16, 32, 1)


def test_numpy_and_torch_agree_and_batch(rng):
    h = 16
    panos = rng.random((2, h, 2 * h, 3)) ** 2
    ref = sh.diffuse_convolution(panos)  # NumPy batch (B, H, W, C)
    np.testing.assert_allclose(ref[1], sh.diffuse_convolution(panos[1]), rtol=1e-12)
    t = torch.from_numpy(np.ascontiguousarray(np.moveaxis(panos, -1, 1)))
    Dt = sh.diffuse_convolution(t)
    assert Dt.shape == (2, 3, h, 2 * h)
    np.testing.assert_allclose(Dt.permute(0, 2, 3, 1).numpy(), ref, rtol=1e-10)
    D32 = sh.diffuse_convolution(t.float())
    assert D32.dtype == torch.float32
    np.testing.assert_allclose(D32.permute(0, 2, 3, 1).numpy(), ref, rtol=1e-4, atol=1e-6)
    n = unit(rng.normal(size=(7, 3)))
    Dn = sh.diffuse_convolution(t, torch.from_numpy(n))
    assert Dn.shape == (2, 3, 7)
    np.testing.assert_allclose(Dn.permute(0, 2, 1).numpy(), sh.diffuse_convolution(panos, n), rtol=1e-10)


def test_gradients_flow_in_torch():
    h = 2  # gradcheck differentiates numerically: keep it tiny
    pano = torch.rand(1, 2, h, 2 * h, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(sh.diffuse_convolution, (pano,))
    assert torch.autograd.gradcheck(sh.sh_project, (pano,))
    L = torch.randn(1, 2, 9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: sh.lambertian_sphere(x, h), (L,))
    # the paper's L_dif: both the sky map and the SH coefficients receive gradients
    sky = torch.rand(2, 3, 16, 32, requires_grad=True)
    coeffs = torch.randn(2, 3, 9, requires_grad=True)
    loss = ((sh.diffuse_convolution(sky) - sh.lambertian_sphere(coeffs, 16)) ** 2).mean()
    loss.backward()
    assert sky.grad.abs().sum() > 0 and coeffs.grad.abs().sum() > 0
    n = torch.nn.functional.normalize(torch.randn(5, 3, dtype=torch.float64), dim=-1).requires_grad_()
    sh.sh_render(L, n[:, None, :]).sum().backward()
    assert n.grad.abs().sum() > 0


def test_bad_input_is_a_clear_error():
    with pytest.raises(PanoramaError):
        sh.sh_project(np.zeros((8, 8, 3)))
    with pytest.raises(PanoramaError):
        sh.diffuse_convolution(torch.zeros(1, 3, 8, 8))
    with pytest.raises(PanoramaError):
        sh.sh_project(np.zeros((8, 16)))
    with pytest.raises(InputError):
        sh.diffuse_convolution(np.zeros((8, 16, 3)), np.zeros((4, 2)))
    with pytest.raises(InputError):
        sh.diffuse_convolution(np.zeros((512, 1024, 1)))
