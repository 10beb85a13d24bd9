"""``solidkit capture ...``: Theta capture commands. Angles are degrees at this edge (conventions §6).

Writers take ``-o/--out``; every command takes ``--json`` (the result as JSON on stdout).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from solidkit.camera.metadata import read_metadata
from solidkit.cli.output import echo_json
from solidkit.cli.parsing import parse_angle, parse_exposures, parse_floats, parse_size
from solidkit.errors import InputError
from solidkit.fsutil import jpeg_truncated

app = typer.Typer(no_args_is_help=True)
console = Console()


@app.command()
def info(
    files: list[Path] = typer.Argument(..., help="JPEG or DNG captures."),
    as_json: bool = typer.Option(False, "--json", help="Print the metadata as JSON (one object per file)."),
) -> None:
    """Metadata of captures: EXIF exposure, GPS, GPano, Ricoh image type, zenith correction, gravity."""
    from solidkit.capture.products import stored_tilt

    for path in files:
        meta = read_metadata(path)
        if meta.file_format == "jpeg" and jpeg_truncated(path):  # read_metadata reads the header only
            raise InputError(f"{path}: truncated JPEG (no end-of-image marker)")
        if as_json:
            tilt = stored_tilt(path, meta)
            echo_json({**meta.model_dump(mode="json"), "residual_tilt": None if tilt is None else tilt.to_json()})
            continue
        table = Table(title=str(path), show_header=False)
        table.add_row("size", f"{meta.width} x {meta.height} ({meta.file_format})")
        table.add_row("camera", " ".join(x for x in (meta.make, meta.model, meta.serial) if x) or "-")
        table.add_row("image type", meta.image_type)
        expo = meta.exposure_time
        shutter = f"1/{round(1 / expo, 1):g}" if expo and expo < 1 else expo
        table.add_row("exposure", f"{shutter} s, f/{meta.f_number}, ISO {meta.iso}")
        table.add_row("taken (camera clock)", f"{meta.datetime_original} {meta.utc_offset or ''}")
        table.add_row("zenith corrected", str(meta.zenith_corrected))
        if meta.pitch_deg is not None:
            table.add_row(
                "pitch / roll", f"{meta.pitch_deg:.2f}° / {meta.roll_deg:.2f}°  ({escape(meta.gravity_source or '')})"
            )
        if meta.heading_deg is not None:
            table.add_row("heading", f"{meta.heading_deg:.1f}°")
        if meta.gps:
            table.add_row("gps", json.dumps(meta.gps))
        if meta.gpano:
            table.add_row("GPano", escape(", ".join(f"{k}={v}" for k, v in meta.gpano.items())))
        tilt = stored_tilt(path, meta)
        if tilt is not None:
            table.add_row(
                "residual tilt (as stored)",
                f"{tilt.tilt_deg:.2f}° ± {tilt.uncertainty_deg:.2f}° "
                f"(correction pitch {tilt.pitch_deg:.2f}°, roll {tilt.roll_deg:.2f}°; {tilt.segments} vertical edges"
                + ("" if tilt.reliable else "; unreliable")
                + ")",
            )
        for w in meta.warnings:
            table.add_row("[yellow]warning[/]", escape(w))
        console.print(table)


@app.command()
def merge(
    frames: list[Path] = typer.Argument(..., help="Bracket frames (JPEG via the response curve, DNG linearly)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output EXR (several brackets: OUT-1.exr, OUT-2.exr, ...)."),
    times: str | None = typer.Option(
        None, "--times", help="Exposure times in seconds, comma-separated, in FRAMES order (default: EXIF)."
    ),
    response: Path | None = typer.Option(
        None,
        "--response",
        help=(
            "Inverse response curve (.json profile, .npy, .csv); default: estimated from the bracket (3+ frames), else "
            "sRGB assumed (warned)."
        ),
    ),
    align: bool = typer.Option(
        True, "--align/--no-align", help="Register the frames (sub-pixel shifts) before merging."
    ),
    group: bool = typer.Option(
        True, "--group/--no-group", help="Split FRAMES into brackets by time, sequence and exposure."
    ),
    deghost: bool = typer.Option(False, "--deghost", help="Replace ghost pixels by the reference frame."),
    ghost_mask: Path | None = typer.Option(None, "--ghost-mask", help="Write the ghost mask as a PNG."),
    wb: str = typer.Option("camera", "--wb", help="Raw white balance: camera, daylight, none or r,g,b."),
    as_json: bool = typer.Option(False, "--json", help="Print the merge statistics as JSON."),
) -> None:
    """Merge exposure brackets into linear HDR EXR (weights, saturation/black exclusion, ghost report)."""
    from solidkit.capture.bracket_merge import merge_files  # on use: the other capture commands start without it

    t = parse_exposures(times, "--times") if times else None
    wb_arg: object = tuple(parse_floats(wb, "--wb", 3, positive=True)) if "," in wb else wb
    if isinstance(wb_arg, str) and wb_arg not in ("camera", "daylight", "none"):
        raise InputError(f"--wb: unknown white balance '{wb}' (camera, daylight, none or r,g,b)")
    summaries = merge_files(
        frames,
        out,
        times=t,
        response_path=response,
        group=group,
        deghost=deghost,
        ghost_mask_path=ghost_mask,
        wb=wb_arg,
        align=align,
    )
    if as_json:
        echo_json(summaries, indent=2)
        return
    for s in summaries:
        table = Table(title=escape(s["output"]), show_header=False)
        table.add_row("frames", escape(", ".join(Path(f).name for f in s["frames"])))
        table.add_row("exposures (s)", ", ".join(f"{e:.6g}" for e in s["exposures"]))
        table.add_row("dynamic range", f"{s['dynamic_range_stops']:.1f} stops")
        table.add_row(
            "saturated in every frame", f"{100 * s['saturated_in_all_frames_fraction']:.2f} % (shortest exposure used)"
        )
        table.add_row("black in every frame", f"{100 * s['underexposed_in_all_frames_fraction']:.2f} %")
        table.add_row(
            "ghosts",
            f"{100 * s['ghost_fraction']:.2f} % of pixels"
            + (f" -> {escape(s['ghost_mask'])}" if s["ghost_mask"] else ""),
        )
        rk = s["response"]["kind"]
        table.add_row(
            "response curve",
            {
                "file": f"given ({escape(str(s['response'].get('path')))})",
                "array": "given",
                "estimated": f"estimated from these {s['response'].get('frames')} frames (Debevec)",
                "linear_raw": "none needed (raw frames)",
            }.get(rk, "[yellow]sRGB assumed[/]"),
        )
        if s.get("registration"):
            reg = s["registration"]
            table.add_row("frame shifts (px)", "; ".join(_frame_shift(reg, i) for i in range(len(reg["shifts_px"]))))
        console.print(table)
        for w in s["warnings"]:
            console.print(f"[yellow]warning[/] {escape(w)}")


_DECISIONS = {
    "reference": "reference",
    "no_overlap": "too little in common with the reference: unshifted",
    "static": "static (phase correlation): unshifted",
    "below_min_shift": "below 0.25 px: unshifted",
    "no_improvement": "not applied: does not improve the agreement",
    "not_registered": "does not register: unshifted",
}


def _frame_shift(reg: dict, i: int) -> str:
    """One frame's registration in words: its shift and what was decided (with the agreement when measured)."""
    (dx, dy), decision = reg["shifts_px"][i], (reg.get("decision") or [""] * (i + 1))[i]
    agr = (reg.get("agreement_unshifted_shifted") or [None] * (i + 1))[i]
    said = _DECISIONS.get(decision, "applied" if reg["applied"][i] else "not applied")
    if agr is not None and decision in ("applied", "no_improvement"):
        said += f" (disagreement {agr[0]:.4f} -> {agr[1]:.4f})"
    return f"({dx:+.2f}, {dy:+.2f}) {said}"


