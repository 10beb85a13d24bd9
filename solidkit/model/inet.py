"""I-Net (SOLID-Net stage 1, paper §4.2): intrinsics, SH lighting and the global HDR sky.

One encoder on the ``240 x 320`` LDR image; U-Net decoders (skip links) for diffuse albedo A,
surface normal N, plane distance G and shadow S; a lighting branch whose feature maps go through
a fully-connected layer to the 27 second-order SH coefficients ``P_SH`` (9 per RGB channel, the
paper's ``L in R^{3x9}``, basis :func:`solidkit.envmap.sh.sh_basis`); and a sky decoder that
turns ``P_SH`` into the ``128 x 256`` HDR sky ``H_g``.

Sky decoder (the paper: "we reshape this vector and upsample it 8 times, and then combine it by
flipping padded sky features"). Here ``P_SH`` is rendered (``L b(d)``, :func:`sh_render`) on the
panorama grid at 1/8 of the output height (16 x 32 for H = 128) and upsampled 8x by three
(x2 upsample, conv) stages. At every stage it is concatenated with *flip-padded sky features*:
the lighting branch's image feature map placed on the image's footprint on the panorama and
extended to the whole panorama by mirror tiling (alternately flipped copies, horizontally and
vertically), plus a ``sin(elevation)`` channel. The footprint (``config.sky_footprint``) is either
an ``hfov x vfov`` box around the forward direction at the horizon (``"level"``, the first
checkpoints: a camera pitched 15° up has its features 15° too low) or the image's own field of view,
pitch and roll (``"camera"``, :func:`camera_footprint_grid`), so a sun or a glow in the image lands
on its direction. The head outputs ``y = log1p(H_g)`` (see
:data:`solidkit.model.blocks.HDR_PARAMETERISATION`).

Frames: N is predicted in the camera frame (OpenCV: x right, y down, z forward); ``P_SH`` and
``H_g`` live in the panorama frame (docs/conventions.md §2), so using ``P_SH`` to shade N requires
the camera rotation (done in :mod:`solidkit.model.losses`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from solidkit.envmap.coords import angles_from_direction, angles_grid, direction_grid
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.envmap.sh import sh_basis
from solidkit.model.blocks import ConvBlock, Encoder, UNetDecoder, radiance_from_log, resize_to
from solidkit.model.config import SolidNetConfig
from solidkit.model.imagesun import put_sun_on_blob
from solidkit.model.sunhead import SunHead, render_sun, render_sun_with_aureole
from solidkit.model.sunnet import SunNet
from solidkit.model.sununcertainty import cone_radii, cones_deg
from solidkit.model.warp import camera_rotation

__all__ = ["INet", "camera_footprint_grid", "flip_pad", "image_footprint", "sh_panorama"]


def flip_pad(x: torch.Tensor, out_size: tuple[int, int], top: int, left: int) -> torch.Tensor:
    """Extend ``x (B, C, h, w)`` to ``out_size`` by mirror tiling, ``x`` itself placed at ``(top, left)``.

    Output pixel ``(i, j)`` takes ``x[r(i - top), c(j - left)]`` where ``r, c`` reflect their
    argument into ``[0, h)`` / ``[0, w)`` with period ``2h`` / ``2w`` (copies alternate between
    ``x`` and its flip), so the padding is continuous at every copy's border.
    """
    h, w = x.shape[-2:]
    H, W = out_size

    def reflect(n: int, start: int, size: int) -> torch.Tensor:
        t = (torch.arange(n, device=x.device) - start) % (2 * size)
        return torch.where(t < size, t, 2 * size - 1 - t)

    return x[:, :, reflect(H, top, h)][:, :, :, reflect(W, left, w)]


def image_footprint(pano_height: int, hfov_deg: float, vfov_deg: float) -> tuple[int, int, int, int]:
    """``(height, width, top, left)`` in pixels of a camera's field of view centred on the panorama's
    forward direction at the horizon (an approximation that ignores pitch and roll)."""
    W = 2 * pano_height
    fw = max(1, round(W * hfov_deg / 360.0))
    fh = max(1, round(pano_height * vfov_deg / 180.0))
    return fh, fw, (pano_height - fh) // 2, (W - fw) // 2


def _mirror(t: torch.Tensor) -> torch.Tensor:
    """Reflect normalised coordinates into ``[-1, 1]`` with period 4 (alternately flipped copies)."""
    return 1.0 - torch.abs(torch.remainder(t + 1.0, 4.0) - 2.0)


def camera_footprint_grid(
    pano_height: int, K: torch.Tensor, pitch: torch.Tensor, roll: torch.Tensor, image_size: tuple[int, int]
) -> torch.Tensor:
    """``grid_sample`` grid ``(B, H, 2H, 2)`` that places an image's features on the panorama at their directions.

    Every panorama direction ``d`` (panorama frame, conventions §2) is turned into the camera frame,
    ``c = R_cam^T d`` with ``R_cam = R(0, pitch, roll)``; its azimuth / elevation in that frame, divided by
    the image's half fields of view (``atan(W / 2 fx)``, ``atan(H / 2 fy)`` from ``K (B, 3, 3)``,
    pixels of an image of ``image_size = (H, W)``), are the normalised image coordinates, mirror-reflected
    outside the image. With ``pitch = roll = 0`` and the config's ``hfov`` this is the ``"level"`` box
    of :func:`image_footprint` (up to the resampling).
    """
    h, w = image_size
    dirs = direction_grid(pano_height, torch, dtype=K.dtype, device=K.device)  # (H, 2H, 3)
    R = camera_rotation(pitch, roll).to(K.dtype)  # (B, 3, 3) camera -> panorama
    cam = torch.einsum("bji,hwj->bhwi", R, dirs)
    phi, theta = angles_from_direction(cam)
    half_h = torch.atan(0.5 * w / K[:, 0, 0])[:, None, None]
    half_v = torch.atan(0.5 * h / K[:, 1, 1])[:, None, None]
    return torch.stack([_mirror(phi / half_h), _mirror(-theta / half_v)], dim=-1)


def sh_panorama(L: torch.Tensor, height: int) -> torch.Tensor:
    """``L b(d)`` over the equirect grid: ``(B, C, height, 2 height)`` from ``L (B, C, 9)``."""
    basis = sh_basis(direction_grid(height, torch, dtype=L.dtype, device=L.device))  # (H, W, 9)
    return torch.einsum("bck,hwk->bchw", L, basis)


def _upsample_panorama(x: torch.Tensor, height: int) -> torch.Tensor:
    """Bilinear upsampling of ``(B, C, h, 2h)`` to ``(B, C, height, 2 height)``, continuous across the seam."""
    h = x.shape[-2]
    if h == height:
        return x
    s = height // h
    x = F.pad(x, (1, 1, 0, 0), mode="circular")
    return F.interpolate(x, scale_factor=float(s), mode="bilinear", align_corners=False)[..., s:-s]


class INet(nn.Module):
    """I-Net: ``image (B, 3, H, W)`` in [0, 1] (sRGB LDR) -> dict of intrinsics and lighting.

    Output keys (all float32, ``B`` leading):

    - ``albedo`` (B, 3, H, W) in [0, 1] (sigmoid)
    - ``normal`` (B, 3, H, W) unit vectors, camera frame
    - ``distance`` (B, 1, H, W) plane distance ``p`` in metres, >= 0 (softplus)
    - ``shadow`` (B, 1, H, W) in [0, 1], 1 = lit, 0 = fully shadowed (sigmoid)
    - ``sh`` (B, 3, 9) the SH coefficients ``L`` (the paper's ``P_SH`` reshaped)
    - ``sky_log`` (B, 3, Hp, 2Hp) ``log1p(H_g)``; ``sky`` (B, 3, Hp, 2Hp) the radiance ``H_g``

    With ``config.sun_head`` (:mod:`solidkit.model.sunhead`; with ``config.sun_net`` the separate
    low-resolution :mod:`solidkit.model.sunnet` instead) also ``sun_logits (B, 1, Hp, 2Hp)``,
    ``sun_dir (B, 3)``, ``sun_energy``, ``sun_log_energy (B, 3)``, ``sun_sigma (B,)`` and
    ``sky_np_log`` (the non-parametric sky without the sun); ``sky`` is then the non-parametric sky
    plus the rendered sun. With ``config.sun_visibility`` also ``sun_visible (B,)`` (probability) and
    ``sun_visible_logit``; in eval mode no sun is added to a sky where it is below 0.5.
    """

    def __init__(self, config: SolidNetConfig) -> None:
        super().__init__()
        self.config = config
        w = config.widths
        self.encoder = Encoder(3, w)
        self.decoders = nn.ModuleDict(
            {
                "albedo": UNetDecoder(w, 3, extra_in=3),
                "normal": UNetDecoder(w, 3, extra_in=3),
                "distance": UNetDecoder(w, 1, extra_in=3),
                "shadow": UNetDecoder(w, 1, extra_in=3),
            }
        )
        lw = config.light_width
        self.light = nn.Sequential(ConvBlock(w[-1], lw), ConvBlock(lw, lw))
        self.light_pool = nn.AdaptiveAvgPool2d((3, 4))
        self.light_fc = nn.Linear(lw * 12, 27)
        mid = min(2, len(w) - 1)  # the 1/8-resolution level provides the sky features
        self._sky_level = mid
        sf = config.sky_feature_width or lw
        self.sky_features = ConvBlock(w[mid] + lw, sf)
        sw = config.sky_widths
        self.sky_in = nn.Sequential(ConvBlock(3 + sf + 1, sw[0], panorama=True), ConvBlock(sw[0], sw[0], panorama=True))
        stages = config.sky_stages
        self.sky_ups = nn.ModuleList(ConvBlock(sw[i] + 3 + sf + 1, sw[i + 1], panorama=True) for i in range(stages - 1))
        self.sky_head = nn.Conv2d(sw[stages - 1], 3, 1)
        if config.sun_net:
            self.sun: nn.Module | None = SunNet(
                config.sun_net,
                config.sun_net_size,
                logit_height=config.pano_height // 2,
                coarse_height=min(16, config.pano_height // 2),
            )
        elif config.sun_head:
            self.sun = SunHead(lw * 12, sw[stages - 1], visibility=config.sun_visibility, fine=config.sun_fine)
        else:
            self.sun = None
        self._footprints = [
            image_footprint(config.pano_height >> (3 - k), config.hfov_deg, config.vfov_deg) for k in range(4)
        ]

    def _sky_stage_inputs(self, L: torch.Tensor, feats: torch.Tensor, k: int, camera: tuple | None) -> torch.Tensor:
        h = self.config.pano_height >> (3 - k)
        shading = torch.log1p(sh_panorama(L, h).clamp_min(0.0))
        if camera is None:
            fh, fw, top, left = self._footprints[k]
            padded = flip_pad(resize_to(feats, (fh, fw)), (h, 2 * h), top, left)
        else:
            grid = camera_footprint_grid(h, *camera)
            padded = F.grid_sample(
                feats, grid.to(feats.dtype), mode="bilinear", padding_mode="border", align_corners=False
            )
        _, theta = angles_grid(h, torch, dtype=L.dtype, device=L.device)
        elev = torch.sin(theta).expand(L.shape[0], 1, h, 2 * h)
        return torch.cat([shading, padded, elev], dim=1)

    def forward(
        self,
        image: torch.Tensor,
        intrinsics: bool = True,
        K: torch.Tensor | None = None,
        pitch: torch.Tensor | None = None,
        roll: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """``intrinsics=False`` skips the A/N/G/S decoders (lighting outputs only: sky-only training).

        ``K (B, 3, 3)`` (pixels of ``image``), ``pitch``, ``roll`` ``(B,)`` (radians, conventions §4) place
        the sky features with ``config.sky_footprint = "camera"``; missing ones default to the config's
        ``hfov_deg`` and a level camera. The ``"level"`` footprint ignores them.
        """
        size = tuple(image.shape[-2:])
        b = image.shape[0]
        if K is None:
            K = torch.as_tensor(
                intrinsics_from_fov(math.radians(self.config.hfov_deg), size[1], size[0]),
                dtype=image.dtype,
                device=image.device,
            ).expand(b, 3, 3)
        zeros = image.new_zeros(b)
        view = (K.to(image), zeros if pitch is None else pitch.to(image), zeros if roll is None else roll.to(image))
        camera = (*view, size) if self.config.sky_footprint == "camera" else None
        x = image * 2.0 - 1.0
        feats = self.encoder(x)
        out: dict[str, torch.Tensor] = {}
        if intrinsics:
            out["albedo"] = torch.sigmoid(self.decoders["albedo"](feats, size, x))
            out["normal"] = F.normalize(self.decoders["normal"](feats, size, x), dim=1, eps=1e-6)
            out["distance"] = F.softplus(self.decoders["distance"](feats, size, x))
            out["shadow"] = torch.sigmoid(self.decoders["shadow"](feats, size, x))
        light = self.light(feats[-1])
        pooled = torch.flatten(self.light_pool(light), 1)
        L = self.light_fc(pooled).view(-1, 3, 9)
        out["sh"] = L
        mid = feats[self._sky_level]
        sky_feats = self.sky_features(torch.cat([mid, resize_to(light, mid.shape[-2:])], dim=1))
        y = self.sky_in(self._sky_stage_inputs(L, sky_feats, 0, camera))
        for k, up in enumerate(self.sky_ups, start=1):
            y = F.interpolate(y, scale_factor=2.0, mode="bilinear", align_corners=False)
            y = up(torch.cat([y, self._sky_stage_inputs(L, sky_feats, k, camera)], dim=1))
        sky_log = _upsample_panorama(F.softplus(self.sky_head(y)), self.config.pano_height)
        if self.sun is None:
            out["sky_log"] = sky_log
            out["sky"] = radiance_from_log(sky_log)
            return out
        out.update(self.sun(image, *view) if self.config.sun_net else self.sun(pooled, y))
        if not self.training:
            self.finish_sun(out, image, view)
        # the size is learnt from its own loss only (losses.sun_size_loss): through the radiance terms it
        # would grow to hedge an uncertain direction
        sigma = out["sun_sigma"].detach()
        if not self.training and self.config.sun_aureole and "sun_cone_radius_deg" in out:
            # the network's own 68 % radius, not the calibrated cone: recalibrating the stated uncertainty for
            # another domain leaves the sky the aureole was tuned for
            sun = render_sun_with_aureole(
                out["sun_dir"],
                out["sun_energy"],
                sigma,
                out["sun_cone_radius_deg"][:, 0],
                self.config.sun_aureole,
                self.config.pano_height,
            )
        else:
            sun = render_sun(out["sun_dir"], out["sun_energy"], sigma, self.config.pano_height)
        if "sun_visible" in out:
            # a sun only in skies that have one: soft while training, a decision at evaluation
            gate = (
                out["sun_visible"]
                if self.training
                else (out["sun_visible"] >= self.config.sun_visibility_threshold).to(sun.dtype)
            )
            sun = sun * gate[:, None, None, None]
        out["sky_np_log"] = sky_log
        out["sky"] = radiance_from_log(sky_log) + sun
        out["sky_log"] = torch.log1p(out["sky"])
        return out

    def finish_sun(
        self, out: dict[str, torch.Tensor], image: torch.Tensor, view: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    ) -> None:
        """The network's sun moved onto a sun-like image blob (``config.sun_in_image``; ``sun_on_blob (B,)``;
        with ``config.sun_blob_visibility`` a blob may also make the sun visible, ``sun_visible`` raised to the
        threshold) and its cones (``sun_cone_deg (B, 2)``: 68 % / 90 %, calibrated where the config has the scales)."""
        on = torch.zeros(image.shape[0], dtype=torch.bool, device=image.device)
        if self.config.sun_in_image and "sun_visible" in out:
            out["sun_dir"], on, promoted = put_sun_on_blob(
                out["sun_dir"],
                out["sun_visible"],
                image,
                *view,
                threshold=self.config.sun_visibility_threshold,
                logits=out.get("sun_logits"),
                gate_deg=self.config.sun_blob_gate_deg,
                promote=self.config.sun_blob_visibility,
            )
            if bool(promoted.any()):  # the visibility after the image's own cue: at the threshold where a blob decided
                t = torch.full_like(out["sun_visible"], self.config.sun_visibility_threshold)
                out["sun_visible"] = torch.where(promoted, torch.maximum(out["sun_visible"], t), out["sun_visible"])
        out["sun_on_blob"] = on
        if "sun_logits" in out:
            radii = cone_radii(out["sun_logits"], out["sun_dir"])
            cones = cones_deg(radii, self.config.sun_cone_scale) if self.config.sun_cone_scale else radii
            out["sun_cone_radius_deg"] = radii
            out["sun_cone_deg"] = cones

    @property
    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())
