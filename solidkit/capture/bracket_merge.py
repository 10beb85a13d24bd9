"""One bracket of files -> one merged linear HDR image and its provenance (shared by ``capture merge`` and ``ingest``).

The steps, each recorded in the provenance:

1. **Read by content**, not by file name (:func:`solidkit.capture.frame_merge.sniff_format`): a JPEG
   named ``.png`` is read as the JPEG it is (and said so); raw files (DNG, ...) linearly.
2. **Check the exposure times** against the frames: a frame darker than a shorter exposure
   (:func:`solidkit.calibration.response.exposure_order_conflicts`, e.g. times given in the wrong
   order) is an :class:`~solidkit.errors.InputError` naming both frames.
3. **Register** the frames (:mod:`solidkit.capture.register`: phase correlation as the cheap test,
   ECC where it may pay), undo a measured shift only where it improves the frames' agreement,
   warn about frames that do not register; each frame's decision is recorded.
4. **Response curve** (:mod:`solidkit.capture.selfcal`): the given one (checked on the frames: a
   warning when it explains them clearly worse than a curve estimated from them); else, with 3+
   8-bit frames, one estimated from the (registered) bracket itself; else the sRGB inverse,
   *assumed* and warned about. Raw frames are linear and need none.
5. **Merge** (:func:`solidkit.capture.frame_merge.merge_frames`): weights, saturation/black, ghosts.

:func:`merge_bracket` returns the :class:`~solidkit.capture.frame_merge.MergeResult` and a
provenance dict (``inputs``, ``response``, ``registration``, ``warnings``, ``stats``) that
:func:`merge_files` and the ingest's HDR products write into the EXR
header and the manifest.
"""

from __future__ import annotations

import dataclasses
import errno
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
from PIL import Image

from solidkit import __version__
from solidkit.calibration.response import exposure_order_conflicts
from solidkit.camera.metadata import CaptureMetadata, read_metadata
from solidkit.camera.raw import is_raw_file, read_raw
from solidkit.capture.bracket_groups import ShotInfo, gain_from, group_brackets, sequence_from_name
from solidkit.capture.frame_merge import (
    DEFAULT_BLACK,
    DEFAULT_SATURATION,
    Frame,
    MergeResult,
    effective_exposure,
    frame_from_ldr,
    frame_from_raw,
    load_response,
    merge_frames,
    read_ldr_codes,
    sniff_frame,
    validate_response,
)
from solidkit.capture.register import register_frames, shift_image
from solidkit.capture.selfcal import check_given_response, response_for_bracket
from solidkit.envmap.io import write_exr, write_ldr
from solidkit.errors import InputError
from solidkit.fsutil import sha256_file
from solidkit.threads import deterministic

__all__ = ["merge_bracket", "merge_files", "read_codes"]

_CONTENT_SUFFIXES = {"jpeg": (".jpg", ".jpeg", ".jpe"), "png": (".png",), "tiff": (".tif", ".tiff", ".dng")}


def read_codes(path: Path) -> tuple[np.ndarray | None, Any, list[str]]:
    """``(codes, raw, warnings)``: an LDR frame's codes (raw None) or a raw frame (codes None), by content."""
    path, kind = sniff_frame(path)
    warnings = []
    if kind in _CONTENT_SUFFIXES and path.suffix.lower() not in _CONTENT_SUFFIXES[kind] and not is_raw_file(path):
        warnings.append(
            f"content_not_suffix: {path.name} is a {kind.upper()} file named {path.suffix}; read as {kind.upper()}"
        )
    if is_raw_file(path) or kind == "raw":
        return None, read_raw(path), warnings
    return read_ldr_codes(path), None, warnings


