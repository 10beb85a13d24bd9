"""Merge the frames of an exposure bracket into one linear HDR image, with ghost detection.

Model (Debevec & Malik, SIGGRAPH 1997; Robertson, Borman & Stevenson, JEI 2003): frame ``i``
with effective exposure ``t_i`` records ``Z_i = f(E · t_i)`` (clipped, noisy, quantised). With
the inverse response ``R = f⁻¹`` (a ``(256, 3)`` table: 8-bit code -> relative linear exposure;
the sRGB inverse by default, a calibrated curve from :mod:`solidkit.calibration` otherwise)
each frame gives an estimate ``R(Z_i) / t_i`` of the radiance ``E``; the merge is the weighted
mean

    ``E = Σ_i w_i · R(Z_i) / t_i  /  Σ_i w_i``,   ``w_i = h(Z_i) · t_i``,

with Debevec's hat ``h`` in code space (zero at the black and saturation limits) times the
exposure (longer exposures collect more light: higher SNR for the same code, cf. Granados
et al., CVPR 2010). RAW frames are already linear: ``h = 1`` on valid photosites.

- A frame's pixel is excluded when any channel is saturated (code >= ``saturation``) and, per
  channel, when it is black (code <= ``black``).
- A pixel saturated in every frame takes the shortest exposure's value (a lower bound) and is
  flagged in ``MergeResult.saturated``; one black in every frame takes the longest exposure's
  value and is flagged in ``MergeResult.underexposed``.
- Ghosts: each frame's code is predicted from the merged radiance (``f(E · t_i)``); pixels whose
  residual exceeds ``ghost_k`` robust standard deviations (per frame, median absolute
  deviation over all valid pixels) in any frame, after a 3x3 opening that removes isolated
  noise, form the ghost mask. ``deghost=True`` replaces ghost pixels by the reference frame's
  estimate (the frame with the most well-exposed pixels) where that frame is valid.

Units: the output is ``code-linear units per second`` at the bracket's reference ISO and
f-number (``effective_exposure``), i.e. relative radiance; absolute calibration is the
Calibration issue's business.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image, ImageOps

from solidkit.calibration.response import ResponseProfile
from solidkit.camera.raw import is_raw_file, read_raw
from solidkit.envmap.io import check_image_size, jpeg_damage, srgb_decode
from solidkit.envmap.sun import LUMINANCE_WEIGHTS
from solidkit.errors import InputError, SolidkitError
from solidkit.threads import helper_threads

__all__ = [
    "Frame",
    "MergeResult",
    "srgb_response",
    "validate_response",
    "load_response",
    "hat_weight",
    "frame_from_ldr",
    "frame_from_raw",
    "load_frame",
    "merge_frames",
    "detect_ghosts",
    "dynamic_range_stops",
    "effective_exposure",
    "sniff_format",
    "sniff_frame",
    "lookup",
    "BLOCK_ROWS",
]

DEFAULT_SATURATION = 0.97  # code fraction (≈ 247/255): JPEG ringing sits just below 255
DEFAULT_BLACK = 0.02  # code fraction (≈ 5/255)
_LUMA = LUMINANCE_WEIGHTS


# --------------------------------------------------------------------------- response curves
def srgb_response() -> np.ndarray:
    """The default inverse response: sRGB decoding of each 8-bit code, ``(256, 3)`` float64."""
    codes = np.arange(256, dtype=np.float64) / 255.0
    return np.repeat(np.asarray(srgb_decode(codes), dtype=np.float64)[:, None], 3, axis=1)


def validate_response(response: Any) -> np.ndarray:
    """Check an inverse response curve and return it as ``(256, 3)`` float64.

    Accepts ``(256,)``, ``(256, 1)`` or ``(256, 3)``: entry ``[z, c]`` is the relative linear
    exposure that produced 8-bit code ``z`` in channel ``c``. It must be finite, non-negative
    and non-decreasing with ``R[255] > R[0]``; the overall scale is irrelevant.
    """
    r = np.asarray(response, dtype=np.float64)
    if r.ndim == 1:
        r = r[:, None]
    if r.ndim != 2 or r.shape[0] != 256 or r.shape[1] not in (1, 3):
        raise InputError(f"response curve must have shape (256, 3) (or (256,)); got {np.shape(response)}")
    if r.shape[1] == 1:
        r = np.repeat(r, 3, axis=1)
    if not np.all(np.isfinite(r)):
        raise InputError("response curve contains NaN or Inf")
    if np.any(r < 0):
        raise InputError("response curve has negative values (it maps codes to linear exposure >= 0)")
    if np.any(np.diff(r, axis=0) < 0):
        raise InputError("response curve is not non-decreasing in the code value")
    if np.any(r[-1] <= r[0]):
        raise InputError("response curve is constant in some channel")
    return r


def load_response(path: str | os.PathLike) -> np.ndarray:
    """Read an inverse response curve from ``.npy``, ``.csv``/``.txt`` (256 rows) or ``.json``.

    JSON: a :class:`solidkit.calibration.response.ResponseProfile` (``"kind": "response"``,
    validated by its loader), a 256 x 3 list, or an object holding one under ``response``,
    ``inverse_response``, ``curve`` or ``g`` (``g`` = natural log of exposure, Debevec's
    convention, exponentiated here).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such response file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
        elif suffix in (".csv", ".txt"):
            arr = np.loadtxt(path, delimiter="," if suffix == ".csv" else None)
        elif suffix == ".json":
            data = json.loads(path.read_text())
            arr = None
            if isinstance(data, list):
                arr = np.asarray(data, dtype=np.float64)
            elif isinstance(data, dict) and data.get("kind") == "response":
                arr = ResponseProfile.from_dict(data, str(path)).array()
            elif isinstance(data, dict):
                for key in ("response", "inverse_response", "curve"):
                    if key in data:
                        arr = np.asarray(data[key], dtype=np.float64)
                        break
                else:
                    if "g" in data:
                        arr = np.exp(np.asarray(data["g"], dtype=np.float64))
            if arr is None:
                raise InputError(f"{path}: no response curve found (expected a 256x3 list or a 'response' key)")
        else:
            raise InputError(f"{path}: unknown response file type '{suffix}' (use .npy, .csv, .txt or .json)")
    except SolidkitError:
        raise
    except Exception as exc:
        raise InputError(f"{path}: cannot read response curve ({exc})") from None
    return validate_response(arr)


