"""Camera response curve from exposure brackets (Debevec & Malik 1997; Robertson et al. 2003).

The curve is the camera's *inverse* response per channel: a ``(256, 3)`` float array mapping an
8-bit code (rows) to relative linear exposure ``E·t`` (columns R, G, B), normalised so that
code 128 maps to exactly 1.0 in every channel (the per-channel scale is not observable from
brackets; white balance is the colour profile's job). The HDR merge consumes exactly this array.

References
----------
- P. Debevec, J. Malik, "Recovering High Dynamic Range Radiance Maps from Photographs",
  SIGGRAPH 1997 (``cv2.createCalibrateDebevec``).
- M. Robertson, S. Borman, R. Stevenson, "Estimation-theoretic approach to dynamic range
  enhancement using multiple exposures", JEI 2003 (``cv2.createCalibrateRobertson``).
  Measured here: OpenCV's Robertson is biased by up to ~0.35 stops on noise-free synthetic
  gamma-2.2 brackets (Debevec: 0.04 stops), so Debevec is the default.

"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from solidkit.calibration.profile import Profile, make_provenance
from solidkit.camera.metadata import read_metadata
from solidkit.envmap.io import imread
from solidkit.errors import InputError, SolidkitError
from solidkit.fsutil import atomic_path
from solidkit.threads import helper_threads

__all__ = [
    "NORMALISATION_CODE",
    "ResponseProfile",
    "read_brackets",
    "calibrate_response",
    "default_smoothness",
    "exposure_order_conflicts",
    "response_sanity",
    "radiance_consistency",
    "plot_response",
    "make_monotonic",
    "calibrate_response_files",
]

NORMALISATION_CODE = 128
Method = Literal["debevec", "robertson"]


class ResponseError(SolidkitError):
    """The brackets cannot determine a response curve (too few, mismatched, no exposure times)."""


class ResponseProfile(Profile):
    """Inverse camera response: ``curve[code, channel]`` = relative linear exposure (code 128 -> 1)."""

    KIND = "response"
    method: str
    channels: str = "RGB"
    normalisation: str = f"curve[{NORMALISATION_CODE}, c] = 1 for every channel c"
    curve: list[list[float]] = Field(description="256 rows (8-bit code) x 3 columns (R, G, B)")
    exposure_times_s: list[float] = Field(default_factory=list)
    sanity: dict = Field(default_factory=dict)

    def array(self) -> np.ndarray:
        """The curve as a ``(256, 3)`` float32 array."""
        a = np.asarray(self.curve, dtype=np.float32)
        if a.shape != (256, 3):
            raise InputError(f"response curve has shape {a.shape}, expected (256, 3)")
        return a


def read_brackets(
    paths: Sequence[str | os.PathLike], times: Sequence[float] | None = None
) -> tuple[list[np.ndarray], np.ndarray]:
    """Read an exposure bracket as RGB uint8 images plus exposure times in seconds.

    Exposure times come from EXIF ``ExposureTime`` unless ``times`` is given. Raises
    :class:`ResponseError` when sizes differ, a time is missing, or fewer than 2 distinct times.
    """
    if len(paths) < 2:
        raise ResponseError(f"a response curve needs at least 2 bracketed images, got {len(paths)}")
    images: list[np.ndarray] = []
    ts: list[float] = []
    for _, p in enumerate(paths):
        p = Path(p)
        img = imread(p, cv2.IMREAD_COLOR)
        images.append(np.ascontiguousarray(img[..., ::-1]))
        if times is None:
            try:
                t = read_metadata(p).exposure_time
            except InputError:  # readable by OpenCV but not a JPEG/TIFF (e.g. PNG): no EXIF
                t = None
            if t is None:
                raise ResponseError(f"{p}: no EXIF ExposureTime; pass the exposure times explicitly")
            ts.append(t)
    if times is not None:
        if len(times) != len(paths):
            raise ResponseError(f"{len(times)} exposure times for {len(paths)} images")
        ts = [float(t) for t in times]
    if any(t <= 0 for t in ts):
        raise ResponseError(f"exposure times must be positive, got {ts}")
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise ResponseError(f"bracketed images differ in size: {sorted(shapes)}")
    if len(set(ts)) < 2:
        raise ResponseError(f"the bracket needs at least 2 distinct exposure times, got {ts}")
    return images, np.asarray(ts, dtype=np.float64)


def calibrate_response(
    images: Sequence[np.ndarray],
    times: Sequence[float] | np.ndarray,
    method: Method = "debevec",
    samples: int = 400,
    smoothness: float = 10.0,
) -> np.ndarray:
    """Estimate the inverse response per channel from aligned brackets.

    Parameters
    ----------
    images : sequence of (H, W, 3) uint8
        The bracket (any channel order; the curve's columns follow it).
    times : sequence of float
        Exposure times in seconds (only their ratios matter).
    method : "debevec" or "robertson"
    samples, smoothness : Debevec's pixel sample count and smoothness weight (lambda).

    Returns
    -------
    (256, 3) float64 : relative linear exposure per code, ``curve[128] = 1``.
    """
    imgs = [np.ascontiguousarray(im) for im in images]
    if any(im.dtype != np.uint8 or im.ndim != 3 or im.shape[2] != 3 for im in imgs):
        raise ResponseError("response calibration needs 8-bit 3-channel images")
    t = np.asarray(times, dtype=np.float32)
    if method == "debevec":
        n_px = imgs[0].shape[0] * imgs[0].shape[1]
        if not 1 <= samples <= n_px:
            raise ResponseError(f"Debevec samples must be in 1..{n_px} (the pixels of one image), got {samples}")
        raw = _debevec_per_channel(imgs, t, int(samples), float(smoothness))
    elif method == "robertson":
        raw = cv2.createCalibrateRobertson().process(imgs, t)[:, 0, :].astype(np.float64)
    else:
        raise ResponseError(f"unknown response method {method!r} (debevec or robertson)")
    curve = _fill_unobserved(raw)
    if not np.all(np.isfinite(curve)) or np.any(curve[NORMALISATION_CODE] <= 0):
        raise ResponseError(f"{method} produced a degenerate curve (the bracket may not overlap in exposure)")
    return curve / curve[NORMALISATION_CODE]


def _debevec_per_channel(images: list[np.ndarray], t: np.ndarray, samples: int, smoothness: float) -> np.ndarray:
    """OpenCV's Debevec curve ``(256, C)`` float64, each channel's solve in its own thread.

    OpenCV solves the channels one after the other (an SVD each, most of a 1920x960 merge's time); a
    channel's equations are the same whether it comes alone or with the others (the same sample points,
    weights and solve), so the curve is the same bits, in a half to a third of the time on two or three cores.
    """
    n = images[0].shape[2]

    def solve(c: int) -> np.ndarray:
        frames = [np.ascontiguousarray(im[..., c]) for im in images]
        return cv2.createCalibrateDebevec(samples=samples, lambda_=smoothness).process(frames, t).reshape(256)

    if helper_threads() <= 1:
        out = [solve(c) for c in range(n)]
    else:  # a thread per channel even on two cores: the three solves end together, not in two waves
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(n) as pool:  # OpenCV releases the GIL while it solves
            out = list(pool.map(solve, range(n)))
    return np.stack(out, axis=-1).astype(np.float64)


def default_smoothness(samples: int) -> float:
    """Debevec's smoothness weight for ``samples`` pixels: OpenCV's lambda = 10 for its 70, scaled with the samples.

    The data term grows with the samples; at a fixed lambda more samples fit the noise (400 samples with
    lambda 10 gave curves that bent back, moved by up to 0.65 stops when made monotonic).
    """
    return 10.0 * samples / 70.0


def exposure_order_conflicts(
    images: Sequence[np.ndarray], times: Sequence[float], *, step: int = 4, min_ratio: float = 1.25
) -> list[tuple[int, int, float]]:
    """Pairs of frames whose brightness contradicts their exposure times: ``[(shorter, longer, fraction), ...]``.

    ``images``: the frames (8-bit codes, or values normalised to ``[0, 1]``); ``times``: their
    exposures. Frames next to each other in exposure order (at least ``min_ratio`` apart) are compared
    on every ``step``-th pixel that is neither black nor saturated in both and differs by more than two
    8-bit codes: the longer exposure must be the brighter one. A pair is returned (indices into
    ``images``) when the longer exposure is the *darker* on more than 75 % of those pixels (the
    ``fraction``); a correct bracket scores near 0, times given in reverse order near 1.
    """
    order = sorted(range(len(images)), key=lambda i: times[i])
    lum = []
    for im in images:
        arr = np.asarray(im)
        top = float(np.iinfo(arr.dtype).max) if np.issubdtype(arr.dtype, np.integer) else 1.0
        sub = arr[::step, ::step].astype(np.float32) * np.float32(255.0 / top)  # in 8-bit code units
        lum.append(sub.mean(axis=-1) if sub.ndim == 3 else sub)
    out = []
    for a, b in zip(order, order[1:]):
        if times[b] < times[a] * min_ratio:
            continue
        za, zb = lum[a], lum[b]
        inside = ~(((za < 6) & (zb < 6)) | ((za > 249) & (zb > 249)))
        diff = (zb - za)[inside]
        moved = diff[np.abs(diff) > 2]
        if moved.size < max(50, 0.01 * za.size):
            continue
        darker = float(np.mean(moved < 0))
        if darker > 0.75:
            out.append((a, b, darker))
    return out


def _fill_unobserved(curve: np.ndarray, edge: int = 5) -> np.ndarray:
    """Fill codes the fit left undefined (NaN/non-positive: never observed) in the log domain.

    Inner gaps are interpolated linearly in log2; the ends are extrapolated with the mean slope
    of the ``edge`` nearest defined codes. A channel with fewer than 2 defined codes stays NaN.
    """
    out = curve.copy()
    codes = np.arange(curve.shape[0])
    for c in range(curve.shape[1]):
        ok = np.isfinite(curve[:, c]) & (curve[:, c] > 0)
        if ok.all() or ok.sum() < 2:
            continue
        k = codes[ok]
        lg = np.log2(curve[ok, c])
        filled = np.interp(codes, k, lg)
        n = min(edge, len(k) - 1)
        lo_slope = (lg[n] - lg[0]) / (k[n] - k[0])
        hi_slope = (lg[-1] - lg[-1 - n]) / (k[-1] - k[-1 - n])
        filled = np.where(codes < k[0], lg[0] + (codes - k[0]) * lo_slope, filled)
        filled = np.where(codes > k[-1], lg[-1] + (codes - k[-1]) * hi_slope, filled)
        out[:, c] = 2.0**filled
    return out


def _smooth(x: np.ndarray, k: int = 5) -> np.ndarray:
    pad = np.pad(x, ((k // 2, k // 2), (0, 0)), mode="edge")
    kern = np.ones(k) / k
    return np.stack([np.convolve(pad[:, c], kern, mode="valid") for c in range(x.shape[1])], 1)


def response_sanity(curve: np.ndarray, images: Sequence[np.ndarray] | None = None, margin: int = 5) -> dict:
    """Sanity checks of a ``(256, C)`` inverse response.

    - ``monotonic``: the log curve, smoothed over 5 codes, strictly increases over the covered
      codes (per channel; the list of offending codes is given when it does not).
    - ``coverage``: the fraction of the 256 codes observed in ``images`` per channel, and the
      observed code range; codes outside it are extrapolated by the fit's smoothness term.
    - ``dynamic_range_stops``: log2(curve[254] / curve[1]) per channel.
    """
    curve = np.asarray(curve, dtype=np.float64)
    logc = np.log2(np.maximum(curve, 1e-30))
    sm = _smooth(logc)
    out: dict = {"channels": curve.shape[1]}
    lo, hi = margin, 255 - margin
    if images is not None:
        stack = np.stack([np.asarray(im).reshape(-1, curve.shape[1]) for im in images])
        cover, ranges = [], []
        for c in range(curve.shape[1]):
            hist = np.bincount(stack[..., c].ravel(), minlength=256)
            seen = np.nonzero(hist)[0]
            cover.append(float((hist > 0).mean()))
            ranges.append([int(seen.min()), int(seen.max())])
        out["coverage_fraction"] = cover
        out["code_range"] = ranges
        lo = max(lo, max(r[0] for r in ranges))
        hi = min(hi, min(r[1] for r in ranges))
    d = np.diff(sm[lo : hi + 1], axis=0)
    bad = [[int(lo + i + 1) for i in np.nonzero(d[:, c] <= 0)[0]] for c in range(curve.shape[1])]
    out["checked_codes"] = [int(lo), int(hi)]
    out["monotonic"] = all(not b for b in bad)
    out["non_monotonic_codes"] = bad
    out["dynamic_range_stops"] = [float(logc[254, c] - logc[1, c]) for c in range(curve.shape[1])]
    return out


def radiance_consistency(
    curve: np.ndarray, images: Sequence[np.ndarray], times: Sequence[float] | np.ndarray, lo: int = 10, hi: int = 245
) -> dict:
    """How well one radiance explains every exposure: the fit's residual.

    For every pixel and channel, each exposure with a code in ``[lo, hi]`` gives a radiance
    estimate ``curve[Z] / t``; the residual is the RMS deviation (in stops) of those estimates
    from their per-pixel mean, over pixels seen well exposed in at least two exposures.
    """
    curve = np.asarray(curve, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    Z = np.stack([np.asarray(im) for im in images])  # (n, H, W, C)
    logE = np.log2(np.maximum(curve, 1e-30))
    per = []
    for c in range(Z.shape[-1]):
        z = Z[..., c].reshape(len(t), -1)
        ok = (z >= lo) & (z <= hi)
        est = logE[z, c] - np.log2(t)[:, None]
        n = ok.sum(0)
        use = n >= 2
        mean = np.where(ok, est, 0).sum(0)[use] / n[use]
        dev = np.where(ok[:, use], est[:, use] - mean, 0)
        per.append(float(np.sqrt((dev**2).sum() / max(ok[:, use].sum(), 1))) if use.any() else float("nan"))
    return {"rms_stops_per_channel": per, "code_window": [lo, hi]}


def plot_response(curve: np.ndarray, path: str | os.PathLike, title: str = "inverse camera response") -> Path:
    """Plot log2 relative exposure vs code per channel into ``path`` (PNG, written atomically)."""
    import matplotlib  # lazy: only the plot needs it (about 1 s to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = np.asarray(curve)
    fig, ax = plt.subplots(figsize=(5, 4), dpi=100)
    for c, col in zip(range(curve.shape[1]), ("tab:red", "tab:green", "tab:blue")):
        ax.plot(np.arange(256), np.log2(np.maximum(curve[:, c], 1e-30)), color=col, label="RGB"[c])
    ax.set_xlabel("8-bit code")
    ax.set_ylabel("log2 relative exposure (code 128 = 0)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def make_monotonic(curve: np.ndarray, min_step_stops: float = 1e-4) -> np.ndarray:
    """Nearest strictly increasing curve per channel (least squares in log2, pool-adjacent-violators).

    Applied after the fit so that every code maps to a distinct exposure (the HDR merge requires
    a non-decreasing curve); codes 128 keeps its value 1 up to the re-normalisation.
    """
    curve = np.asarray(curve, dtype=np.float64)
    out = np.empty_like(curve)
    ramp = min_step_stops * np.arange(curve.shape[0])
    for c in range(curve.shape[1]):
        y = np.log2(np.maximum(curve[:, c], 1e-30)) - ramp  # strict increase = non-decrease after the ramp
        vals, wts, lens = [], [], []
        for v in y:
            vals.append(v)
            wts.append(1.0)
            lens.append(1)
            while len(vals) > 1 and vals[-2] > vals[-1]:
                w = wts[-2] + wts[-1]
                v2 = (vals[-2] * wts[-2] + vals[-1] * wts[-1]) / w
                n = lens[-2] + lens[-1]
                del vals[-1], wts[-1], lens[-1]
                vals[-1], wts[-1], lens[-1] = v2, w, n
        out[:, c] = 2.0 ** (np.repeat(vals, lens) + ramp)
    return out / out[NORMALISATION_CODE]


def calibrate_response_files(
    paths: Sequence[str | os.PathLike],
    times: Sequence[float] | None = None,
    method: Method = "debevec",
    samples: int = 400,
    smoothness: float | None = None,
    enforce_monotonic: bool = True,
) -> ResponseProfile:
    """Read a bracket, fit the inverse response and return the profile with sanity and residuals.

    ``smoothness`` (Debevec's lambda) defaults to :func:`default_smoothness` of ``samples``: the same
    fit as the one ``capture merge`` estimates from a bracket when no curve is given, so a calibrated
    curve merges those frames as well as the merge's own estimate. Frames whose brightness contradicts
    their exposure times (:func:`exposure_order_conflicts`) are a :class:`ResponseError` naming them.

    ``sanity`` describes the raw fit; with ``enforce_monotonic`` the saved curve is its nearest
    strictly increasing version (:func:`make_monotonic`), ``sanity["monotonic_fix_max_stops"]``
    says how far that moved it and ``sanity["radiance_rms_stops_raw_fit"]`` how well the raw fit explained
    the frames (against ``residuals`` for the saved curve).
    """
    images, ts = read_brackets(paths, times)
    conflicts = exposure_order_conflicts(images, list(ts))
    if conflicts:
        names = [Path(p).name for p in paths]
        raise ResponseError(
            "the exposure times contradict the frames: "
            + "; ".join(
                f"{names[b]} ({ts[b]:.6g} s) is darker than {names[a]} ({ts[a]:.6g} s) on {100 * f:.0f} % of the "
                "pixels that differ"
                for a, b, f in conflicts
            )
            + "; give the times in the order of the frames"
        )
    if smoothness is None:
        smoothness = default_smoothness(samples)
    raw = calibrate_response(images, ts, method=method, samples=samples, smoothness=smoothness)
    sanity = response_sanity(raw, images)
    curve = raw
    if enforce_monotonic:
        curve = make_monotonic(raw)
        sanity["monotonic_fix_max_stops"] = float(np.abs(np.log2(curve / raw)).max())
        sanity["radiance_rms_stops_raw_fit"] = radiance_consistency(raw, images, ts)["rms_stops_per_channel"]
    prov = make_provenance(
        list(paths),
        tool="solidkit.calibration.response.calibrate_response",
        method=method,
        samples=samples,
        smoothness=smoothness,
        enforce_monotonic=enforce_monotonic,
        times_from="cli" if times is not None else "exif",
    )
    return ResponseProfile(
        provenance=prov,
        method=method,
        curve=curve.tolist(),
        exposure_times_s=ts.tolist(),
        sanity=sanity,
        residuals=radiance_consistency(curve, images, ts),
    )
