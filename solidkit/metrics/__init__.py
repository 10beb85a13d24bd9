"""The evaluation's metrics, written once: the sun's errors, the global and local map scores, intervals.

Zhu et al., "Spatially-Varying Outdoor Lighting Estimation from Intrinsics", CVPR 2021, §5 and
supplementary Table 1. Training validation (:mod:`solidkit.model.trainer`), the crop protocol
(:mod:`solidkit.model.suneval`) and ``solidkit eval`` (:mod:`solidkit.finetune.evaluate`) all score with
these functions, so their numbers cannot drift apart.

- :mod:`~solidkit.metrics.sun`: :func:`direction_errors` (angle, azimuth, elevation; NumPy or torch),
  :func:`find_sun` (the paper's recipe or the default detector), :func:`sun_error`, :func:`sun_statistics`;
- :mod:`~solidkit.metrics.maps`: :func:`global_mae` (the paper's ``xi_HDR``), :func:`local_ldr_metrics`
  (SSIM / MAE against a real LDR probe), :func:`local_hdr_metrics`, :func:`simulate_ldr_probe`;
- :mod:`~solidkit.metrics.relight`: the re-rendering error of relit objects, :func:`si_rmse`, :func:`render_ssim`,
  :func:`shading_direction` and :func:`shading_angle_deg`;
- :mod:`~solidkit.metrics.stats`: :func:`bootstrap_ci` (scene-level cluster bootstrap), :func:`summarise`.

Quick use::

    from solidkit import metrics
    err = metrics.sun_error(predicted_direction, true_direction)   # SunError, degrees
    scores = metrics.local_ldr_metrics(predicted_hdr, probe_ldr)    # {"ssim", "mae", ...}
    low, high = metrics.bootstrap_ci(values, groups=scene_ids)

The names are imported lazily (on first access): :mod:`~solidkit.metrics.maps` pulls in torch and kornia.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "SUN_METHODS": "sun",
    "SunError": "sun",
    "direction_errors": "sun",
    "find_sun": "sun",
    "sun_error": "sun",
    "sun_statistics": "sun",
    "SATURATION_LEVEL": "maps",
    "DARK_FLOOR": "maps",
    "SSIM_WINDOW": "maps",
    "global_mae": "maps",
    "saturation_mask": "maps",
    "exposure_scale": "maps",
    "ldr_from_hdr": "maps",
    "masked_ssim": "maps",
    "local_ldr_metrics": "maps",
    "local_hdr_metrics": "maps",
    "simulate_ldr_probe": "maps",
    "si_scale": "relight",
    "si_rmse": "relight",
    "render_ssim": "relight",
    "shading_direction": "relight",
    "shading_angle_deg": "relight",
    "bootstrap_ci": "stats",
    "summarise": "stats",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.metrics.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.metrics' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