def merge_bracket(
    paths: Sequence[str | Path],
    exposures: Sequence[float],
    *,
    response: np.ndarray | None = None,
    response_record: dict[str, Any] | None = None,
    align: bool = True,
    ghost_k: float = 6.0,
    deghost: bool = False,
    wb: Any = "camera",
) -> tuple[MergeResult, dict[str, Any]]:
    """Merge one bracket (module docstring). ``exposures``: effective exposures (s) in ``paths`` order.

    ``response``/``response_record``: a curve the user gave and how to record it (None: estimate
    from the frames when possible, else assume sRGB with a warning). Merged with the BLAS libraries on
    one thread (:func:`solidkit.threads.deterministic`): the curve's solve, and so every pixel, is the
    same whatever the thread count.
    """
    with deterministic():
        return _merge_bracket(
            paths,
            exposures,
            response=response,
            response_record=response_record,
            align=align,
            ghost_k=ghost_k,
            deghost=deghost,
            wb=wb,
        )


def _merge_bracket(
    sources: Sequence[str | Path],
    exposures: Sequence[float],
    *,
    response: np.ndarray | None,
    response_record: dict[str, Any] | None,
    align: bool,
    ghost_k: float,
    deghost: bool,
    wb: Any,
) -> tuple[MergeResult, dict[str, Any]]:
    paths = [Path(p) for p in sources]
    warnings: list[str] = []
    decoded = []
    for p in paths:
        codes, raw, w = read_codes(p) if not is_raw_file(p) else (None, read_raw(p, wb=wb), [])
        decoded.append((codes, raw))
        warnings += w
    ldr = all(c is not None for c, _ in decoded)
    if not ldr and any(c is not None for c, _ in decoded):
        raise InputError("a bracket mixes raw and LDR frames: merge them separately")
    shapes = [(c if c is not None else np.asarray(r.linear)).shape[:2] for c, r in decoded]
    for p, shp in zip(paths[1:], shapes[1:]):  # before registration: it needs frames of one size
        if shp != shapes[0]:
            raise InputError(
                f"frame {p.name} is {shp[1]}x{shp[0]}, expected {shapes[0][1]}x{shapes[0][0]} like {paths[0].name}"
            )

    _check_exposure_order(paths, exposures, [c if c is not None else np.asarray(r.linear) for c, r in decoded])

    def frames_with(curve: np.ndarray | None) -> list[Frame]:
        if ldr:
            return [
                frame_from_ldr(cast(np.ndarray, c), t, curve, name=p.name)
                for (c, _), t, p in zip(decoded, exposures, paths)
            ]
        return [frame_from_raw(r, t, name=p.name) for (_, r), t, p in zip(decoded, exposures, paths)]

    registration = None
    if align and len(paths) >= 2:
        if ldr and all(cast(np.ndarray, c).dtype == np.uint8 for c, _ in decoded):
            # 8-bit frames are ranked by their codes: no curve, no linear copies needed to find shifts
            eight = [cast(np.ndarray, c) for c, _ in decoded]
            reg = register_frames(eight, eight, list(exposures), [_valid_codes(c) for c in eight])
        else:
            provisional = frames_with(response)  # sRGB (or the given curve) is enough to find shifts
            reg = register_frames(
                [f.codes if ldr else np.clip(f.linear * 255, 0, 255).astype(np.uint8) for f in provisional],
                [f.linear for f in provisional],
                list(exposures),
                [cast(np.ndarray, f.valid().all(axis=-1)) for f in provisional],
                rank_codes=False,
            )
        warnings += reg.warnings
        registration = reg.to_json()
        for i, (dx, dy) in enumerate(reg.shifts):
            if reg.applied[i]:
                c, r = decoded[i]
                if ldr:
                    decoded[i] = (shift_image(cast(np.ndarray, c), dx, dy), None)
                else:
                    assert r is not None  # a raw frame
                    decoded[i] = (
                        None,
                        dataclasses.replace(  # RawImage is frozen
                            r,
                            linear=shift_image(np.asarray(r.linear, np.float32), dx, dy),
                            saturated=shift_image(np.asarray(r.saturated, np.uint8), dx, dy).astype(bool),
                        ),
                    )
    if ldr and all(cast(np.ndarray, c).dtype == np.uint8 for c, _ in decoded):
        eight_bit = [cast(np.ndarray, c) for c, _ in decoded]
        curve, record, w = response_for_bracket(eight_bit, list(exposures), response, response_record)
        warnings += w
        if response is not None:
            warnings += check_given_response(response, eight_bit, list(exposures))
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
        "parameters": {
            "ghost_k": ghost_k,
            "deghost": deghost,
            "wb": str(wb),
            "align": align,
            "saturation": DEFAULT_SATURATION,
            "black": DEFAULT_BLACK,
        },
        "stats": result.stats(),
    }
    return result, provenance


