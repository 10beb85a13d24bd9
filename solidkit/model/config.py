"""SOLID-Net configuration: widths, input sizes, P-Net inputs, loss weights (one frozen dataclass).

The paper (Zhu et al., CVPR 2021, §4.2 and supplementary) gives the structure of I-Net and
P-Net but no layer widths. The presets:

- ``small``: a CPU-friendly configuration (≈1.5 M parameters) with the sun head (and its visibility
  output) and the located losses, metered inputs (``exposure_key``) and the camera's own sky-feature
  footprint (``sky_footprint``);
- ``small-sun``: the same with the low-resolution sun network (``sun_net``, :mod:`solidkit.model.sunnet`,
  +0.9 M parameters) instead of the sun head (the shipped checkpoint's);
- ``small-paper``: the same widths, inputs and footprint with the paper's sky decoder and losses (the ablation);
- ``paper``: a paper-sized configuration (standard U-Net widths 32..512, paper losses) for GPU training;
- ``tiny`` / ``tiny-paper``: a few thousand parameters, for tests.

The configuration travels inside every checkpoint (:mod:`solidkit.model.checkpoint`), so a
model is always rebuilt with the widths it was trained with.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from solidkit.errors import SolidkitError

__all__ = ["LOSS_VARIANTS", "PNET_INPUTS", "SKY_FOOTPRINTS", "ConfigError", "SolidNetConfig", "preset", "PRESETS"]

# Sky losses: "paper" = the paper's L1 on log1p(H_g) alone; "located" = a parametric sun (sun head)
# with location, energy and peak terms, the L1 on the sky away from the sun, and plane distance
# relative to the scene's median depth (see solidkit.model.losses).
LOSS_VARIANTS = ("paper", "located")

# Inputs P-Net may receive (paper Table 2): warped colour W_col (+ its observed mask), warped
# shadow W_sha, the Lambertian sphere relit with P_SH (W_SH) and the global sky H_g (W_sky).
PNET_INPUTS = ("col", "sha", "sh", "sky")

# Placement of the image's features on the sky decoder's panorama (SolidNetConfig.sky_footprint).
SKY_FOOTPRINTS = ("level", "camera")


class ConfigError(SolidkitError):
    """A model configuration is invalid or unknown."""


def _default_loss_weights() -> dict[str, float]:
    """The default ``SolidNetConfig.loss_weights`` (a fresh dict per call)."""
    return {
        "albedo": 1.0,
        "normal": 1.0,
        "distance": 1.0,
        "shadow": 1.0,
        "sky": 1.0,
        "dif": 1.0,
        "rec": 1.0,
        "local": 1.0,
        "tom": 1.0,
        "sun_dir": 1.0,
        "sun_energy": 1.0,
        "sun_peak": 0.2,
        "sun_size": 0.2,
        "sun_cos": 0.0,
        "sun_vis": 1.0,
    }


@dataclass(frozen=True)
class SolidNetConfig:
    """Hyper-parameters of SOLID-Net.

    Attributes
    ----------
    name : str
        Preset name (informational).
    widths : tuple of int
        I-Net encoder channels per level; level ``k`` works at ``1/2**(k+1)`` of the input size.
        The A/N/G/S decoders mirror them (U-Net skip links).
    light_width : int
        Channels of the lighting branch (the features behind ``P_SH`` and the sky features).
    sky_widths : tuple of int
        Sky-decoder channels at panorama heights ``pano_height/8, /4, /2, /1``.
    sky_stages : int
        4: the sky decoder runs up to ``pano_height``; 3: it stops at ``pano_height / 2`` and its smooth
        output is upsampled bilinearly (the sun is rendered at full resolution by the sun head), which
        saves the full-resolution stage, the costliest of a lighting-only training step.
    sky_feature_width : int
        Channels of the flip-padded sky features concatenated at every sky-decoder stage; 0 means
        ``light_width`` (the first checkpoints). Fewer channels make the full-resolution stages,
        the bulk of a lighting-only training step, cheaper.
    pnet_widths : tuple of int
        P-Net (U-Net) channels per level on the ``pano_height x 2 pano_height`` panorama.
    pnet_inputs : tuple of str
        Subset of :data:`PNET_INPUTS` fed to P-Net; ``("col", "sha", "sky")`` is the full model.
    image_size : (int, int)
        Input ``(height, width)``; the paper uses 240 x 320.
    pano_height : int
        Height ``H`` of H_g and H_l (width ``2H``); the paper uses 128.
    hfov_deg : float
        Horizontal field of view assumed by :meth:`SolidNet.predict` when no intrinsics are given,
        and the footprint of the image in the sky decoder's flip-padded sky features.
    probe_offset : float
        Metres the probe centre is moved along the surface normal (paper §3.1: 0.10 m).
    sun_head : bool
        Predict the sun parametrically (:mod:`solidkit.model.sunhead`) and add it to the sky map;
        False is the paper's purely non-parametric sky decoder.
    sun_visibility : bool
        The sun head also predicts whether a sun is visible; none is rendered below probability 0.5.
    sun_fine : bool
        The sun logits add a 1x1 convolution of the sky decoder's (mirror-tiled) features to the
        global coarse map; False: the global map alone.
    exposure_key : float
        The log-average luminance the network's inputs are exposed to (a camera's average metering;
        :func:`solidkit.synth.panocrops.metered_gain`): training crops are metered to it and
        :meth:`SolidNet.predict` re-exposes a photo to it (radiance returned in the photo's own units).
        0: the paper's fixed exposure (the HDR values as stored, the first checkpoints).
    sky_footprint : str
        Where the image's sky features sit on the panorama in the sky decoder: ``"level"`` (an
        ``hfov_deg`` x ``vfov_deg`` box centred at the horizon, the first checkpoints) or ``"camera"``
        (the image's own field of view, pitch and roll: :func:`solidkit.model.inet.camera_footprint_grid`).
    sun_net : tuple of int
        Encoder widths of a separate low-resolution sun network (:class:`solidkit.model.sunnet.SunNet`)
        that replaces the sun head on I-Net's features; empty: the sun head (the first checkpoints).
    sun_net_size : (int, int)
        ``(height, width)`` the sun network resizes the image to.
    sun_visibility_threshold : float
        Visibility probability at or above which a sun is rendered in evaluation (tuned on a validation
        split when a checkpoint is exported; 0.5 untuned).
    sun_in_image : bool
        At evaluation, put the sun on a sun-like saturated blob of the image when the sun network says
        a sun is visible and points near it (:mod:`solidkit.model.imagesun`); needs ``sun_head``.
    sun_cone_scale : (float, float)
        Calibrated 68 % / 90 % sun-direction cones (:mod:`solidkit.model.sununcertainty`): factors on the
        radii holding 68 % / 90 % of the sun network's direction distribution; ``()``: uncalibrated.
    sun_blob_gate_deg : float
        With ``sun_in_image``: the largest angle between the network's sun and a blob it is moved onto.
    sun_blob_visibility : float
        With ``sun_in_image``: the visibility probability (at most ``sun_visibility_threshold``) from which a
        sun-like image blob alone makes the sun visible (:func:`solidkit.model.imagesun.put_sun_on_blob`,
        ``promote``; tuned on validation); 0: off.
    sun_aureole : float
        At evaluation, the fraction of the rendered sun's energy spread over the sun network's own (uncalibrated)
        68 % direction radius
        (:func:`solidkit.model.sunhead.render_sun_with_aureole`; needs the cones of a ``sun_net``):
        the global map's brightest region is then where its sun is. 0: a sharp sun only.
    loss_variant : str
        One of :data:`LOSS_VARIANTS`.
    loss_weights : dict
        Weights of ``sup1`` terms, of ``dif``, ``rec``, ``sup2``, ``tom`` (paper: all 1) and of the
        sun terms ``sun_dir``, ``sun_energy``, ``sun_peak``, ``sun_size`` (used by ``loss_variant="located"``).
    """

    name: str = "small"
    widths: tuple[int, ...] = (16, 24, 32, 64, 96)
    light_width: int = 64
    sky_widths: tuple[int, ...] = (32, 24, 16, 16)
    sky_feature_width: int = 0
    sky_stages: int = 4
    pnet_widths: tuple[int, ...] = (16, 24, 32, 64, 96)
    pnet_inputs: tuple[str, ...] = ("col", "sha", "sky")
    image_size: tuple[int, int] = (240, 320)
    pano_height: int = 128
    hfov_deg: float = 60.0
    probe_offset: float = 0.10
    sun_head: bool = False
    sun_visibility: bool = False
    sun_fine: bool = True
    exposure_key: float = 0.0
    sky_footprint: str = "level"
    sun_net: tuple[int, ...] = ()
    sun_net_size: tuple[int, int] = (96, 128)
    sun_visibility_threshold: float = 0.5
    sun_in_image: bool = False
    sun_cone_scale: tuple[float, ...] = ()
    sun_blob_gate_deg: float = 60.0
    sun_blob_visibility: float = 0.0
    sun_aureole: float = 0.0
    loss_variant: str = "paper"
    loss_weights: dict[str, float] = field(default_factory=_default_loss_weights)

    def __post_init__(self) -> None:
        object.__setattr__(self, "widths", tuple(int(w) for w in self.widths))
        object.__setattr__(self, "sky_widths", tuple(int(w) for w in self.sky_widths))
        object.__setattr__(self, "pnet_widths", tuple(int(w) for w in self.pnet_widths))
        object.__setattr__(self, "pnet_inputs", tuple(self.pnet_inputs))
        object.__setattr__(self, "image_size", tuple(int(s) for s in self.image_size))
        object.__setattr__(self, "sun_net", tuple(int(w) for w in self.sun_net))
        object.__setattr__(self, "sun_net_size", tuple(int(s) for s in self.sun_net_size))
        object.__setattr__(self, "sun_cone_scale", tuple(float(s) for s in self.sun_cone_scale))
        v = self.sun_cone_scale
        if v and (len(v) != 2 or not 0.0 < v[0] <= v[1]):
            raise ConfigError(f"sun_cone_scale must be () or two values 0 < s68 <= s90, got {v}")
        if not 0.0 < self.sun_blob_gate_deg <= 180.0:
            raise ConfigError(f"sun_blob_gate_deg must be in (0, 180], got {self.sun_blob_gate_deg}")
        if not 0.0 <= self.sun_blob_visibility <= self.sun_visibility_threshold:
            raise ConfigError(
                f"sun_blob_visibility must be in [0, sun_visibility_threshold = {self.sun_visibility_threshold}], "
                f"got {self.sun_blob_visibility}"
            )
        if not 0.0 <= self.sun_aureole < 1.0:
            raise ConfigError(f"sun_aureole must be in [0, 1), got {self.sun_aureole}")
        if self.sun_aureole and not self.sun_net:
            raise ConfigError("sun_aureole needs the direction cones of a sun network (sun_net)")
        if self.sun_in_image and not self.sun_head:
            raise ConfigError("sun_in_image needs sun_head=True")
        if len(self.widths) < 2 or min(self.widths) < 1:
            raise ConfigError(f"widths must list at least two positive channel counts, got {self.widths}")
        if len(self.pnet_widths) < 2 or min(self.pnet_widths) < 1:
            raise ConfigError(f"pnet_widths must list at least two positive channel counts, got {self.pnet_widths}")
        if len(self.sky_widths) != 4 or min(self.sky_widths) < 1:
            raise ConfigError(f"sky_widths must list 4 positive channel counts, got {self.sky_widths}")
        if self.sky_stages not in (3, 4):
            raise ConfigError(f"sky_stages must be 3 or 4, got {self.sky_stages}")
        bad = [k for k in self.pnet_inputs if k not in PNET_INPUTS]
        if bad or "col" not in self.pnet_inputs:
            raise ConfigError(f"pnet_inputs must include 'col' and be drawn from {PNET_INPUTS}, got {self.pnet_inputs}")
        if self.pano_height % 8 or self.pano_height < 16:
            raise ConfigError(f"pano_height must be a multiple of 8 and >= 16, got {self.pano_height}")
        if self.pano_height % (2 ** (len(self.pnet_widths) - 1)):
            raise ConfigError(
                f"pano_height {self.pano_height} must be divisible by 2**(len(pnet_widths)-1) = "
                f"{2 ** (len(self.pnet_widths) - 1)}"
            )
        if not 1.0 < self.hfov_deg < 179.0:
            raise ConfigError(f"hfov_deg must be in (1, 179), got {self.hfov_deg}")
        if not self.exposure_key >= 0.0:
            raise ConfigError(f"exposure_key must be >= 0 (0: fixed exposure), got {self.exposure_key}")
        if self.sky_footprint not in SKY_FOOTPRINTS:
            raise ConfigError(f"sky_footprint must be one of {SKY_FOOTPRINTS}, got {self.sky_footprint!r}")
        if not 0.0 < self.sun_visibility_threshold < 1.0:
            raise ConfigError(f"sun_visibility_threshold must be in (0, 1), got {self.sun_visibility_threshold}")
        if self.loss_variant not in LOSS_VARIANTS:
            raise ConfigError(f"loss_variant must be one of {LOSS_VARIANTS}, got {self.loss_variant!r}")
        if (self.sun_visibility or not self.sun_fine) and not self.sun_head:
            raise ConfigError("sun_visibility / sun_fine=False need sun_head=True")
        if self.sun_net and (
            not (self.sun_head and self.sun_visibility)
            or len(self.sun_net) < 3
            or min(self.sun_net) < 1
            or len(self.sun_net_size) != 2
            or min(self.sun_net_size) < 16
        ):
            raise ConfigError(
                f"sun_net needs sun_head and sun_visibility, at least 3 positive widths and a size of at "
                f"least 16 x 16; got {self.sun_net}, {self.sun_net_size}"
            )
        if self.loss_variant == "located" and not self.sun_head:
            raise ConfigError("loss_variant 'located' needs sun_head=True (its sun terms read the sun head)")
        unknown = set(self.loss_weights) - set(_default_loss_weights())
        if unknown:
            raise ConfigError(f"unknown loss weights {sorted(unknown)}")

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view implied by ``hfov_deg`` and the image aspect (square pixels)."""
        h, w = self.image_size
        return math.degrees(2 * math.atan(math.tan(math.radians(self.hfov_deg) / 2) * h / w))

    def replace(self, **changes: Any) -> SolidNetConfig:
        """A copy with ``changes`` applied (validated)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (tuples become lists)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SolidNetConfig:
        """Inverse of :meth:`to_dict`; unknown keys are refused with a clear message."""
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ConfigError(f"unknown SolidNetConfig keys {sorted(unknown)} (written by a newer solidkit?)")
        weights = _default_loss_weights()
        weights.update(data.get("loss_weights", {}))
        return cls(**{**data, "loss_weights": weights})


_SUN: dict[str, Any] = {
    "sun_head": True,
    "sun_visibility": True,
    "loss_variant": "located",
    "sky_feature_width": 16,
    "sky_stages": 3,
    "exposure_key": 0.18,
    "sky_footprint": "camera",
    "loss_weights": {**_default_loss_weights(), "sun_cos": 1.0},
}

PRESETS: dict[str, SolidNetConfig] = {
    # small widths, the sun head and the located losses
    "small": SolidNetConfig(**_SUN),
    # the same with the low-resolution sun network instead of the sun head (the shipped checkpoint's)
    "small-sun": SolidNetConfig(**{**_SUN, "name": "small-sun", "sun_net": (16, 32, 64, 128)}),
    # the paper's sky decoder and losses at the small widths (the ablation of the sun head)
    "small-paper": SolidNetConfig(name="small-paper", sky_feature_width=16, exposure_key=0.18, sky_footprint="camera"),
    "paper": SolidNetConfig(
        name="paper",
        widths=(32, 64, 128, 256, 512),
        light_width=256,
        sky_widths=(128, 64, 32, 32),
        pnet_widths=(32, 64, 128, 256, 512),
    ),
    # for unit tests: a few thousand parameters, fast on one CPU core
    "tiny": SolidNetConfig(
        name="tiny",
        widths=(4, 8, 8, 16),
        light_width=16,
        sky_widths=(8, 8, 4, 4),
        pnet_widths=(4, 8, 8, 16),
        **_SUN,
    ),
    "tiny-paper": SolidNetConfig(
        name="tiny-paper",
        widths=(4, 8, 8, 16),
        light_width=16,
        sky_widths=(8, 8, 4, 4),
        pnet_widths=(4, 8, 8, 16),
        exposure_key=0.18,
        sky_footprint="camera",
    ),
}


def preset(name: str, **changes: Any) -> SolidNetConfig:
    """A named configuration (``small``, ``paper``, ``tiny``), optionally modified."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name].replace(**changes) if changes else PRESETS[name]
