"""The SOLID-Net losses (paper §4.3): zero for identical inputs, positive otherwise, analytic SH cases."""

from __future__ import annotations

import math

import pytest
import torch

from solidkit.envmap.coords import rotation_from_ypr
from solidkit.envmap.sh import sh_irradiance, sh_project
from solidkit.model.losses import (
    albedo_loss,
    diffuse_loss,
    distance_loss,
    hdr_l1_loss,
    non_shadow_mask,
    normal_loss,
    reconstruction_loss,
    sh_shading,
    shadow_loss,
    sup2_loss,
    tonemapped_ssim_loss,
)

pytestmark = pytest.mark.usefixtures("torch_one_thread")


G = torch.Generator().manual_seed(0)


def _rand(*shape):
    return torch.rand(*shape, generator=G)


def _unit(*shape):
    return torch.nn.functional.normalize(torch.randn(*shape, generator=G), dim=1)


def test_constant_sky_sh_relighting_matches_analytic_value():
    """A constant sky c: its SH is c b_0, the paper's D is c/2 everywhere, so the Lambertian sphere
    relit with sh_irradiance(sh_project(sky)) gives c/2 for every normal and L_dif vanishes."""
    c = torch.tensor([2.0, 1.0, 0.5])
    sky = c.view(1, 3, 1, 1).expand(2, 3, 64, 128).contiguous()
    L = sh_irradiance(sh_project(sky))
    assert torch.allclose(L[..., 0], c / 2, atol=1e-5) and L[..., 1:].abs().max() < 1e-5
    normals = _unit(2, 3, 10, 12)
    shade = sh_shading(
        normals, L, rotation_from_ypr(torch.tensor([0.0, 0.0]), torch.tensor([0.3, -0.2]), torch.tensor([0.1, 0.0]))
    )
    assert torch.allclose(shade, (c / 2).view(1, 3, 1, 1).expand_as(shade), atol=1e-5)
    assert diffuse_loss(sky, L) < 1e-6
    assert diffuse_loss(sky, L * 1.2) > 1e-3


def test_sh_shading_rotates_normals_into_panorama_frame():
    """L = b_y only (the y = down coefficient): shading = n_y in the panorama frame, so a camera
    pitched by t sees its camera-frame normal (0, -1, 0) at n_y = -cos t."""
    L = torch.zeros(1, 3, 9)
    L[..., 2] = 1.0
    n = torch.zeros(1, 3, 1, 1)
    n[:, 1] = -1.0
    t = 0.4
    R = rotation_from_ypr(torch.tensor([0.0]), torch.tensor([t]), torch.tensor([0.0]))
    assert torch.allclose(sh_shading(n, L, R), torch.full((1, 3, 1, 1), -math.cos(t)), atol=1e-6)


@pytest.mark.parametrize(
    "loss,shape",
    [(albedo_loss, (2, 3, 8, 8)), (distance_loss, (2, 1, 8, 8)), (shadow_loss, (2, 1, 8, 8))],
)
def test_pixel_losses_zero_for_identical_positive_otherwise(loss, shape):
    a, b = _rand(*shape), _rand(*shape)
    assert loss(a, a) == 0
    assert loss(a, b) > 0
    mask = torch.zeros(shape[0], 1, *shape[2:], dtype=torch.bool)
    mask[..., :4, :] = True
    b2 = a.clone()
    b2[..., 4:, :] += 1.0  # differences only outside the mask
    assert loss(a, b2, mask) == 0 and loss(a, b2) > 0


def test_normal_loss():
    n = _unit(2, 3, 8, 8)
    assert normal_loss(n, n).abs() < 1e-6
    assert torch.isclose(normal_loss(n, -n), torch.tensor(2.0))
    assert normal_loss(n, _unit(2, 3, 8, 8)) > 0


def test_hdr_losses():
    h = _rand(2, 3, 16, 32) * 100
    y = torch.log1p(h)
    assert hdr_l1_loss(y, h) < 1e-6
    assert hdr_l1_loss(y, h * 2) > 0.1
    local = _rand(2, 4, 3, 16, 32) * 10
    assert sup2_loss(torch.log1p(local), local) < 1e-6 and sup2_loss(torch.log1p(local), local + 1) > 0


def test_tonemapped_ssim_loss():
    h = _rand(3, 3, 32, 64) * 3
    assert tonemapped_ssim_loss(h, h) < 1e-6
    assert tonemapped_ssim_loss(h, h.flip(-1)) > 0.01
    assert tonemapped_ssim_loss(h.view(1, 3, 3, 32, 64), (h * 0.3).view(1, 3, 3, 32, 64)) > 0.001


