"""SOLID-Img-style synthetic data and a virtual field campaign with a hidden truth (Mitsuba 3).

Samples (:func:`generate`, :class:`SynthDataset`): a photo of a procedural city block
(:func:`city_block`) with its intrinsic buffers, global map and 4 local probes; crops of HDR
panoramas for the sun (:func:`render_sources`, :class:`CropSampler`); a virtual field campaign
(:func:`generate_campaign`): what a field team brings home, plus the truth to hold the chain against.

Quick use::

    from solidkit.synth import SynthDataset, generate, generate_campaign
    generate("synth/", 12, seed=0)                # 12 samples, resumable, sharded
    item = SynthDataset("synth/")[0]              # image, global, probes, probe_pixels, sun, K, ...
    truth = generate_campaign("virtual/", scenes=2, probes=3)  # cards + truth/truth.json

The names below are imported lazily (on first access); Mitsuba is imported on the first render.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "SampleConfig": "sample",
    "Generator": "sample",
    "generate": "dataset",
    "build_index": "dataset",
    "SynthDataset": "dataset",
    "ReferenceSet": "filter",
    "CityBlock": "scene",
    "city_block": "scene",
    "SourceConfig": "panocrops",
    "render_sources": "panocrops",
    "load_sources": "panocrops",
    "CropConfig": "panocrops",
    "CropSampler": "panocrops",
    "CampaignConfig": "campaign_truth",
    "CampaignTruth": "campaign_truth",
    "load_truth": "campaign_truth",
    "generate_campaign": "campaign",
    "rerender_truth": "truth_rerender",
    "SolarFix": "solar",
    "place_sun": "solar",
    "solar_position": "solar",
    "select_variant": "mitsuba_variant",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.synth.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.synth' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
