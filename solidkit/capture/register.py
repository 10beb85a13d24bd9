"""Registering the frames of a bracket before merging: global sub-pixel shifts, recorded.

A handheld or bumped bracket is shifted by a pixel or so between frames (on a real
bracket one frame was off by about (−0.7, +0.8) px and was merged unaligned, smearing
every edge into a "ghost"). Each frame is registered to the reference frame (the middle
exposure) in two steps:

1. coarse, integer: OpenCV's median-threshold-bitmap alignment (``AlignMTB``; Ward, "Fast,
   robust image registration for compositing high dynamic range photographs from hand-held
   exposures", JGT 2003), which does not care how differently the frames are exposed;
2. fine, sub-pixel: enhanced correlation coefficient maximisation (``cv2.findTransformECC``,
   translation; Evangelidis & Psarakis, PAMI 2008) of the two frames' luminance *ranks* over
   the pixels well exposed in both (rank-normalised: any monotone camera response gives the same
   image, so a wrong provisional curve cannot bias the shift; an sRGB-linearised film-curve
   bracket was "shifted" by 0.24 px before this), started from no shift and from the coarse
   one, on images at most ``max_width`` wide (the shift is scaled back).

A frame with too few pixels well exposed in common with the reference (a sun frame) is not
registered (correlation ``None``) and merged unshifted. The correlation coefficient is the
registration's confidence: below ``min_correlation``, or
when ECC does not converge, the frame "does not register" (a warning; it is then left
unshifted), as is a shift above ``max_shift_px`` or 5 % of the image's smaller side (a tripod
bracket does not move that much; a degenerate image can fool the search). Shifts below ``min_shift_px``
are not applied (0.25 px: about the fine step's own error on real and simulated brackets;
resampling below it would only blur). Shifts are ``(dx, dy)`` in pixels, positive to
the right and down, of the frame's content relative to the reference.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

__all__ = ["Registration", "register_frames", "shift_image"]


class Registration:
    """Per frame: ``shifts[i] = (dx, dy)`` px, ``responses[i]`` (ECC correlation; 1 for the reference),
    ``applied[i]``."""

    def __init__(
        self,
        reference: int,
        shifts: list[tuple[float, float]],
        responses: list[float],
        applied: list[bool],
        warnings: list[str],
    ):
        self.reference, self.shifts, self.responses, self.applied, self.warnings = (
            reference,
            shifts,
            responses,
            applied,
            warnings,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "reference_frame": self.reference,
            "shifts_px": [[round(dx, 3), round(dy, 3)] for dx, dy in self.shifts],
            "correlation": [None if r != r else round(r, 3) for r in self.responses],
            "applied": self.applied,
        }


def _log_lum(linear: np.ndarray, exposure: float) -> np.ndarray:
    return np.log(np.maximum(np.asarray(linear, np.float32).mean(axis=-1) / np.float32(exposure), 1e-6)).astype(
        np.float32
    )


def _ranks(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``img`` replaced by its values' ranks (0..1) among the ``mask`` pixels (0.5 elsewhere).

    Two frames seen through the same monotone response then agree on their common pixels,
    whatever that response is: registration does not depend on the curve being known yet.
    """
    out = np.full(img.shape, 0.5, np.float32)
    sel = mask.astype(bool)
    if sel.sum() > 1:
        v = img[sel]
        order = np.argsort(v, kind="stable")
        r = np.empty(v.size, np.float32)
        r[order] = np.arange(v.size, dtype=np.float32) / (v.size - 1)
        out[sel] = r
    return out


