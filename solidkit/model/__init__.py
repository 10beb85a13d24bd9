"""SOLID-Net in PyTorch and kornia: I-Net, panoramic warping, P-Net, losses, baselines, predict.

Quick use::

    from solidkit.model import SolidNet
    pred = SolidNet.from_checkpoint().predict("photo.jpg", [(160, 200)])
    pred.sky, pred.sun, pred.local[0]

HDR outputs are parameterised as ``y = log1p(H)`` (radiance ``H = expm1(y)``); see
:data:`solidkit.model.blocks.HDR_PARAMETERISATION`.
"""

from solidkit.model.blocks import HDR_PARAMETERISATION, log_from_radiance, radiance_from_log
from solidkit.model.config import PNET_INPUTS, ConfigError, SolidNetConfig, preset
from solidkit.model.inet import INet
from solidkit.model.pnet import PNet
from solidkit.model.solidnet import (
    DEFAULT_CHECKPOINT,
    CheckpointError,
    Prediction,
    SolidNet,
    default_intrinsics,
    load_checkpoint,
    save_checkpoint,
)

__all__ = [
    "HDR_PARAMETERISATION",
    "PNET_INPUTS",
    "ConfigError",
    "CheckpointError",
    "DEFAULT_CHECKPOINT",
    "INet",
    "PNet",
    "Prediction",
    "SolidNet",
    "SolidNetConfig",
    "default_intrinsics",
    "load_checkpoint",
    "log_from_radiance",
    "preset",
    "radiance_from_log",
    "save_checkpoint",
]
