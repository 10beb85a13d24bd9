"""Does a lens profile fit this dual-fisheye frame? The checks ``capture unwarp`` reports.

Three questions, each answered from the frame itself:

- **seam**: the seam error (:func:`solidkit.calibration.seam.seam_error`) of the profile on the
  frame; above :data:`SEAM_ERROR_WARN` a ``seam_mismatch`` warning (doubled content at the seams);
- **arrangement**: the frame's image circles (:func:`~solidkit.calibration.circles.find_image_circles`)
  side by side or stacked as the profile's lens centres are; else ``layout_mismatch``;
- **upright** (:func:`check_upright`, on the unwarped panorama): it is upright
  (:func:`~solidkit.calibration.upright.upright_of_panorama`); a confident turn of ±90° is a
  ``layout_mismatch`` (circles turned relative to the profile: a sideways panorama).

:data:`SEAM_ERROR_WARN` = 0.7 was chosen from measured seam errors (benchmarks/results/selfcal.md):
correct profiles stay at or below 0.11 on rendered Theta V frames of three real HDR panoramas, 0.48
on the virtual campaign's Theta V JPEGs (1920x960, parallax of nearby geometry) and 0.60 on the real
indoor Theta S frame with its own profile (objects within a metre: parallax): 0 false alarms in 28.
Wrong profiles: another camera's 0.83 or its ring on black (warned), r(theta) 3 % off 0.91-1.08 or
on black, the back lens 8° off 0.76-0.87, a lens centre 3 % of the radius off 0.44-0.83, the back
lens 4° off 0.57-0.65: 11 of 23 warned. So the warning catches another camera, another layout and
gross unit errors with a margin of 0.1 over the worst correct case; errors of a few degrees
(doubling by a few pixels) pass: ``calibrate overlap`` is the tool for those. Dark frames (a
1/25000 s sun frame: less than 20 % of the ring usable) get no seam error and no warning.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from solidkit.calibration.circles import CircleError, arrangement_of_centres, find_image_circles
from solidkit.calibration.seam import LDR_FLOOR, WORK_RADIUS_PX, prepare_seam_image, seam_error
from solidkit.calibration.upright import upright_of_panorama
from solidkit.camera.lens import LensProfile
from solidkit.envmap.io import srgb_decode
from solidkit.envmap.sun import luminance

__all__ = ["SEAM_ERROR_WARN", "check_profile_fit", "check_upright"]

#: Seam error above which ``capture unwarp`` warns that the profile does not fit the frame.
SEAM_ERROR_WARN = 0.7


def _working_copy(image: np.ndarray, radius_px: float, bgr: bool = False) -> tuple[np.ndarray, float]:
    """Linear float copy at the seam's working resolution (8-bit reduced before decoding: cheap)."""
    h, w = image.shape[:2]
    s = min(1.0, WORK_RADIUS_PX / max(radius_px, 1.0))
    small = image
    if s < 0.5:  # decimate by 2 first: the area reduction then reads a quarter of the pixels
        small, s = small[::2, ::2], s * 2
        h, w = small.shape[:2]
    if s < 1.0:
        small = cv2.resize(small, (max(8, round(w * s)), max(8, round(h * s))), interpolation=cv2.INTER_AREA)
    s = small.shape[1] / image.shape[1]
    if bgr and small.ndim == 3:
        small = small[..., 2::-1]
    if small.dtype == np.uint8:
        small = np.asarray(srgb_decode(small.astype(np.float32) / 255.0), np.float32)
    return small.astype(np.float32, copy=False), s


