"""Align a campaign's captures to each scene's photo: sun labels, yaws, probe pixels, aligned products.

What ``solidkit align CAMPAIGN`` does: every capture's sun candidates and the scene's consensus sun,
each capture's yaw into the photo's panorama frame (conventions §8), the probe pixels in the photo,
written to ``CAMPAIGN/align/alignment.json`` (:class:`CampaignAlignment`) with the aligned probe
products and a report.

Quick use::

    from solidkit.align import align_campaign, load_alignment
    align_campaign("campaign/")                    # writes campaign/align/alignment.json
    scene = load_alignment("campaign/").scenes[0]
    scene.sun.azimuth_deg, scene.sun.elevation_deg  # in the photo's panorama frame
    [(p.id, p.yaw_deg, p.pixel_full) for p in scene.probes]

The names below are imported lazily (on first access): alignment pulls in OpenCV, SciPy and pvlib.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "AlignSettings": "pipeline",
    "align_campaign": "pipeline",
    "align_scene": "pipeline",
    "scene_sun": "sun",
    "choose_sun": "sun",
    "SunChoice": "sun",
    "SunSettings": "sun",
    "CampaignAlignment": "schema",
    "SceneAlignment": "schema",
    "ProbeAlignment": "schema",
    "SceneSun": "schema",
    "CaptureSun": "schema",
    "Cue": "schema",
    "alignment_summary": "schema",
    "photo_azimuth_from_solar": "schema",
    "solar_azimuth_from_photo": "schema",
    "load_alignment": "schema",
    "save_alignment": "schema",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.align.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.align' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
