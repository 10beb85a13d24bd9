"""SOLID-Net: I-Net + panoramic warping + P-Net, checkpoints and ``predict``.

Batch format (what :meth:`SolidNet.forward` and :func:`solidkit.model.losses.solidnet_losses` use),
``B`` images with ``N`` probe pixels each:

=================  ==========================  =================================================
key                shape                       meaning
=================  ==========================  =================================================
image              (B, 3, 240, 320)            LDR input in [0, 1] (sRGB-encoded)
K                  (B, 3, 3)                   intrinsics of that image (pixels, OpenCV)
pitch, roll        (B,)                        camera pitch and roll, radians (conventions §4)
pixels             (B, N, 2)                   probe pixels ``(x, y)`` in the image
albedo             (B, 3, 240, 320)            ground truth (training only, as below)
normal             (B, 3, 240, 320)            unit normals, camera frame
distance           (B, 1, 240, 320)            plane distance p (metres), ``n . P + p = 0``
shadow             (B, 1, 240, 320)            1 = lit, 0 = fully shadowed
geometry_mask      (B, 1, 240, 320) bool       pixels with geometry (not sky); optional
sky                (B, 3, 128, 256)            global HDR sky H_g (radiance)
local              (B, N, 3, 128, 256)         local HDR probes H_l (radiance)
=================  ==========================  =================================================

Checkpoints are ``torch.save`` dicts holding the weights, the :class:`SolidNetConfig`, the
conventions version (docs/conventions.md) and a free-form ``card`` (data, steps, hardware, seed);
:func:`load_checkpoint` refuses files of another format or conventions version with a
:class:`CheckpointError` / :class:`~solidkit.errors.ConventionsError`.
"""

from __future__ import annotations

import io
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch import nn

from solidkit.envmap.coords import CONVENTIONS_VERSION, angles_from_direction
from solidkit.envmap.io import decode_ldr, read_ldr, tonemap
from solidkit.envmap.perspective import intrinsics_from_fov, scale_intrinsics, scale_pixel_coordinates
from solidkit.envmap.sun import Method, detect_sun
from solidkit.errors import ConventionsError, InputError, SolidkitError
from solidkit.fsutil import atomic_write_bytes
from solidkit.model.config import ConfigError, SolidNetConfig, preset
from solidkit.model.inet import INet
from solidkit.model.pnet import PNet, pnet_input
from solidkit.model.warp import camera_rotation, points_from_plane_distance, sample_at_pixels, warp_to_probes
from solidkit.synth.panocrops import metered_gain
from solidkit.threads import ensure_threads

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "CheckpointError",
    "SolidNet",
    "Prediction",
    "save_checkpoint",
    "load_checkpoint",
    "DEFAULT_CHECKPOINT",
]

CHECKPOINT_FORMAT = "solidkit.solidnet"
CHECKPOINT_VERSION = 1
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "solidnet_small.pt"


class CheckpointError(SolidkitError):
    """A checkpoint is missing, corrupt, of another format, or does not fit its configuration."""