def check_profile_fit(
    image: np.ndarray, profile: LensProfile, saturation: float | None = None, *, bgr: bool = False
) -> tuple[dict[str, Any], list[str]]:
    """Seam error and arrangement checks of ``profile`` on a dual-fisheye ``image`` (module docstring).

    ``image``: ``(H, W, C)`` uint8 sRGB or linear float; ``saturation``: the linear clipping level
    (``None`` for HDR); ``bgr``: the channels are in OpenCV's order. Returns ``(report, warnings)``;
    the report has ``ok`` (no warning), ``seam_error``, ``seam_error_warn`` (the threshold) and
    ``arrangement`` (frame / profile).
    """
    h, w = image.shape[:2]
    prof = profile.scaled(w, h) if tuple(profile.reference_size) != (w, h) else profile
    report: dict[str, Any] = {"seam_error_warn": SEAM_ERROR_WARN}
    warnings: list[str] = []
    if len(prof.lenses) != 2:
        return report, warnings
    radius = float(np.mean([lens.max_radius() for lens in prof.lenses]))
    small, s = _working_copy(image, radius, bgr)
    sp = prof.scaled(small.shape[1], small.shape[0]) if s < 1.0 else prof
    seam = prepare_seam_image(small, radius * s, saturation)
    e = seam_error(seam, sp)
    report.update(
        seam_error=None if not math.isfinite(e["seam_error"]) else round(e["seam_error"], 4), seam_samples=e["samples"]
    )
    if report["seam_error"] is None:
        lum = luminance(small) if small.ndim == 3 else small
        if float(np.median(lum)) > 10 * LDR_FLOOR:  # a well-exposed frame, yet the ring sees black (or clipping)
            warnings.append(
                "seam_mismatch: the profile's overlap ring falls on black (or clipped) pixels, outside the "
                "frame's image circles: another camera or layout? 'solidkit calibrate fisheye FRAME' makes a "
                "profile from the frame"
            )
        report["seam_error_note"] = (
            "unmeasured: less than 20 % of the overlap ring is usable (a dark or clipped "
            "frame, e.g. a sun frame, or a profile whose ring falls outside the image circles)"
        )
    if math.isfinite(e["seam_error"]) and e["seam_error"] > SEAM_ERROR_WARN:
        warnings.append(
            f"seam_mismatch: seam error {e['seam_error']:.2f} > {SEAM_ERROR_WARN} (0 = the lenses agree, "
            "~0.6 = 4° off, 1 = unrelated): the profile does not fit this frame and the seams will show doubled "
            "content; 'solidkit calibrate fisheye FRAME' makes a profile from the frame"
        )
    want = arrangement_of_centres([lens.center for lens in prof.lenses])
    try:
        _, have = find_image_circles(luminance(small) if small.ndim == 3 else small)
    except CircleError:
        have = None
    report["arrangement"] = {"frame": have, "profile": want}
    if have is not None and have != want:
        warnings.append(
            f"layout_mismatch: the frame's image circles are {have.replace('_', ' ')}, the profile's "
            f"{want.replace('_', ' ')}: another camera or layout (check --profile)"
        )
    report["ok"] = not warnings
    return report, warnings


def check_upright(pano: np.ndarray, report: dict[str, Any] | None = None) -> list[str]:
    """Is the unwarped panorama upright (:func:`~solidkit.calibration.upright.upright_of_panorama`)?
    A confident ±90° turn is a ``layout_mismatch`` warning; ``report`` (optional) gets ``roll_deg``,
    ``upright_cue``, ``upright_confident`` and ``ok`` updated."""
    up = upright_of_panorama(pano)
    warnings = []
    if up.roll_deg != 0.0 and up.confident:
        warnings.append(
            f"layout_mismatch: the panorama comes out turned by {-up.roll_deg:+.0f}° (by {up.cue}): the "
            "frame's image circles are rotated relative to the profile (e.g. a ±90° sensor layout); "
            "'solidkit calibrate fisheye FRAME' detects the layout"
        )
    if report is not None:
        report.update(roll_deg=up.roll_deg, upright_cue=up.cue, upright_confident=up.confident)
        report["ok"] = bool(report.get("ok", True)) and not warnings
    return warnings