def _valid_codes(codes: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: the 8-bit pixels a :class:`Frame` counts as well exposed in every channel (above black,
    none saturated), from the codes alone."""
    grid = np.arange(256) / 255.0
    lowest = np.uint8(np.argmax(grid > DEFAULT_BLACK))  # the first code above black
    saturated = np.uint8(np.ceil(DEFAULT_SATURATION * 255.0))
    r, g, b = codes[..., 0], codes[..., 1], codes[..., 2]  # (NumPy's reductions over an axis of 3 are slow)
    return cast(np.ndarray, (np.minimum(np.minimum(r, g), b) >= lowest) & (np.maximum(np.maximum(r, g), b) < saturated))


def _check_exposure_order(paths: Sequence[Path], exposures: Sequence[float], images: Sequence[np.ndarray]) -> None:
    """:class:`InputError` naming the frames whose brightness contradicts their exposure times."""
    conflicts = exposure_order_conflicts(images, list(exposures))
    if not conflicts:
        return
    pairs = "; ".join(
        f"{paths[b].name} ({exposures[b]:.6g} s) is darker than {paths[a].name} ({exposures[a]:.6g} s) "
        f"on {100 * frac:.0f} % of the pixels that differ"
        for a, b, frac in conflicts
    )
    raise InputError(
        f"the exposure times contradict the frames: {pairs}; give the times in the order of the frames "
        "(--times t1,t2,...) or check the frames' metadata"
    )


def _bracket_infos(paths: Sequence[Path], times: Sequence[float] | None) -> list[tuple[Path, Any, float]]:
    """(path, metadata, exposure time in s) per file; times from ``times`` or EXIF."""
    if times is not None and len(times) != len(paths):
        raise InputError(f"--times has {len(times)} value(s) for {len(paths)} frame(s)")
    out = []
    for i, p in enumerate(paths):
        if sniff_frame(p)[1] == "png":  # no EXIF in PNG: size only
            with Image.open(p) as im:
                meta = CaptureMetadata(path=str(p), width=im.width, height=im.height, warnings=["no_exif: PNG file"])
        else:
            meta = read_metadata(p)
        t: float | None
        if times is not None:
            t = float(times[i])
            if not (np.isfinite(t) and t > 0):
                raise InputError(f"--times: exposure time {times[i]} for {p.name} is not positive")
        else:
            t = meta.exposure_time
            if not t or t <= 0:
                raise InputError(f"{p}: no exposure time in the metadata; pass --times t1,t2,...")
        out.append((p, meta, float(t)))
    return out


def merge_files(
    paths: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    times: Sequence[float] | None = None,
    response_path: str | os.PathLike | None = None,
    response: np.ndarray | None = None,
    group: bool = True,
    max_gap_s: float = 10.0,
    deghost: bool = False,
    ghost_k: float = 6.0,
    ghost_mask_path: str | os.PathLike | None = None,
    wb: Any = "camera",
    progress: Any = None,
    align: bool = True,
) -> list[dict[str, Any]]:
    """Group ``paths`` into brackets, merge each and write EXR(s) with provenance.

    One bracket is written to ``out``; several to ``<stem>-1.exr``, ``<stem>-2.exr``, ... in
    capture order (``group=False`` merges all frames as one bracket). Exposure times come from
    the metadata (scaled by ISO and f-number relative to the bracket's first frame) or from
    ``times`` (seconds, in the order of ``paths``, taken as effective exposures). Each bracket
    goes through :func:`solidkit.capture.bracket_merge.merge_bracket` (read by content, registered
    unless ``align=False``, response given / estimated from the frames / sRGB assumed with a
    warning). The EXR's ``solidkit`` attribute holds ``exposure_time`` (the reference frame's),
    ``units`` and ``provenance`` (inputs with sha256, times, response and where it came from,
    registration shifts, warnings, parameters, solidkit version, merge statistics). Returns one
    summary dict per written file.
    """
    files = [Path(p) for p in paths]
    if not files:
        raise InputError("no frames given")
    if len(set(p.resolve() for p in files)) != len(files):
        raise InputError("the same file is given more than once")
    out = Path(out)
    if out.suffix.lower() != ".exr":
        raise InputError(f"{out}: the output must be an .exr file")
    for folder in (out.parent, *out.parent.parents):  # before the merge, which would be lost
        if folder.exists():
            if not folder.is_dir():
                raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(folder))
            break
    if response is not None and response_path is not None:
        raise InputError("give a response array or a response file, not both")
    given = (
        load_response(response_path)
        if response_path is not None
        else (validate_response(response) if response is not None else None)
    )
    given_record: dict[str, Any] | None = (
        {"kind": "file", "path": str(response_path), "sha256": sha256_file(response_path)}
        if response_path is not None
        else {"kind": "array"}
        if response is not None
        else None
    )
    infos = _bracket_infos(files, times)
    if group and times is None:
        shots = [
            ShotInfo(
                key=str(i),
                time=m.datetime_original,
                sequence=m.sequence if m.sequence is not None else sequence_from_name(p.name),
                exposure=t,
                camera=" ".join(x for x in (m.make, m.model, m.serial) if x),
                size=(m.width, m.height),
                name=p.name,
                gain=gain_from(m.iso, m.f_number),
            )
            for i, (p, m, t) in enumerate(infos)
        ]
        brackets = [[infos[int(s.key)] for s in g] for g in group_brackets(shots, max_gap_s=max_gap_s)]
    else:
        brackets = [infos]
    outputs = (
        [out]
        if len(brackets) == 1
        else [out.with_name(f"{out.stem}-{i + 1}{out.suffix}") for i in range(len(brackets))]
    )
    summaries: list[dict[str, Any]] = []
    for bracket, target in zip(brackets, outputs):
        if len(bracket) < 2:
            raise InputError(
                f"{bracket[0][0].name} forms a bracket of one frame (by time/sequence/exposure); "
                "pass the frames of one bracket, or --no-group to merge them as one"
            )
        ref_meta = bracket[0][1]
        effs, inputs = [], []
        for p, m, t in bracket:
            eff = t if times is not None else effective_exposure(t, m.iso, m.f_number, ref_meta.iso, ref_meta.f_number)
            effs.append(eff)
            inputs.append(
                {
                    "path": str(p),
                    "sha256": sha256_file(p),
                    "exposure_time": t,
                    "effective_exposure": eff,
                    "iso": m.iso,
                    "f_number": m.f_number,
                }
            )
        result, prov = merge_bracket(
            [p for p, _, _ in bracket],
            effs,
            response=given,
            response_record=given_record,
            align=align,
            ghost_k=ghost_k,
            deghost=deghost,
            wb=wb,
        )
        if progress is not None:
            for _ in bracket:
                progress()
        stats = prov["stats"]
        meta = {
            "exposure_time": bracket[0][2],
            "units": "relative radiance: linear code per second at the first frame's ISO and f-number",
            "provenance": {"tool": "solidkit capture merge", "solidkit_version": __version__, "inputs": inputs, **prov},
        }
        write_exr(target, result.hdr, meta)
        mask_file = None
        if ghost_mask_path is not None:
            gm = Path(ghost_mask_path)
            mask_file = gm if len(brackets) == 1 else gm.with_name(f"{gm.stem}-{len(summaries) + 1}{gm.suffix}")
            write_ldr(mask_file, (result.ghost.astype(np.uint8) * 255)[..., None].repeat(3, axis=2))
        summaries.append(
            {
                "output": str(target),
                "frames": [str(p) for p, _, _ in bracket],
                "ghost_mask": str(mask_file) if mask_file else None,
                "response": prov["response"],
                "registration": prov["registration"],
                "warnings": prov["warnings"],
                **stats,
            }
        )
    return summaries
