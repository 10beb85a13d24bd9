"""The camera model, below capture and calibration: lens profiles (and the shipped ones),
EXIF/XMP/maker-note metadata, raw decoding.

Quick use::

    from solidkit.camera import load_profile, read_metadata, unproject
    meta = read_metadata("R0010001.JPG")          # EXIF, GPS, GPano XMP, Ricoh maker note
    meta.model, meta.exposure_time, meta.pitch_deg, meta.roll_deg
    lens = load_profile("theta-v").lenses[0]      # a shipped dual-fisheye lens profile
    directions, theta = unproject(lens, [960.0], [960.0])  # fisheye pixels -> camera-frame rays

The names below are imported lazily (on first access).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CaptureMetadata": "metadata",
    "read_metadata": "metadata",
    "level_rotation": "metadata",
    "gravity_from_pitch_roll": "orientation",
    "pitch_roll_from_gravity": "orientation",
    "LensModel": "lens",
    "LensProfile": "lens",
    "LensProfileError": "lens",
    "load_profile": "lens",
    "list_profiles": "lens",
    "profile_for_metadata": "lens",
    "project": "lens",
    "unproject": "lens",
    "RawImage": "raw",
    "read_raw": "raw",
    "is_raw_file": "raw",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.camera.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.camera' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