class SolidNet(nn.Module):
    """The two-stage SOLID-Net (paper Fig. 3): ``inet`` then, per probe pixel, warping and ``pnet``.

    ``config.pnet_inputs`` selects the P-Net inputs, which gives the paper's ablations on the same
    code path (see :mod:`solidkit.model.baselines`).
    """

    card: dict[str, Any]  # set by from_checkpoint and solidkit.model.trainer.model_from_state

    def __init__(self, config: SolidNetConfig | None = None) -> None:
        super().__init__()
        self.config = config or preset("small")
        self.inet = INet(self.config)
        self.pnet = PNet(self.config)

    def reconfigure(self, **changes: Any) -> SolidNetConfig:
        """Change evaluation-time settings of the config (``sun_visibility_threshold``, ``sun_in_image``, the
        sun cones; stored in checkpoints) in the model and both networks; returns the previous config."""
        old = self.config
        cfg = old.replace(**changes)
        self.config = self.inet.config = self.pnet.config = cfg
        return old

    @property
    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def forward(
        self,
        image: torch.Tensor,
        K: torch.Tensor,
        pixels: torch.Tensor | None = None,
        pitch: torch.Tensor | None = None,
        roll: torch.Tensor | None = None,
        geometry: dict[str, torch.Tensor] | None = None,
    ) -> dict[str, torch.Tensor]:
        """Run I-Net and, when ``pixels (B, N, 2)`` are given, the warping and P-Net for each.

        ``geometry`` (optional: ``normal``, ``distance``, ``shadow`` in the batch format) replaces the
        predicted intrinsics *for the warping only* (teacher forcing while training P-Net).

        Returns I-Net's outputs (see :class:`INet`) plus ``rotation (B, 3, 3)`` and, with pixels,
        ``warped_image (B, N, 3, H, 2H)``, ``warped_mask``, ``warped_shadow`` (``(B, N, 1, H, 2H)``),
        ``centres (B, N, 3)`` (metres, panorama frame), ``probe_valid (B, N)`` bool (the geometry at the
        probe pixel faces the camera; otherwise the centre is only ``offset`` from the camera), ``local_log``
        and ``local`` (``(B, N, 3, H, 2H)``).
        """
        b = image.shape[0]
        zeros = image.new_zeros(b)
        pitch = zeros if pitch is None else pitch.to(image)
        roll = zeros if roll is None else roll.to(image)
        out = self.inet(image, K=K.to(image), pitch=pitch, roll=roll)
        out["rotation"] = camera_rotation(pitch, roll)
        if pixels is None:
            return out
        geo = {k: out[k] for k in ("normal", "distance", "shadow")}
        if geometry is not None:
            geo.update({k: v for k, v in geometry.items() if k in geo})
        h = self.config.pano_height
        values = torch.cat([image, geo["shadow"]], dim=1)
        warped, mask, centres = warp_to_probes(
            values, geo["normal"], geo["distance"], K.to(image), pixels, pitch, roll, h, self.config.probe_offset
        )
        _, valid = points_from_plane_distance(geo["normal"], geo["distance"], K.to(image))
        n = pixels.shape[1]
        flat = warped.reshape(b * n, 4, h, 2 * h)
        x = pnet_input(
            self.config.pnet_inputs,
            flat[:, :3],
            mask.reshape(b * n, 1, h, 2 * h),
            flat[:, 3:],
            out["sh"].repeat_interleave(n, dim=0),
            out["sky_log"].repeat_interleave(n, dim=0),
        )
        local = self.pnet(x)
        out.update(
            warped_image=warped[:, :, :3],
            warped_shadow=warped[:, :, 3:],
            warped_mask=mask,
            centres=centres,
            probe_valid=sample_at_pixels(valid.to(image.dtype), pixels)[..., 0] > 0.5,
            local_log=local["local_log"].view(b, n, 3, h, 2 * h),
            local=local["local"].view(b, n, 3, h, 2 * h),
        )
        return out

    # ------------------------------------------------------------------ checkpoints

    def save(self, path: str | os.PathLike, card: dict[str, Any] | None = None) -> Path:
        """Write a checkpoint (weights + config + conventions version + ``card``) atomically."""
        return save_checkpoint(self, path, card)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike | None = None, map_location: str = "cpu") -> SolidNet:
        """Rebuild the model saved at ``path`` (default: the shipped checkpoint), in eval mode."""
        if path is None and not DEFAULT_CHECKPOINT.is_file():
            raise CheckpointError(
                f"no shipped checkpoint at {DEFAULT_CHECKPOINT}; pass a checkpoint path (--checkpoint)"
            )
        ckpt = load_checkpoint(path or DEFAULT_CHECKPOINT, map_location)
        model = cls(ckpt["config"])
        try:
            model.load_state_dict(ckpt["state_dict"])
        except RuntimeError as exc:
            first = str(exc).strip().splitlines()
            raise CheckpointError(
                f"{path}: weights do not fit the stored configuration ({first[-1].strip()})"
            ) from None
        model.card = ckpt.get("card", {})
        return model.eval()

    # ------------------------------------------------------------------ inference

    def photo_input(self, photo: np.ndarray, encoding: str | np.ndarray = "srgb") -> tuple[np.ndarray, float]:
        """A photo ``(H, W, 3)`` in [0, 1] as the model's training photos were made, and the gain applied.

        Its linear values (:func:`solidkit.envmap.io.decode_ldr` with ``encoding``) times
        :func:`solidkit.synth.panocrops.metered_gain` (with ``config.exposure_key``; otherwise 1), under the
        paper's tonemap: ``(H, W, 3)`` float32 in [0, 1] and the gain (divide predicted radiance by it to
        return to the photo's own linear units).
        """
        linear = decode_ldr(photo, encoding)
        gain = metered_gain(linear, self.config.exposure_key) if self.config.exposure_key > 0 else 1.0
        return np.clip(np.asarray(tonemap(linear * np.float32(gain))), 0.0, 1.0).astype(np.float32), float(gain)

    @torch.no_grad()
    def predict(
        self,
        image: np.ndarray | str | os.PathLike,
        pixels: list[tuple[float, float]] | np.ndarray,
        K: np.ndarray | None = None,
        pitch: float = 0.0,
        roll: float = 0.0,
        sun_method: Method = "core",
        encoding: str | np.ndarray = "srgb",
    ) -> Prediction:
        """Predict the global sky, its sun direction and one local panorama per pixel.

        Parameters
        ----------
        image : (H, W, 3) float in [0, 1] / uint8 sRGB LDR array, or a path to an LDR file.
            It is resized (area) to the model's input size (240 x 320 by default); an aspect ratio
            other than the model's is stretched, with K and the pixels scaled to match.
        pixels : N ``(x, y)`` pixel coordinates in ``image`` (OpenCV: pixel centres at integers).
        K : (3, 3) intrinsics of ``image``; default: a centred pinhole with ``config.hfov_deg``.
        pitch, roll : camera pitch and roll in radians (conventions §4); default level.
        sun_method : passed to :func:`solidkit.envmap.sun.detect_sun`.
        encoding : how ``image`` encodes linear light (:func:`solidkit.envmap.io.decode_ldr`): ``"srgb"``
            (default: a camera's JPEG), ``"paper"`` (an image made by the paper's tonemap, as the rendered
            training photos are) or the camera's inverse response ``(256, 3)`` where it is calibrated.

        The photo is first given to the model as its training photos were made: its linear values
        (``encoding``) times :func:`solidkit.synth.panocrops.metered_gain` (with ``config.exposure_key``:
        the model's inputs were metered to it while training; otherwise 1), under the paper's tonemap.
        The predicted radiance is divided by that gain, so it stays in the photo's own linear units
        (``decode_ldr(photo, encoding)``). The gain is ``extra["exposure_gain"]``.

        Returns
        -------
        Prediction with ``sky (Hp, 2Hp, 3)`` and ``local`` (list of ``(Hp, 2Hp, 3)``) as float32
        linear radiance (channels last), ``sun`` (a SunDetection in the panorama frame) and the
        probe ``centres (N, 3)`` in metres; ``extra["probe_valid"]`` flags probes whose predicted
        geometry was usable (a pixel on the sky is not).
        """
        ensure_threads()
        if isinstance(image, (str, os.PathLike)):
            image = read_ldr(image)
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] < 3:
            raise InputError(f"expected an (H, W, 3) image, got shape {image.shape}")
        image = image[..., :3]
        if image.dtype == np.uint8:
            image = image.astype(np.float32) / 255.0
        image = np.clip(np.nan_to_num(image.astype(np.float32)), 0.0, 1.0)
        h0, w0 = image.shape[:2]
        pix = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if pix.shape[0] == 0:
            raise InputError("give at least one probe pixel")
        outside = (pix[:, 0] < -0.5) | (pix[:, 0] > w0 - 0.5) | (pix[:, 1] < -0.5) | (pix[:, 1] > h0 - 0.5)
        if outside.any():
            raise InputError(f"probe pixel {pix[outside][0].tolist()} lies outside the {w0}x{h0} image")
        K = (
            intrinsics_from_fov(math.radians(self.config.hfov_deg), w0, h0)
            if K is None
            else np.asarray(K, dtype=np.float64)
        )
        if K.shape != (3, 3):
            raise InputError(f"K must be 3x3, got {K.shape}")
        H, W = self.config.image_size
        sx, sy = W / w0, H / h0
        resized = cv2.resize(image, (W, H), interpolation=cv2.INTER_AREA if sx < 1 else cv2.INTER_LINEAR)
        resized, gain = self.photo_input(resized, encoding)
        K_net = scale_intrinsics(K, sx, sy)
        pix_net = np.stack([scale_pixel_coordinates(pix[:, 0], sx), scale_pixel_coordinates(pix[:, 1], sy)], axis=-1)
        pix_net = np.clip(pix_net, 0, [W - 1, H - 1])
        dev = next(self.parameters()).device
        t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=dev)  # noqa: E731
        out = self(
            t(resized).permute(2, 0, 1)[None],
            t(K_net)[None],
            t(pix_net)[None],
            t([pitch]),
            t([roll]),
        )
        sky = out["sky"][0].permute(1, 2, 0).cpu().numpy() / np.float32(gain)
        extra: dict[str, Any] = {}
        if "sun_dir" in out:
            az, el = angles_from_direction(out["sun_dir"][0].double().cpu().numpy())
            net = {"azimuth_deg": math.degrees(float(az)), "elevation_deg": math.degrees(float(el))}
            if "sun_visible" in out:
                p = float(out["sun_visible"][0])
                net.update(visible_prob=p, says_sun=p >= self.config.sun_visibility_threshold)
            if "sun_cone_deg" in out:
                c = out["sun_cone_deg"][0].cpu().numpy()
                net.update(
                    cone_68_deg=float(c[0]), cone_90_deg=float(c[1]), cones_calibrated=bool(self.config.sun_cone_scale)
                )
            if "sun_on_blob" in out:
                net["in_image_blob"] = bool(out["sun_on_blob"][0])
            extra["sun_network"] = net
        local = [x.permute(1, 2, 0).cpu().numpy() / np.float32(gain) for x in out["local"][0]]
        return Prediction(
            sky=sky,
            sun=detect_sun(sky, method=sun_method),
            local=local,
            pixels=pix,
            centres=out["centres"][0].cpu().numpy(),
            extra={"probe_valid": out["probe_valid"][0].cpu().numpy().tolist(), "exposure_gain": float(gain), **extra},
        )


