"""Lens, response-curve, colour, vignetting and photo-camera profiles (``solidkit calibrate ...``).

Each profile is a versioned JSON file with provenance (:class:`Profile`;
:func:`load_calibration_profile` reads any of them by its ``kind``): the inverse camera response
from brackets (Debevec, Robertson), white balance and a 3x3 CCM from a ColorChecker, the photo
camera's K (EXIF, field of view or board views) resized and cropped to 320x240, fisheye intrinsics
(Kannala-Brandt, Mei) and a lens profile from one dual-fisheye frame, per-lens vignetting.

Quick use::

    from solidkit.calibration import calibrate_camera_from_photo, calibrate_response_files, load_calibration_profile
    calibrate_camera_from_photo("photo.jpg").save("camera.json")  # K from the EXIF, and at 320x240
    calibrate_response_files(["b1.jpg", "b2.jpg", "b3.jpg"]).save("response.json")
    load_calibration_profile("camera.json").K

EXIF is read by :func:`solidkit.camera.read_metadata`. The names below are imported lazily (on first access).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Profile": "profile",
    "ProfileError": "profile",
    "load_calibration_profile": "profile",
    "ResponseProfile": "response",
    "calibrate_response": "response",
    "calibrate_response_files": "response",
    "ColourProfile": "colour",
    "calibrate_colour": "colour",
    "CameraProfile": "camera",
    "intrinsics_from_exif": "camera",
    "calibrate_camera_from_photo": "camera",
    "calibrate_camera_from_board": "camera",
    "resize_crop": "camera",
    "BoardView": "boards",
    "CharucoTarget": "boards",
    "detect_views": "boards",
    "render_board": "boards",
    "FisheyeProfile": "fisheye",
    "calibrate_fisheye": "fisheye",
    "lens_profile_from_calibrations": "fisheye",
    "LensFit": "lensfit",
    "fit_dual_fisheye": "lensfit",
    "fit_file": "lensfit",
    "RefineResult": "overlap",
    "refine_overlap": "overlap",
    "refine_files": "overlap",
    "VignettingProfile": "vignetting",
    "fit_flat_field": "vignetting",
    "fit_overlap": "vignetting",
    "correct_vignetting": "vignetting",
    "check_profile_fit": "fitcheck",
    "estimate_upright": "upright",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.calibration.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.calibration' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
