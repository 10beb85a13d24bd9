"""The camera's response curve estimated from the bracket being merged (no sRGB assumption).

Without a calibrated curve (``--response``), merging a bracket through the sRGB inverse biases
every frame differently (on a real film bracket the per-frame colour bias drifted
from −0.45 to +0.96 stops). With three or more 8-bit frames the bracket itself constrains the
curve: Debevec & Malik's least-squares fit (SIGGRAPH 1997; OpenCV's ``CalibrateDebevec``
through :func:`solidkit.calibration.response.calibrate_response`) on pixels chosen to cover the
code range evenly, then made strictly increasing per channel
(:func:`solidkit.calibration.response.make_monotonic`).

Samples and smoothness: OpenCV's random draw of ``samples`` = 400 pixels (its default is 70;
black and saturated samples, e.g. outside a dual-fisheye frame's image circles, get zero weight
in Debevec's equations), with the smoothness weight scaled by the same factor (lambda =
10 x 400 / 70): the data term grows with the samples, and without the scaling more samples fit
the noise (on HDR panoramas through simulated film and gamma cameras, 400 samples with lambda 10
merged *worse* than OpenCV's 70/10, with lambda 57 2-3x better: benchmarks/results/merge_selfcal.md).
On the real frobisher bracket the estimated curve brings the ghost detector's false positives
from 4.3 % (sRGB assumed) to 0.4 %.

:func:`response_for_bracket` decides what a merge uses and says so: a given curve
(``"file"``/``"array"``), a curve ``"estimated"`` from these frames, or ``"srgb_assumed"``
(fewer than 3 frames, fewer than :data:`MIN_DISTINCT_CODES` distinct values, 16-bit frames,
or an estimate that failed: the reason is recorded and a warning is returned).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from solidkit.calibration.response import (
    ResponseError,
    calibrate_response,
    default_smoothness,
    make_monotonic,
    radiance_consistency,
    response_sanity,
)
from solidkit.capture.frame_merge import srgb_response

__all__ = ["MIN_FRAMES", "MIN_DISTINCT_CODES", "estimate_response", "response_for_bracket", "check_given_response"]

MIN_FRAMES = 3
#: Fewer distinct 8-bit values than this (per channel, middle exposure) leave the curve between
#: them unconstrained: Debevec then fits the samples and bends in between (a 54-value synthetic
#: gradient merged 3x worse than through sRGB), so sRGB is assumed instead (and said so).
MIN_DISTINCT_CODES = 128


def _distinct_codes(codes: np.ndarray) -> int:
    """Smallest per-channel count of distinct values in an 8-bit image."""
    flat = codes.reshape(-1, codes.shape[-1])
    return int(min(np.count_nonzero(np.bincount(flat[:, c], minlength=256)) for c in range(flat.shape[1])))


def estimate_response(
    images: Sequence[np.ndarray], times: Sequence[float], *, samples: int = 400, smoothness: float | None = None
) -> tuple[np.ndarray, dict[str, Any]]:
    """Inverse response ``(256, 3)`` (``curve[128] = 1``) fitted to the bracket itself, and its record.

    ``images``: 8-bit ``(H, W, 3)`` frames of one static scene (registered); ``times``: their
    effective exposures (only ratios matter). Raises :class:`ResponseError` when the fit fails.
    """
    imgs = [np.ascontiguousarray(im) for im in images]
    t = np.asarray(times, np.float64)
    if smoothness is None:  # OpenCV's lambda = 10 is tuned for its 70 samples: keep the balance
        smoothness = default_smoothness(samples)
    raw = calibrate_response(imgs, t, method="debevec", samples=samples, smoothness=smoothness)
    curve = make_monotonic(raw)
    sanity = response_sanity(curve, [im[::4, ::4] for im in imgs])
    if not all(d > 2.0 for d in sanity["dynamic_range_stops"]):
        raise ResponseError(f"degenerate curve (dynamic range {sanity['dynamic_range_stops']} stops)")
    record = {
        "kind": "estimated",
        "method": "debevec (OpenCV CalibrateDebevec), made monotonic",
        "frames": len(imgs),
        "samples": samples,
        "smoothness": smoothness,
        "monotonic_fix_max_stops": round(float(np.abs(np.log2(curve / np.maximum(raw, 1e-30))).max()), 4),
        "dynamic_range_stops": [round(d, 3) for d in sanity["dynamic_range_stops"]],
        "curve_log2_at_codes": {
            str(c): [round(float(v), 4) for v in np.log2(curve[c])] for c in (16, 64, 128, 192, 240)
        },
    }
    return curve, record


def response_for_bracket(
    images: Sequence[np.ndarray] | None,
    times: Sequence[float],
    given: np.ndarray | None,
    given_record: dict[str, Any] | None,
) -> tuple[np.ndarray | None, dict[str, Any], list[str]]:
    """The curve a bracket merge uses: ``(curve or None for sRGB, record, warnings)``.

    ``images``: the 8-bit frames (None when the frames are raw or 16-bit: linear or decoded
    otherwise); ``given``: a curve the user gave (recorded as ``given_record``).
    """
    if given is not None:
        return given, dict(given_record or {"kind": "array"}), []
    why = None
    if images is None:
        why = "frames are not 8-bit"
    elif len(images) < MIN_FRAMES:
        why = f"{len(images)} frames (estimating a curve needs {MIN_FRAMES}+)"
    elif (distinct := _distinct_codes(images[int(np.argsort(times)[len(times) // 2])])) < MIN_DISTINCT_CODES:
        why = f"the frames show only {distinct} distinct code values (a 256-entry curve needs {MIN_DISTINCT_CODES}+)"
    else:
        try:
            curve, record = estimate_response(images, times)
            return curve, record, []
        except ResponseError as exc:
            why = f"the estimate failed ({exc})"
    record = {"kind": "srgb_assumed", "reason": why}
    return (
        srgb_response(),
        record,
        [
            f"srgb_assumed: no response curve given and {why}; the sRGB inverse is "
            "assumed (calibrate one with 'solidkit calibrate response' and pass --response)"
        ],
    )


def check_given_response(
    given: np.ndarray, images: Sequence[np.ndarray], times: Sequence[float], *, step: int = 4, margin: float = 1.25
) -> list[str]:
    """``["response_check: ..."]`` when a given curve explains these 8-bit frames clearly worse than one estimated
    from them, else ``[]``.

    Both curves' radiance disagreement (:func:`solidkit.calibration.response.radiance_consistency`, RMS
    stops, every ``step``-th pixel) is compared; the given one is flagged above ``margin`` times the
    estimate's plus 0.01 stops (the estimate is fitted to these very frames: it has an edge). Nothing
    is said when no estimate can be made (fewer than :data:`MIN_FRAMES` frames, too few codes, a failed fit).
    """
    if (
        len(images) < MIN_FRAMES
        or _distinct_codes(images[int(np.argsort(times)[len(times) // 2])]) < MIN_DISTINCT_CODES
    ):
        return []
    try:
        own, _ = estimate_response(images, times)
    except ResponseError:
        return []
    small = [np.ascontiguousarray(im[::step, ::step]) for im in images]
    rms_given = float(np.nanmean(radiance_consistency(given, small, times)["rms_stops_per_channel"]))
    rms_own = float(np.nanmean(radiance_consistency(own, small, times)["rms_stops_per_channel"]))
    if not rms_given > margin * rms_own + 0.01:
        return []
    return [
        f"response_check: the given response curve explains these frames worse than one estimated from them "
        f"(radiance disagreement {rms_given:.3f} against {rms_own:.3f} stops RMS); is it this camera's curve at "
        "these settings? (without --response the merge estimates its own)"
    ]