def hat_weight(code: np.ndarray, black: float = DEFAULT_BLACK, saturation: float = DEFAULT_SATURATION) -> np.ndarray:
    """Debevec & Malik's hat weight on normalised codes in ``[0, 1]``.

    Linear ramps from 0 at ``black`` to 1 at the midpoint and back to 0 at ``saturation``;
    a floor of 1e-3 inside the open interval keeps a pixel that is valid in one frame only.
    """
    mid = 0.5 * (black + saturation)
    half = 0.5 * (saturation - black)
    w = 1.0 - np.abs(code - mid) / half
    inside = (code > black) & (code < saturation)
    return np.where(inside, np.maximum(w, 1e-3), 0.0).astype(np.float32)


# --------------------------------------------------------------------------- frames
def _any3(x: np.ndarray) -> np.ndarray:
    """``x.any(axis=-1)`` for a last axis of 3 (NumPy's small-axis reduction is slow)."""
    return x[..., 0] | x[..., 1] | x[..., 2]


def lookup(codes: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``table[codes]`` for ``(H, W, 3)`` uint8 codes; ``table`` is ``(256,)`` or per channel ``(256, 3)``.

    Through ``cv2.LUT`` (several times faster than NumPy fancy indexing); bool tables give bool.
    """
    table = np.asarray(table)
    is_bool = table.dtype == bool
    t: np.ndarray = table.astype(np.uint8) if is_bool else table.astype(np.float32)
    if t.ndim == 2:
        t = np.ascontiguousarray(t.reshape(256, 1, t.shape[1]))
    out = cv2.LUT(np.ascontiguousarray(codes), t)
    return out.view(bool) if is_bool else out


@dataclass
class Frame:
    """One frame of a bracket, decoded.

    Attributes
    ----------
    linear : (H, W, 3) float32
        Relative linear exposure ``R(Z)`` (response applied; raw: normalised sensor values).
    codes : (H, W, 3) uint8 or float32
        The recorded values: 8-bit codes, or values normalised to ``[0, 1]`` (16-bit input; raw
        frames: the clipped linear values). :attr:`code` gives them normalised.
    exposure : float
        Effective exposure (seconds, scaled to the bracket's reference ISO and f-number).
    saturated : (H, W) bool
        Any channel clipped.
    response : (256, 3) or None
        The inverse response for LDR frames; ``None`` for linear (raw) frames.
    name : str
        A label (file name) for reports.
    black, saturation : float
        Normalised code limits of the usable range.
    """

    linear: np.ndarray
    codes: np.ndarray
    exposure: float
    saturated: np.ndarray
    response: np.ndarray | None = None
    name: str = ""
    black: float = DEFAULT_BLACK
    saturation: float = DEFAULT_SATURATION

    @property
    def is_raw(self) -> bool:
        return self.response is None

    @property
    def code(self) -> np.ndarray:
        """``(H, W, 3)`` float32 codes normalised to ``[0, 1]``."""
        if self.codes.dtype == np.uint8:
            return self.codes.astype(np.float32) * np.float32(1.0 / 255.0)
        return self.codes

    def _per_code(self, table: np.ndarray) -> np.ndarray:
        """``table[codes]`` for 8-bit codes (a 256-entry lookup, per channel when ``(256, 3)``)."""
        return lookup(self.codes, table)

    def valid(self) -> np.ndarray:
        """``(H, W, 3)`` bool: usable samples (not saturated anywhere, channel above black); cached."""
        cached = self.__dict__.get("_valid")
        if cached is not None:
            return cached
        if self.codes.dtype == np.uint8:
            above = self._per_code(np.arange(256) / 255.0 > self.black)
        else:
            above = self.codes > self.black
        above &= ~self.saturated[..., None]
        self.__dict__["_valid"] = above
        return above

    def residual(self, radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Disagreement with ``radiance`` in the noise domain, and where it is meaningful.

        LDR: ``(R(Z) − E·t) · dZ/dR`` at the observed code (first order in code units; a
        256-entry slope table, no per-pixel curve inversion), meaningful where the frame is
        valid and ``E·t`` falls inside the valid code range. Raw: ``sqrt(L) − sqrt(E·t)``
        (variance-stabilised shot noise). Returns ``(|residual| (H, W, 3) float32, mask)``.
        """
        x = radiance * np.float32(self.exposure)
        valid = self.valid().copy()
        if self.is_raw:
            return np.abs(np.sqrt(np.clip(self.linear, 0.0, None)) - np.sqrt(np.clip(x, 0.0, None))), valid
        assert self.response is not None  # an LDR frame
        grid = np.arange(256, dtype=np.float64) / 255.0
        for c in range(3):
            lo = np.interp(self.black, grid, self.response[:, c])
            hi = np.interp(self.saturation, grid, self.response[:, c])
            valid[..., c] &= (x[..., c] > lo) & (x[..., c] < hi)
        if self.codes.dtype == np.uint8:
            slope = np.gradient(self.response, axis=0) * 255.0  # dR / d(normalised code)
            floor = 1e-6 * float(np.abs(self.response).max())
            inv = (1.0 / np.maximum(slope, floor)).astype(np.float32)
            res = np.abs(self.linear - x)
            res *= self._per_code(inv)
            return res, valid
        return np.abs(self.code - self.predict(radiance)), valid

    def base_weight(self) -> np.ndarray:
        """``(H, W, 3)`` float32 code-space weight (hat for LDR, 1 for raw) on valid samples."""
        if self.is_raw:
            return self.valid().astype(np.float32)
        if self.codes.dtype == np.uint8:
            w = self._per_code(hat_weight(np.arange(256) / 255.0, self.black, self.saturation))
        else:
            w = hat_weight(self.codes, self.black, self.saturation)
        w *= ~self.saturated[..., None]
        return w

    def observed(self) -> np.ndarray:
        """The frame in its noise domain (codes for LDR, sqrt of linear for raw)."""
        return self.code if not self.is_raw else np.sqrt(np.clip(self.linear, 0.0, None))

    def predict(self, radiance: np.ndarray) -> np.ndarray:
        """Predicted observation for ``radiance`` (H, W, 3): ``f(E · t)`` in the noise domain."""
        x = radiance * np.float32(self.exposure)
        if self.is_raw:
            return np.sqrt(np.clip(x, 0.0, None))
        assert self.response is not None  # an LDR frame
        codes = np.arange(256, dtype=np.float64) / 255.0
        out = np.empty_like(x, dtype=np.float32)
        for c in range(3):
            out[..., c] = np.interp(x[..., c], self.response[:, c], codes)
        return out


def frame_from_ldr(
    image: np.ndarray,
    exposure: float,
    response: np.ndarray | None = None,
    *,
    name: str = "",
    black: float = DEFAULT_BLACK,
    saturation: float = DEFAULT_SATURATION,
) -> Frame:
    """Build a :class:`Frame` from an 8-bit (or 16-bit) RGB image and its exposure.

    ``response`` is the ``(256, 3)`` inverse response (default: sRGB inverse). 16-bit input is
    looked up at fractional codes (linear interpolation in the table).
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"{name or 'frame'}: expected an (H, W, 3) RGB image, got {img.shape}")
    if not (np.isfinite(exposure) and exposure > 0):
        raise InputError(f"{name or 'frame'}: exposure time must be positive, got {exposure}")
    r = srgb_response() if response is None else validate_response(response)
    if img.dtype == np.uint8:
        codes = np.ascontiguousarray(img)
        linear = lookup(codes, r.astype(np.float32))  # one pass through the table
        saturated = _any3(codes >= np.uint8(np.ceil(saturation * 255.0)))
    else:
        if np.issubdtype(img.dtype, np.integer):
            codes = img.astype(np.float32) / float(np.iinfo(img.dtype).max)
        else:
            codes = np.clip(img.astype(np.float32), 0.0, 1.0)
        grid = np.arange(256, dtype=np.float64) / 255.0
        linear = np.stack([np.interp(codes[..., c], grid, r[:, c]) for c in range(3)], axis=-1).astype(np.float32)
        saturated = _any3(codes >= saturation)
    return Frame(linear, codes, float(exposure), saturated, r, name, black, saturation)


def frame_from_raw(raw: Any, exposure: float, *, name: str = "", black: float = 0.0) -> Frame:
    """Build a :class:`Frame` from a :class:`solidkit.camera.raw.RawImage` (linear)."""
    if not (np.isfinite(exposure) and exposure > 0):
        raise InputError(f"{name or 'frame'}: exposure time must be positive, got {exposure}")
    linear = np.asarray(raw.linear, dtype=np.float32)
    codes = np.clip(linear, 0.0, 1.0)
    return Frame(linear, codes, float(exposure), np.asarray(raw.saturated, bool), None, name, black, 1.0 + 1e-6)


def sniff_format(path: str | os.PathLike) -> str:
    """``"jpeg"``, ``"png"``, ``"tiff"`` (TIFF, DNG and most raws) or ``"unknown"`` from magic bytes."""
    with open(path, "rb") as f:
        head = f.read(12)
    if head[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if head[:8] == b"\x89PNG\r\n\x1a\n":
        return "png"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "tiff"
    if head[4:12] in (b"ftypcrx ",):
        return "raw"
    return "unknown"


def read_ldr_codes(path: str | os.PathLike) -> np.ndarray:
    """Decode an LDR image fully (a truncated JPEG is an error, not a grey tail) -> (H, W, 3) uint8/16.

    EXIF orientation is applied so that all frames of a bracket share one geometry.
    """
    path = Path(path)
    check_image_size(path)
    try:
        with warnings.catch_warnings(), Image.open(path) as src:
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # the size is checked above
            src.load()
            im = ImageOps.exif_transpose(src)
            if im.mode in ("I;16", "I;16B", "I"):
                arr = np.asarray(im, dtype=np.uint16)
                arr = np.repeat(arr[..., None], 3, axis=2)
            else:
                arr = np.asarray(im.convert("RGB"))
    except Exception as exc:  # PIL: UnidentifiedImageError, OSError('image file is truncated'), ...
        raise InputError(f"{path}: cannot decode image ({type(exc).__name__}: {exc})") from None
    if sniff_format(path) == "jpeg":
        jpeg_damage(path, warn=True)  # Pillow decodes past corrupt data without a word
    return arr


def effective_exposure(
    exposure_time: float,
    iso: float | None = None,
    f_number: float | None = None,
    ref_iso: float | None = None,
    ref_f_number: float | None = None,
) -> float:
    """Exposure relative to a reference ISO and f-number: ``t · (ISO/ISO_ref) · (N_ref/N)²``.

    Missing ISO or f-number (or reference) leave that factor at 1.
    """
    e = float(exposure_time)
    if iso and ref_iso:
        e *= float(iso) / float(ref_iso)
    if f_number and ref_f_number:
        e *= (float(ref_f_number) / float(f_number)) ** 2
    return e


def sniff_frame(path: str | os.PathLike) -> tuple[Path, str]:
    """A bracket frame's path and its format by content (:func:`sniff_format`); :class:`InputError` when
    the file is missing or empty."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: empty file (0 bytes)")
    return path, sniff_format(path)


def load_frame(
    path: str | os.PathLike, exposure: float, response: np.ndarray | None = None, *, wb: Any = "camera"
) -> Frame:
    """Read one bracket frame from disk (JPEG/PNG/TIFF via the response, DNG/raw linearly)."""
    path, kind = sniff_frame(path)
    suffix = path.suffix.lower()
    if is_raw_file(path):
        return frame_from_raw(read_raw(path, wb=wb), exposure, name=path.name)
    if suffix in (".jpg", ".jpeg") and kind == "tiff":
        raise InputError(f"{path}: content is TIFF/DNG (raw) but the name ends in {path.suffix}; rename it to .dng")
    if suffix in (".jpg", ".jpeg") and kind != "jpeg":
        raise InputError(f"{path}: not a JPEG file (bad signature)")
    return frame_from_ldr(read_ldr_codes(path), exposure, response, name=path.name)


# --------------------------------------------------------------------------- merging
@dataclass
class MergeResult:
    """Output of :func:`merge_frames`.

    ``hdr`` (H, W, 3) float32 relative radiance; masks are (H, W) bool; ``ghost_fraction`` is
    the fraction of pixels in the ghost mask; ``reference`` indexes the reference frame.
    """

    hdr: np.ndarray
    weight_sum: np.ndarray
    saturated: np.ndarray
    underexposed: np.ndarray
    ghost: np.ndarray
    ghost_fraction: float
    reference: int
    exposures: list[float]
    noise_sigma: list[float] = field(default_factory=list)

    def stats(self) -> dict[str, Any]:
        """JSON-friendly summary (fractions, dynamic range in stops)."""
        n = self.hdr.shape[0] * self.hdr.shape[1]
        return {
            "size": [int(self.hdr.shape[1]), int(self.hdr.shape[0])],
            "exposures": self.exposures,
            "reference_frame": self.reference,
            "saturated_in_all_frames_fraction": float(self.saturated.sum() / n),
            "underexposed_in_all_frames_fraction": float(self.underexposed.sum() / n),
            "ghost_fraction": float(self.ghost_fraction),
            "noise_sigma": self.noise_sigma,
            "dynamic_range_stops": dynamic_range_stops(self.hdr, self.saturated | self.underexposed),
        }


def dynamic_range_stops(hdr: np.ndarray, exclude: np.ndarray | None = None, percentile: float = 0.1) -> float:
    """Robust dynamic range: ``log2(p_{100-q} / p_q)`` of positive luminance (q = ``percentile`` %)."""
    lum = np.asarray(hdr, dtype=np.float32) @ _LUMA
    keep = lum > 0
    if exclude is not None:
        keep &= ~exclude
    vals = lum[keep]
    if vals.size < 2:
        return 0.0
    lo, hi = np.percentile(vals, [percentile, 100.0 - percentile])
    return float(np.log2(hi / lo)) if lo > 0 else float("inf")


def _check_frames(frames: Sequence[Frame]) -> None:
    if len(frames) < 1:
        raise InputError("no frames to merge")
    shape = frames[0].linear.shape
    for f in frames[1:]:
        if f.linear.shape != shape:
            raise InputError(
                f"frame {f.name or '?'} is {f.linear.shape[1]}x{f.linear.shape[0]}, "
                f"expected {shape[1]}x{shape[0]} like {frames[0].name or 'the first frame'}"
            )
    order = sorted(range(len(frames)), key=lambda i: frames[i].exposure)
    for a, b in zip(order, order[1:]):
        ea, eb = frames[a].exposure, frames[b].exposure
        if eb <= ea * 1.02:
            raise InputError(
                f"frames {frames[a].name or a} and {frames[b].name or b} have the same exposure "
                f"({ea:.6g} s vs {eb:.6g} s): a bracket needs distinct exposures (check --times)"
            )


BLOCK_ROWS = 128  # rows per processing block: temporaries stay small (cache-friendly, no page-fault storms)


def _blocks(h: int, rows: int = BLOCK_ROWS) -> list[slice]:
    return [slice(r, min(r + rows, h)) for r in range(0, h, rows)]


def _map_blocks(fn: Any, items: Sequence[Any]) -> list[Any]:
    """``[fn(item) for item in items]``, the items spread over :func:`~solidkit.threads.helper_threads` threads
    (at most 4; NumPy and OpenCV release the GIL on a block's arrays). Each block is computed alone, whatever
    thread runs it: the same bits."""
    workers = min(helper_threads(), 4, len(items))
    if workers <= 1:
        return [fn(item) for item in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(fn, items))


def _rows(f: Frame, sl: slice) -> Frame:
    """A view of frame ``f`` restricted to the rows ``sl`` (no copies; ``f``'s cached validity mask carried)."""
    sub = Frame(f.linear[sl], f.codes[sl], f.exposure, f.saturated[sl], f.response, f.name, f.black, f.saturation)
    valid = f.__dict__.get("_valid")
    if valid is not None:
        sub.__dict__["_valid"] = valid[sl]
    return sub


#: Residual blocks of one frame kept between the ghost detector's two passes (bytes); beyond it they are recomputed.
_GHOST_CACHE_BYTES = 192 * 2**20


def merge_frames(
    frames: Sequence[Frame],
    *,
    ghost_k: float = 6.0,
    deghost: bool = False,
) -> MergeResult:
    """Merge frames into linear HDR (see the module docstring for the estimator and masks).

    Processed in blocks of :data:`BLOCK_ROWS` rows (results identical to whole-image processing).

    Parameters
    ----------
    frames : sequence of Frame
        Same size, distinct exposures (raises :class:`InputError` otherwise).
    ghost_k : float
        Ghost threshold in robust standard deviations of each frame's residual.
    deghost : bool
        Replace ghost pixels by the reference frame's estimate.
    """
    _check_frames(frames)
    h, w, _ = frames[0].linear.shape
    hdr = np.empty((h, w, 3), np.float32)
    weight_sum = np.empty((h, w), np.float32)
    sat_all = np.empty((h, w), bool)
    underexposed = np.empty((h, w), bool)
    scores = np.zeros(len(frames))
    i_short = min(range(len(frames)), key=lambda i: frames[i].exposure)
    i_long = max(range(len(frames)), key=lambda i: frames[i].exposure)

    def block(sl: slice) -> list[float]:
        sub = [_rows(f, sl) for f in frames]
        num = np.zeros((sl.stop - sl.start, w, 3), np.float32)
        den = np.zeros_like(num)
        sat = np.ones(num.shape[:2], bool)
        block_scores = []
        for f in sub:
            # w = h(Z) t and estimate R(Z)/t: the numerator term is h(Z) R(Z), the denominator h(Z) t
            hz = f.base_weight()
            block_scores.append(float(hz.sum()))
            num += hz * f.linear
            hz *= np.float32(f.exposure)
            den += hz
            sat &= f.saturated
        empty = den <= 0
        out = np.divide(num, den, out=num, where=~empty)
        out[empty] = 0.0
        fill_short = empty & sat[..., None]
        fill_long = empty & ~sat[..., None]
        out[fill_short] = sub[i_short].linear[fill_short] / np.float32(frames[i_short].exposure)
        out[fill_long] = sub[i_long].linear[fill_long] / np.float32(frames[i_long].exposure)
        hdr[sl], weight_sum[sl], sat_all[sl], underexposed[sl] = (
            out,
            den[..., 0] + den[..., 1] + den[..., 2],
            sat,
            _any3(fill_long),
        )
        return block_scores

    for block_scores in _map_blocks(block, _blocks(h)):  # summed in block order, as one loop would
        for i, v in enumerate(block_scores):
            scores[i] += v
    # reference frame: the one with most well-exposed samples
    ref = int(np.argmax(scores))
    ghost, sigmas = detect_ghosts(frames, hdr, k=ghost_k)
    if deghost and ghost.any():
        rf = frames[ref]
        for sl in _blocks(h):
            ref_rows = _rows(rf, sl)
            ok = ghost[sl][..., None] & ref_rows.valid()
            hdr[sl][ok] = ref_rows.linear[ok] / np.float32(rf.exposure)
    return MergeResult(
        hdr=hdr,
        weight_sum=weight_sum,
        saturated=sat_all,
        underexposed=underexposed,
        ghost=ghost,
        ghost_fraction=float(ghost.mean()),
        reference=ref,
        exposures=[float(f.exposure) for f in frames],
        noise_sigma=sigmas,
    )


def detect_ghosts(
    frames: Sequence[Frame],
    hdr: np.ndarray,
    *,
    k: float = 6.0,
    min_sigma: float = 1.0 / 255.0,
    max_samples: int = 2_000_000,
) -> tuple[np.ndarray, list[float]]:
    """Ghost mask: pixels where some frame disagrees with the merged radiance beyond noise.

    For each frame the residual (:meth:`Frame.residual`: ``observed − f(E · t)`` in code units for
    LDR, in sqrt-linear units for raw) is computed on samples valid in that frame whose
    prediction is also in the valid code range; its noise level is the robust sigma
    ``1.4826 · MAD`` (from a regular subsample: every few row blocks, at most about
    ``max_samples`` residuals; at least
    ``min_sigma``, one 8-bit step). A pixel is a ghost candidate when ``|residual| > k · sigma``
    in any channel of any frame; a 3x3 morphological opening removes isolated candidates
    (noise, JPEG blocks) and a 3x3 dilation restores the blobs' extent.
    Returns ``(mask (H, W) bool, [sigma per frame])``.
    """
    h, w, _ = hdr.shape
    cand = np.zeros((h, w), bool)
    if len(frames) < 2:
        return cand, [0.0 for _ in frames]
    blocks = _blocks(h)
    step = max(1, len(blocks) // 8)  # the noise level from every step-th block (at least 8 blocks)
    stride = max(1, (h * w * 3) // (step * max_samples))
    sigmas: list[float] = []
    for f in frames:
        f.valid()  # once for the whole frame: its blocks share it
        samples, kept, kept_bytes = [], {}, 0
        firsts = list(range(0, len(blocks), step))
        for b, (res, valid) in zip(  # pass 1: the frame's noise level
            firsts, _map_blocks(lambda b: _rows(f, blocks[b]).residual(hdr[blocks[b]]), firsts)
        ):
            samples.append(res[valid][::stride])
            if kept_bytes + res.nbytes + valid.nbytes <= _GHOST_CACHE_BYTES:  # reused by pass 2
                kept[b], kept_bytes = (res, valid), kept_bytes + res.nbytes + valid.nbytes
        del res, valid
        vals = np.concatenate(samples)
        floor = min_sigma if not f.is_raw else 1e-4
        sigma = max(1.4826 * float(np.median(vals)), floor) if vals.size else 0.0
        sigmas.append(sigma)
        if sigma <= 0:
            continue

        def outliers(b: int) -> None:  # pass 2; each block writes its own rows of cand
            sl = blocks[b]
            res, valid = kept.pop(b) if b in kept else _rows(f, sl).residual(hdr[sl])
            cand[sl] |= _any3((res > np.float32(k * sigma)) & valid)

        _map_blocks(outliers, range(len(blocks)))
    kernel = np.ones((3, 3), np.uint8)
    mask = cv2.morphologyEx(cand.astype(np.uint8), cv2.MORPH_OPEN, kernel)
    mask = cv2.dilate(mask, kernel) & cand.astype(np.uint8) | mask
    return mask.astype(bool), sigmas
