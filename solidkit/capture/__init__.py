"""Ingest Ricoh Theta cards into a campaign, merge exposure brackets into HDR, unwarp dual-fisheye frames.

Quick use::

    from solidkit.capture import ingest, load_manifest, merge_files, unwarp_file
    ingest("/media/SD_CARD", "campaign/")         # originals, manifest.json, HDR panoramas
    [(s.id, len(s.probes)) for s in load_manifest("campaign/").scenes]
    merge_files(["b1.jpg", "b2.jpg", "b3.jpg"], "merged.exr")  # one bracket -> a linear HDR EXR
    unwarp_file("R0010001.JPG", "pano.exr")       # dual-fisheye -> equirect, levelled

One frame in memory: :func:`solidkit.capture.unwarp.unwarp`. The names below are imported lazily
(on first access), so that the commands which do not merge or unwarp start without OpenCV's remaps.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ingest": "campaign",
    "IngestReport": "campaign",
    "Manifest": "manifest",
    "ManifestError": "manifest",
    "load_manifest": "manifest",
    "save_manifest": "manifest",
    "FieldNotes": "fieldnotes",
    "read_notes": "fieldnotes",
    "ShotInfo": "bracket_groups",
    "group_brackets": "bracket_groups",
    "merge_bracket": "bracket_merge",
    "merge_files": "bracket_merge",
    "Frame": "frame_merge",
    "MergeResult": "frame_merge",
    "load_frame": "frame_merge",
    "merge_frames": "frame_merge",
    "Registration": "register",
    "register_frames": "register",
    "estimate_response": "selfcal",
    "unwarp_file": "unwarp",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.capture.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.capture' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
