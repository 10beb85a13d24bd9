"""SOLID-Net in PyTorch and kornia: I-Net, panoramic warping, P-Net, losses, baselines, predict.

Quick use::

    from solidkit.model import SolidNet
    pred = SolidNet.from_checkpoint().predict("photo.jpg", [(160, 200)])
    pred.sky, pred.sun, pred.local[0]

HDR outputs are parameterised as ``y = log1p(H)`` (radiance ``H = expm1(y)``); see
:data:`solidkit.model.blocks.HDR_PARAMETERISATION`.

The names below are imported lazily (on first access), so that ``solidkit --help`` and the
``predict`` command's option parsing do not pay for importing torch and kornia.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "HDR_PARAMETERISATION": "blocks",
    "log_from_radiance": "blocks",
    "radiance_from_log": "blocks",
    "PNET_INPUTS": "config",
    "ConfigError": "config",
    "SolidNetConfig": "config",
    "preset": "config",
    "INet": "inet",
    "SunHead": "sunhead",
    "render_sun": "sunhead",
    "SunNet": "sunnet",
    "SunCropBank": "suncrops",
    "Trainer": "trainer",
    "load_train_config": "trainer",
    "PNet": "pnet",
    "DEFAULT_CHECKPOINT": "solidnet",
    "CheckpointError": "solidnet",
    "Prediction": "solidnet",
    "SolidNet": "solidnet",
    "load_checkpoint": "solidnet",
    "save_checkpoint": "solidnet",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.model.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.model' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