@dataclass
class Prediction:
    """Result of :meth:`SolidNet.predict` (radiance in the photo's own linear units, ``decode_ldr(photo, encoding)``;
    panorama frame)."""

    sky: np.ndarray
    sun: Any
    local: list[np.ndarray]
    pixels: np.ndarray
    centres: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------- checkpoint I/O


def save_checkpoint(
    model: SolidNet, path: str | os.PathLike, card: dict[str, Any] | None = None, *, half: bool = False
) -> Path:
    """Save ``model`` with its config, the conventions version and ``card`` (atomic write).

    ``half=True`` stores floating-point weights as float16 (half the size; they are cast back to
    float32 on loading, a relative rounding of about 5e-4).
    """
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    if half:
        state = {k: v.half() if v.is_floating_point() else v for k, v in state.items()}
    payload = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_VERSION,
        "conventions_version": CONVENTIONS_VERSION,
        "model": type(model).__name__,
        "config": model.config.to_dict(),
        # plain JSON types only, so that torch.load(weights_only=True) accepts the file
        "card": json.loads(json.dumps(card or {}, default=str)),
        "state_dict": state,
    }
    buf = io.BytesIO()
    torch.save(payload, buf)
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def load_checkpoint(path: str | os.PathLike, map_location: str = "cpu") -> dict[str, Any]:
    """Read and check a checkpoint; returns ``{"config": SolidNetConfig, "state_dict", "card", ...}``.

    Raises :class:`CheckpointError` for a missing/corrupt/foreign file or a bad config, and
    :class:`~solidkit.errors.ConventionsError` when it was written under another conventions version.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # pickle/zip errors of every kind
        raise CheckpointError(f"{path}: not a readable torch checkpoint ({type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a solidkit SOLID-Net checkpoint (no '{CHECKPOINT_FORMAT}' format tag)")
    if payload.get("format_version") != CHECKPOINT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format version {payload.get('format_version')} is not supported "
            f"(this solidkit reads version {CHECKPOINT_VERSION})"
        )
    if payload.get("conventions_version") != CONVENTIONS_VERSION:
        raise ConventionsError(
            f"{path}: checkpoint was written under conventions version {payload.get('conventions_version')}, "
            f"this solidkit uses version {CONVENTIONS_VERSION} (frames/mapping differ; retrain or convert it)"
        )
    try:
        payload["config"] = SolidNetConfig.from_dict(dict(payload["config"]))
    except (ConfigError, TypeError, KeyError) as exc:
        raise CheckpointError(f"{path}: invalid model configuration ({exc})") from None
    if not isinstance(payload.get("state_dict"), dict):
        raise CheckpointError(f"{path}: checkpoint has no weights")
    payload["state_dict"] = {
        k: v.float() if torch.is_tensor(v) and v.is_floating_point() else v for k, v in payload["state_dict"].items()
    }
    return payload
