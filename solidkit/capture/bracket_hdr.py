"""One bracket of files -> one merged linear HDR image and its provenance (shared by ``capture merge`` and ``ingest``).

The steps, each recorded in the provenance:

1. **Read by content**, not by file name (:func:`solidkit.capture.merge.sniff_format`): a JPEG
   named ``.png`` is read as the JPEG it is (and said so); raw files (DNG, ...) linearly.
2. **Register** the frames (:mod:`solidkit.capture.register`: MTB + phase correlation),
   undo measured shifts of ``min_shift_px`` or more, warn about frames that do not register.
3. **Response curve** (:mod:`solidkit.capture.selfcal`): the given one; else, with 3+ 8-bit
   frames, one estimated from the (registered) bracket itself; else the sRGB inverse,
   *assumed* and warned about. Raw frames are linear and need none.
4. **Merge** (:func:`solidkit.capture.merge.merge_frames`): weights, saturation/black, ghosts.

:func:`merge_bracket` returns the :class:`~solidkit.capture.merge.MergeResult` and a
provenance dict (``inputs``, ``response``, ``registration``, ``warnings``, ``stats``) that
:func:`solidkit.capture.merge.merge_files` and the ingest's HDR products write into the EXR
header and the manifest.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from solidkit.camera.raw import is_raw_file, read_raw
from solidkit.capture.merge import (DEFAULT_BLACK, DEFAULT_SATURATION, Frame, MergeResult, frame_from_ldr,
                                    frame_from_raw, merge_frames, read_ldr_codes, sniff_format)
from solidkit.capture.register import register_frames, shift_image
from solidkit.capture.selfcal import response_for_bracket
from solidkit.errors import InputError

__all__ = ["merge_bracket", "read_codes"]

_CONTENT_SUFFIXES = {"jpeg": (".jpg", ".jpeg", ".jpe"), "png": (".png",), "tiff": (".tif", ".tiff", ".dng")}


def read_codes(path: Path) -> tuple[np.ndarray | None, Any, list[str]]:
    """``(codes, raw, warnings)``: an LDR frame's codes (raw None) or a raw frame (codes None), by content."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: empty file (0 bytes)")
    kind = sniff_format(path)
    warnings = []
    if kind in _CONTENT_SUFFIXES and path.suffix.lower() not in _CONTENT_SUFFIXES[kind] and not is_raw_file(path):
        warnings.append(f"content_not_suffix: {path.name} is a {kind.upper()} file named {path.suffix}; read as {kind.upper()}")
    if is_raw_file(path) or kind == "raw":
        return None, read_raw(path), warnings
    return read_ldr_codes(path), None, warnings


def merge_bracket(paths: Sequence[str | Path], exposures: Sequence[float], *, response: np.ndarray | None = None,
                  response_record: dict[str, Any] | None = None, align: bool = True, ghost_k: float = 6.0,
                  deghost: bool = False, wb: Any = "camera") -> tuple[MergeResult, dict[str, Any]]:
    """Merge one bracket (module docstring). ``exposures``: effective exposures (s) in ``paths`` order.

    ``response``/``response_record``: a curve the user gave and how to record it (None: estimate
    from the frames when possible, else assume sRGB with a warning).
    """
    paths = [Path(p) for p in paths]
    warnings: list[str] = []
    decoded = []
    for p in paths:
        codes, raw, w = read_codes(p) if not is_raw_file(p) else (None, read_raw(p, wb=wb), [])
        decoded.append((codes, raw))
        warnings += w
    ldr = all(c is not None for c, _ in decoded)
    if not ldr and any(c is not None for c, _ in decoded):
        raise InputError("a bracket mixes raw and LDR frames: merge them separately")

    def frames_with(curve: np.ndarray | None) -> list[Frame]:
        if ldr:
            return [frame_from_ldr(c, t, curve, name=p.name) for (c, _), t, p in zip(decoded, exposures, paths)]
        return [frame_from_raw(r, t, name=p.name) for (_, r), t, p in zip(decoded, exposures, paths)]

    registration = None
    if align and len(paths) >= 2:
        provisional = frames_with(response)  # sRGB (or the given curve) is enough to find shifts
        reg = register_frames([f.codes if ldr else np.clip(f.linear * 255, 0, 255).astype(np.uint8) for f in provisional],
                              [f.linear for f in provisional], list(exposures),
                              [f.valid().all(axis=-1) for f in provisional])
        warnings += reg.warnings
        registration = reg.to_json()
        for i, (dx, dy) in enumerate(reg.shifts):
            if reg.applied[i]:
                c, r = decoded[i]
                if ldr:
                    decoded[i] = (shift_image(c, dx, dy), None)
                else:
                    r.linear = shift_image(np.asarray(r.linear, np.float32), dx, dy)
                    r.saturated = shift_image(np.asarray(r.saturated, np.uint8), dx, dy).astype(bool)
    if ldr and all(c.dtype == np.uint8 for c, _ in decoded):
        curve, record, w = response_for_bracket([c for c, _ in decoded], list(exposures), response, response_record)
        warnings += w
    elif ldr:  # 16-bit frames: the given curve, else sRGB (looked up at fractional codes)
        curve, record, w = response_for_bracket(None, list(exposures), response, response_record)
        warnings += w
    else:
        curve, record = None, {"kind": "linear_raw"}
    result = merge_frames(frames_with(curve), ghost_k=ghost_k, deghost=deghost)
    provenance = {
        "response": record,
        "registration": registration,
        "warnings": warnings,
        "parameters": {"ghost_k": ghost_k, "deghost": deghost, "wb": str(wb), "align": align,
                       "saturation": DEFAULT_SATURATION, "black": DEFAULT_BLACK},
        "stats": result.stats(),
    }
    return result, provenance
