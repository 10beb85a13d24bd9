"""Does a lens profile fit this dual-fisheye frame? The checks ``capture unwarp`` reports.

Three questions, each answered from the frame itself:

- **seam**: the seam disparity (:func:`solidkit.calibration.disparity.seam_disparity`): how far apart, in degrees,
  the two lenses put the scene points both show, over the whole overlap. A median above
  :data:`~solidkit.calibration.disparity.DISPARITY_WARN_DEG` (1°, 15 px of doubling in a 5376-px panorama) or more
  than half the matches over 1° apart is a ``seam_disparity`` warning: the rule and the text of ``calibrate
  fisheye`` (:func:`~solidkit.calibration.disparity.disparity_warning`). The seam error
  (:func:`solidkit.calibration.seam.seam_error`, photometric, without a unit) is reported beside it and decides only
  where the disparity is unmeasured (fewer than 20 matches: a dark, clipped or textureless overlap): above
  :data:`SEAM_ERROR_WARN` a ``seam_mismatch`` warning;
- **arrangement**: the frame's image circles (:func:`~solidkit.calibration.circles.find_image_circles`)
  side by side or stacked as the profile's lens centres are; else ``layout_mismatch``;
- **upright** (:func:`check_upright`, on the unwarped panorama): it is upright
  (:func:`~solidkit.calibration.upright.upright_of_panorama`); a confident turn of ±90° is a
  ``layout_mismatch`` (circles turned relative to the profile: a sideways panorama).

Why the disparity decides: on the real indoor Theta S frame its shipped profile measures 0.70° here (parallax of
objects within a metre) and seam error 0.60; the same profile with the back lens yawed 1° or 2°, or pitched 4.8° off
its aim, measures 1.55°, 2.12° and 3.10° (warned) while their seam errors, 0.68, 0.66 and 0.66, stayed under
:data:`SEAM_ERROR_WARN` (no warning before). The seam error's scale is not comparable between cameras (a right
hand-made profile of a real Gear 360 frame scored 1.04, a wrong fit 0.74: benchmarks/results/seam_disparity.md).
The frame is reduced first (a whole factor, where ``calibrate fisheye``'s strips reduce it by any factor) and its
circles come from the seam error's working copy: the figures differ from ``calibrate fisheye``'s by a few hundredths
of a degree on this frame (0.70° against 0.64°).

:data:`SEAM_ERROR_WARN` = 0.7 was chosen from measured seam errors (benchmarks/results/selfcal.md): correct profiles
stay at or below 0.11 on rendered Theta V frames of three real HDR panoramas, 0.48 on the virtual campaign's Theta V
JPEGs and 0.60 on the real indoor Theta S frame; another camera's profile 0.83, or its ring on black (warned).
Dark frames (a 1/25000 s sun frame: less than 20 % of the ring usable) get neither figure and no warning.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np

from solidkit.calibration.circles import Circle, CircleError, arrangement_of_centres, find_image_circles
from solidkit.calibration.disparity import DISPARITY_WARN_DEG, STEP_DEG, disparity_warning, seam_disparity
from solidkit.calibration.seam import LDR_FLOOR, WORK_RADIUS_PX, prepare_seam_image, seam_error
from solidkit.calibration.upright import upright_of_panorama
from solidkit.camera.lens import LensProfile
from solidkit.envmap.io import srgb_decode
from solidkit.envmap.perspective import scale_pixel_coordinates
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


def _disparity_copy(image: np.ndarray, profile: LensProfile, bgr: bool) -> np.ndarray:
    """The frame reduced by a whole factor (area) to about the resolution the disparity's ring strips sample (1.5
    lens px per strip px: :func:`~solidkit.calibration.disparity.ring_strips` reduces no further), RGB order."""
    px_per_deg = max(float(lens.dradius(math.radians(90.0))) * math.pi / 180.0 for lens in profile.lenses[:2])
    k = max(1, int(px_per_deg * STEP_DEG / 1.5))
    h, w = image.shape[:2]
    small = image
    if k > 1:  # a whole factor: OpenCV's fast area path (a fifth of the time of a fractional one at Theta V size)
        small = cv2.resize(image[: h - h % k, : w - w % k], (w // k, h // k), interpolation=cv2.INTER_AREA)
    if bgr and small.ndim == 3:
        small = small[..., 2::-1]
    return np.ascontiguousarray(small)


def check_profile_fit(
    image: np.ndarray, profile: LensProfile, saturation: float | None = None, *, bgr: bool = False
) -> tuple[dict[str, Any], list[str]]:
    """Seam error and arrangement checks of ``profile`` on a dual-fisheye ``image`` (module docstring).

    ``image``: ``(H, W, C)`` uint8 sRGB or linear float; ``saturation``: the linear clipping level
    (``None`` for HDR); ``bgr``: the channels are in OpenCV's order. Returns ``(report, warnings)``;
    the report has ``ok`` (no warning), ``seam_disparity``
    (:meth:`~solidkit.calibration.disparity.SeamDisparity.to_json`, degrees), ``seam_disparity_warn_deg`` (its
    threshold), ``seam_error``, ``seam_error_warn`` (its threshold, applied when the disparity is unmeasured) and
    ``arrangement`` (frame / profile).
    """
    h, w = image.shape[:2]
    prof = profile.scaled(w, h) if tuple(profile.reference_size) != (w, h) else profile
    report: dict[str, Any] = {"seam_error_warn": SEAM_ERROR_WARN, "seam_disparity_warn_deg": DISPARITY_WARN_DEG}
    warnings: list[str] = []
    if len(prof.lenses) != 2:
        return report, warnings
    radius = float(np.mean([lens.max_radius() for lens in prof.lenses]))
    with ThreadPoolExecutor(1) as pool:  # the disparity (SIFT on the ring strips) beside the seam error
        reduced = pool.submit(_disparity_copy, image, prof, bgr)
        small, s = _working_copy(image, radius, bgr)
        want = arrangement_of_centres([lens.center for lens in prof.lenses])
        circles: list[Circle] | None
        try:
            circles, have = find_image_circles(luminance(small) if small.ndim == 3 else small)
        except CircleError:
            circles, have = None, None
        report["arrangement"] = {"frame": have, "profile": want}
        frame = reduced.result()
        if circles is not None:  # the frame's circles bound the overlap band (a profile's narrower field does not)
            k = frame.shape[1] / small.shape[1]
            circles = [
                Circle(scale_pixel_coordinates(c.cx, k), scale_pixel_coordinates(c.cy, k), c.r * k, c.inliers)
                for c in circles
            ]
        measuring = pool.submit(seam_disparity, frame, prof, circles)
        sp = prof.scaled(small.shape[1], small.shape[0]) if s < 1.0 else prof
        seam = prepare_seam_image(small, radius * s, saturation)
        e = seam_error(seam, sp)
        report.update(
            seam_error=None if not math.isfinite(e["seam_error"]) else round(e["seam_error"], 4),
            seam_samples=e["samples"],
        )
        disparity = measuring.result()
    report["seam_disparity"] = disparity.to_json()
    doubled = disparity_warning(disparity)
    if doubled is not None:
        warnings.append(doubled)
    if not disparity.measured:  # nothing to match across the overlap: the photometric seam error decides
        if report["seam_error"] is None:
            lum = luminance(small) if small.ndim == 3 else small
            if float(np.median(lum)) > 10 * LDR_FLOOR:  # a well-exposed frame, yet the ring sees black (or clipping)
                warnings.append(
                    "seam_mismatch: the profile's overlap ring falls on black (or clipped) pixels, outside the "
                    "frame's image circles: another camera or layout? 'solidkit calibrate fisheye FRAME' makes a "
                    "profile from the frame"
                )
        elif e["seam_error"] > SEAM_ERROR_WARN:
            warnings.append(
                f"seam_mismatch: seam error {e['seam_error']:.2f} > {SEAM_ERROR_WARN} (0 = the lenses agree, "
                "~0.6 = 4° off, 1 = unrelated; the seam disparity is unmeasured: too little texture in the overlap): "
                "the profile does not fit this frame and the seams will show doubled content; 'solidkit calibrate "
                "fisheye FRAME' makes a profile from the frame"
            )
    if report["seam_error"] is None:
        report["seam_error_note"] = (
            "unmeasured: less than 20 % of the overlap ring is usable (a dark or clipped "
            "frame, e.g. a sun frame, or a profile whose ring falls outside the image circles)"
        )
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