def _print_many(results: list[dict], out: Path, as_json: bool) -> None:
    """One row per capture of a multi-capture unwarp (or the summaries as JSON)."""
    if as_json:
        echo_json(results, indent=1, default=str)
        return
    table = Table(title=escape(f"{len(results)} captures -> {out}"))
    for col in ("capture", "mode", "seam error", "coverage", "time", "notes"):
        table.add_column(col)
    for r in results:
        if "error" in r:
            table.add_row(escape(Path(r["input"]).name), "[red]failed[/]", "", "", "", escape(r["error"]))
            continue
        fit = r.get("profile_fit") or {}
        seam = fit.get("seam_error")
        table.add_row(
            escape(Path(r["input"]).name),
            escape(r["mode"]),
            "" if seam is None else f"{seam:.3f}",
            f"{100 * r['coverage']:.2f} %" if "coverage" in r else "",
            f"{r['seconds']:.2f} s",
            escape("; ".join(r["warnings"])),
        )
    console.print(table)
    failed = sum("error" in r for r in results)
    total = sum(r.get("seconds", 0.0) for r in results)
    console.print(f"{len(results) - failed} unwarped, {failed} failed; {total:.1f} s in all")


@app.command()
def unwarp(
    sources: list[Path] = typer.Argument(
        ..., help="Dual-fisheye (JPEG, DNG, EXR) or stitched equirect captures, or folders of them."
    ),
    out: Path = typer.Option(
        ...,
        "-o",
        "--out",
        help=(
            "One capture: the output panorama, .exr (linear HDR) or .png/.jpg (sRGB). Several captures or a folder: "
            "the output folder (one <stem>.<--format> each)."
        ),
    ),
    fmt: str = typer.Option("exr", "--format", help="Output type of several captures: exr, png or jpg."),
    profile: str | None = typer.Option(
        None,
        "--profile",
        help=(
            "Lens profile: a shipped name (theta-v, theta-z1, theta-s, theta-s-video) or a unit.json; default from the "
            "EXIF model."
        ),
    ),
    size: str | None = typer.Option(
        None, "--size", help="Output WxH (W = 2H); default: as wide as the input (the size ingest products get too)."
    ),
    feather: float = typer.Option(10.0, "--feather", help="Seam cross-fade band, degrees of incidence angle."),
    level: str = typer.Option(
        "auto",
        "--level",
        help=(
            "Levelling: auto (the metadata's gravity when it gives one that applies, else the image's own vertical "
            "edges), metadata, content (the gravity, then the edges), off. A content correction is kept only when it "
            "lowers the measured tilt."
        ),
    ),
    no_level: bool = typer.Option(False, "--no-level", help="The same as --level off."),
    gain: bool = typer.Option(True, "--gain/--no-gain", help="Match the lenses' gains on the overlap (linear light)."),
    cache_dir: Path | None = typer.Option(
        None,
        "--cache-dir",
        help=(
            "On-disk cache of remap tables (default: per user, ~/.cache/solidkit/<version>/unwarp; $SOLIDKIT_CACHE_DIR "
            "overrides)."
        ),
    ),
    disk_cache: bool = typer.Option(
        True,
        "--disk-cache/--no-disk-cache",
        help=(
            "Keep remap tables on disk between runs (a second file of the same camera and size skips the table build)."
        ),
    ),
    vignetting: Path | None = typer.Option(
        None,
        "--vignetting",
        help=(
            "Vignetting profile (solidkit calibrate vignetting): each lens divided by its falloff before gain matching "
            "and blending."
        ),
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """Dual-fisheye -> equirectangular panorama in the panorama frame (docs/conventions.md)."""
    out_height = parse_size(size, "--size", equirect=True)[1] if size is not None else None
    feather = parse_angle(feather, "--feather", 0.0, 180.0)
    from solidkit.capture.unwarp import default_cache_dir, unwarp_file, unwarp_files

    cache_dir = (cache_dir or default_cache_dir()) if disk_cache else None
    options: dict[str, Any] = dict(
        profile=profile,
        out_height=out_height,
        feather_deg=feather,
        level="off" if no_level else level,
        gain_match=gain,
        cache_dir=cache_dir,
        vignetting=vignetting,
    )
    if len(sources) > 1 or sources[0].is_dir():
        results = unwarp_files(sources, out, fmt=fmt, **options)
        _print_many(results, out, as_json)
        if any("error" in r for r in results):
            raise typer.Exit(2)
        return
    s = unwarp_file(sources[0], out, **options)
    if as_json:
        echo_json(s, indent=1, default=str)
        return
    table = Table(title=escape(str(out)), show_header=False)
    table.add_row("mode", escape(s["mode"]))
    if "profile" in s:
        table.add_row("profile / size", f"{escape(s['profile'])} -> {s['size'][0]} x {s['size'][1]}")
        table.add_row(
            "vignetting", "corrected before blending" if s.get("vignetting") else "not corrected (no --vignetting)"
        )
        table.add_row("lens gains (R,G,B)", "; ".join(", ".join(f"{g:.3f}" for g in lg) for lg in s["gains"]))
        table.add_row(
            "seam disagreement",
            f"median |diff| {s['seam_mad']:.4g} (before gain match {s['seam_mad_before_gain']:.4g}), rmse "
            f"{s['seam_rmse']:.4g}",
        )
        fit = s.get("profile_fit") or {}
        if fit:
            d = fit.get("seam_disparity") or {}
            disp = (
                "unmeasured (too little texture in the overlap)"
                if d.get("median_deg") is None
                else f"{d['median_deg']:.2f}° median, {100 * d['doubled_fraction']:.0f} % of {d['matches']} "
                f"matches over 1°"
            )
            seam = "unmeasured (dark or clipped frame)" if fit.get("seam_error") is None else f"{fit['seam_error']:.3f}"
            table.add_row(
                "profile fit",
                f"seam disparity {disp} (warns above {fit['seam_disparity_warn_deg']:g}°); seam error {seam} "
                f"(decides where the disparity is unmeasured, above {fit['seam_error_warn']}); "
                f"layout {'ok' if fit.get('ok') else '[yellow]see warnings[/]'}",
            )
        table.add_row("coverage", f"{100 * s['coverage']:.2f} % of output pixels")
        table.add_row("remap tables", s["cache"])
    if s.get("level_pitch_roll_deg"):
        table.add_row("levelled (pitch, roll)", ", ".join(f"{a:.2f}°" for a in s["level_pitch_roll_deg"]))
    lv = s.get("levelling")
    if lv:
        before, after = lv["tilt_before_deg"], lv["tilt_after_deg"]
        table.add_row(
            "levelled by content",
            (
                f"tilt {before:.2f}° -> {after:.2f}° (correction pitch, roll "
                + ", ".join(f"{a:.2f}°" for a in lv["correction_pitch_roll_deg"])
                + ")"
            )
            if lv["applied"]
            else f"no: {escape(lv.get('note', ''))}",
        )
    if s.get("residual_tilt"):
        t = s["residual_tilt"]
        table.add_row(
            "residual tilt (vertical edges)",
            f"{t['tilt_deg']:.2f}° ± {t['uncertainty_deg']:.2f}° from {t['segments']} edges"
            + ("" if t["reliable"] else " [dim](unreliable: few vertical edges)[/]"),
        )
    table.add_row("time", f"{s['seconds']:.2f} s")
    for w in s["warnings"]:
        table.add_row("[yellow]warning[/]", escape(w))
    console.print(table)