def test_reconstruction_loss_zero_for_a_consistent_rendering():
    albedo = _rand(2, 3, 12, 16) * 0.8 + 0.1
    normal = _unit(2, 3, 12, 16)
    L = torch.zeros(2, 3, 9)
    L[..., 0] = 0.8
    L[..., 2] = -0.3  # brighter when facing up (-y)
    R = rotation_from_ypr(torch.zeros(2), torch.tensor([0.1, -0.05]), torch.tensor([0.0, 0.1]))
    image = (albedo * sh_shading(normal, L, R)) ** (1 / 2.2)
    mask = torch.ones(2, 1, 12, 16, dtype=torch.bool)
    assert reconstruction_loss(image, albedo, normal, L, mask, R) < 1e-10
    assert reconstruction_loss(image, albedo * 0.5, normal, L, mask, R) > 1e-3
    # a pixel that differs is ignored once masked out
    bad = image.clone()
    bad[:, :, 0, 0] = 0.0
    mask[:, :, 0, 0] = False
    assert reconstruction_loss(bad, albedo, normal, L, mask, R) < 1e-10


def test_non_shadow_mask_otsu():
    s = torch.full((2, 1, 10, 10), 0.9)
    s[0, :, :, :4] = 0.1  # shadowed band
    s[0, :, 0, 0] = 0.3  # weak inter-reflection: still shadow
    m = non_shadow_mask(s)
    assert m.dtype == torch.bool
    assert m[0, :, :, 4:].all() and not m[0, :, :, :4].any()
    assert m[1].all()  # a flat, lit map has no split: all lit
    valid = torch.ones_like(m)
    valid[..., 9, :] = False
    assert not non_shadow_mask(s, valid)[..., 9, :].any()


# --- hand-computed pins of the paper's loss functions (§4.3, eq. 4, 5, 7): an L1 where the paper says L2
# (or the reverse), a sum instead of a mean or a dropped mask changes these numbers.
def _img(*values):
    return torch.tensor(values, dtype=torch.float64).view(1, 1, 1, -1)


def test_sup1_pixel_losses_pinned():
    pred, target = _img(0.0, 0.0), _img(1.0, 3.0)
    assert albedo_loss(pred, target).item() == 5.0  # L2: (1 + 9) / 2
    assert shadow_loss(pred, target).item() == 5.0  # L2
    assert distance_loss(pred, target).item() == 2.0  # L1: (1 + 3) / 2
    second = torch.tensor([False, True]).view(1, 1, 1, 2)
    assert albedo_loss(pred, target, second).item() == 9.0 and distance_loss(pred, target, second).item() == 3.0
    nothing = torch.zeros(1, 1, 1, 2, dtype=torch.bool)
    assert albedo_loss(pred, target, nothing).item() == 0.0  # an empty mask is 0, not NaN


def test_normal_cosine_loss_pinned():
    x = torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1)
    y = torch.tensor([0.0, 1.0, 0.0]).view(1, 3, 1, 1)
    at60 = torch.tensor([0.5, math.sqrt(3) / 2, 0.0]).view(1, 3, 1, 1)
    assert normal_loss(x, y).item() == pytest.approx(1.0)  # 1 - cos 90°
    assert normal_loss(-x, x).item() == pytest.approx(2.0)  # opposite
    assert normal_loss(at60, x).item() == pytest.approx(0.5, abs=1e-6)  # 1 - cos 60°
    assert normal_loss(3.0 * x, x).item() == pytest.approx(0.0, abs=1e-7)  # the length of the prediction is ignored


def test_sky_and_local_l1_in_log1p_pinned():
    target = _img(0.0, math.e - 1.0)  # log1p: 0, 1
    pred_log = _img(0.5, 0.0)
    assert hdr_l1_loss(pred_log, target).item() == pytest.approx(0.75)  # (|0.5 - 0| + |0 - 1|) / 2; an L2 gives 0.625
    assert sup2_loss(pred_log, target).item() == pytest.approx(0.75)


def test_reconstruction_and_diffuse_losses_pinned():
    """L_rec with a constant SH (shading = L_0 for every normal): ((I - (A L_0)^(1/2.2))^2, masked mean."""
    L = torch.zeros(1, 3, 9, dtype=torch.float64)
    L[..., 0] = 0.25
    normals = _unit(1, 3, 1, 2).double()
    image = torch.full((1, 3, 1, 2), 0.5, dtype=torch.float64)
    image[..., 1] = 0.9  # masked out below
    albedo = torch.ones(1, 3, 1, 2, dtype=torch.float64)
    mask = torch.tensor([True, False]).view(1, 1, 1, 2)
    expected = (0.5 - 0.25 ** (1 / 2.2)) ** 2  # 0.0010575...
    assert reconstruction_loss(image, albedo, normals, L, mask).item() == pytest.approx(expected, rel=1e-9)
    # L_dif of a constant sky c: D(H) = c / 2; relit with L_0 = 0.6 c the error is (0.1 c)^2, channel mean
    c = torch.tensor([2.0, 1.0, 0.5], dtype=torch.float64)
    sky = c.view(1, 3, 1, 1).expand(1, 3, 32, 64).contiguous()
    L = torch.zeros(1, 3, 9, dtype=torch.float64)
    L[..., 0] = 0.6 * c
    assert diffuse_loss(sky, L).item() == pytest.approx(
        ((0.1 * c) ** 2).mean().item(), rel=1e-3
    )  # 0.0175; D on a 32x64 grid