def shift_image(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``image`` with its content moved by ``(-dx, -dy)`` (undoing a measured shift), edges replicated."""
    M = np.array([[1, 0, -dx], [0, 1, -dy]], np.float32)
    h, w = image.shape[:2]
    interp = cv2.INTER_LINEAR if abs(dx - round(dx)) > 1e-6 or abs(dy - round(dy)) > 1e-6 else cv2.INTER_NEAREST
    return cv2.warpAffine(image, M, (w, h), flags=interp, borderMode=cv2.BORDER_REPLICATE)


def register_frames(
    codes: Sequence[np.ndarray],
    linear: Sequence[np.ndarray],
    exposures: Sequence[float],
    valid: Sequence[np.ndarray],
    *,
    max_width: int = 2048,
    min_correlation: float = 0.8,
    min_shift_px: float = 0.25,
    max_shift_px: float = 32.0,
) -> Registration:
    """Measure each frame's shift against the middle exposure (module docstring).

    ``codes``: 8-bit ``(H, W, 3)`` frames (for MTB); ``linear``: their linear values, divided
    here by ``exposures``; ``valid``: ``(H, W)`` bool, well-exposed pixels of each frame.
    """
    n = len(codes)
    ref = int(np.argsort(exposures)[n // 2])
    h, w = codes[0].shape[:2]
    scale = min(1.0, max_width / w)
    size = (max(8, int(round(w * scale))), max(8, int(round(h * scale))))
    mtb = cv2.createAlignMTB(max_bits=5, exclude_range=4, cut=True)
    gray = [cv2.cvtColor(np.ascontiguousarray(c), cv2.COLOR_RGB2GRAY) if c.dtype == np.uint8 else None for c in codes]

    def small(x: np.ndarray, interp: int = cv2.INTER_AREA) -> np.ndarray:
        return cv2.resize(x, size, interpolation=interp) if scale < 1 else x

    lum = [small(_log_lum(linear[i], exposures[i])) for i in range(n)]
    ok = [small(np.asarray(v, np.uint8), cv2.INTER_NEAREST) for v in valid]
    kernel = np.ones((5, 5), np.uint8)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 300, 1e-7)
    shifts, scores, applied, warnings = [], [], [], []
    for i in range(n):
        if i == ref:
            shifts.append((0.0, 0.0))
            scores.append(1.0)
            applied.append(False)
            continue
        cx = cy = 0.0
        gray_ref, gray_i = gray[ref], gray[i]
        if gray_i is not None and gray_ref is not None:
            mx, my = mtb.calculateShift(gray_ref, gray_i)  # how to move frame i onto the reference
            cx, cy = -float(mx), -float(my)  # the content's displacement
        mask = cv2.erode(ok[ref] & ok[i], kernel)
        if int(mask.sum()) < max(500, 0.005 * mask.size):
            # nothing in common to register on (e.g. a 1/25000 s sun frame: black but for the sun); it
            # contributes only where the others clip, so it is merged unshifted without a warning
            shifts.append((0.0, 0.0))
            scores.append(float("nan"))
            applied.append(False)
            continue
        a, b = _ranks(lum[ref], mask), _ranks(lum[i], mask)
        # ECC's warp maps reference coordinates into frame i: x_i = x_ref + (dx, dy). Started from no
        # shift and from MTB's: MTB can lock onto a wrong offset in images with little structure
        # (a smooth gradient); the better correlation wins, the smaller shift on a tie.
        best = None
        for sx, sy in {(0.0, 0.0), (cx, cy)}:
            warp: np.ndarray = np.array([[1, 0, sx * scale], [0, 1, sy * scale]], np.float32)
            try:
                # a 5x5 Gaussian first: rank images of noisy frames are noisy (unfiltered, a (-0.7, 0.8) px
                # shift of a 256x128 bracket came out as (-0.46, 0.55))
                cc_try, warp = cv2.findTransformECC(a, b, warp, cv2.MOTION_TRANSLATION, criteria, mask, 5)
            except cv2.error:
                continue
            cand = (float(cc_try), float(warp[0, 2]) / scale, float(warp[1, 2]) / scale)
            if (
                best is None
                or cand[0] > best[0] + 1e-3
                or (abs(cand[0] - best[0]) <= 1e-3 and np.hypot(*cand[1:]) < np.hypot(*best[1:]))
            ):
                best = cand
        cc, dx, dy = best if best is not None else (0.0, cx, cy)
        max_shift_px = min(max_shift_px, 0.05 * min(h, w))
        if cc < min_correlation or abs(dx) > max_shift_px or abs(dy) > max_shift_px:
            warnings.append(
                f"frame_not_registered: frame {i} (exposure {exposures[i]:.6g}) does not register "
                f"(correlation {cc:.3f}, shift ({dx:.2f}, {dy:.2f}) px); merged unshifted"
            )
            shifts.append((dx, dy))
            scores.append(float(cc))
            applied.append(False)
            continue
        shifts.append((dx, dy))
        scores.append(float(cc))
        applied.append(bool(max(abs(dx), abs(dy)) >= min_shift_px))
    return Registration(ref, shifts, scores, applied, warnings)
