"""``solidkit envmap ...``: panorama commands. Angles are degrees at this edge (conventions §6).

Writers take ``-o/--out``; every command takes ``--json`` (the result as JSON on stdout).
"""

from __future__ import annotations

import json
import math
from enum import Enum
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from solidkit.cli.output import echo_json
from solidkit.cli.parsing import parse_angle, parse_size
from solidkit.envmap.coords import rotation_from_ypr, solid_angle
from solidkit.envmap.io import LDR_SUFFIXES, read_image, tonemap, validate_panorama, write_exr, write_ldr
from solidkit.envmap.perspective import intrinsics_from_fov, perspective_crop
from solidkit.envmap.resample import rotate as rotate_pano
from solidkit.envmap.sun import detect_sun, luminance
from solidkit.errors import InputError

app = typer.Typer(no_args_is_help=True)
console = Console()


def load_panorama(path: Path) -> tuple[np.ndarray, dict]:
    """Read and validate a panorama file (EXR or LDR); errors are one-line SolidkitErrors."""
    img, meta = read_image(path)
    return validate_panorama(img, str(path)), meta


@app.command()
def info(
    pano: Path = typer.Argument(..., help="Equirectangular panorama (EXR or LDR)."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """Size, dynamic range and radiometric summary of a panorama."""
    img, meta = load_panorama(pano)
    h, w = img.shape[:2]
    lum = luminance(img)
    positive = lum[lum > 0]
    summary = {
        "path": str(pano),
        "width": w,
        "height": h,
        "channels": int(img.shape[2]),
        "kind": "ldr" if meta.get("ldr") else "hdr",
        "luminance_min": float(lum.min()),
        "luminance_max": float(lum.max()),
        "dynamic_range_stops": float(np.log2(positive.max() / max(positive.min(), 1e-12))) if positive.size else None,
        "mean_rgb": [float(c) for c in img.reshape(-1, 3).mean(0)],
        "luminance_integral": float((lum * solid_angle(h)).sum()),
        **{k: meta[k] for k in ("exposure_time", "provenance", "conventions_version") if k in meta},
    }
    if as_json:
        echo_json(summary, default=str)
        return
    table = Table(title=str(pano), show_header=False)
    table.add_row("size", f"{w} x {h} ({img.shape[2]} channels used)")
    table.add_row("kind", "LDR (sRGB decoded to linear)" if meta.get("ldr") else "HDR (linear)")
    table.add_row("min / max luminance", f"{summary['luminance_min']:.4g} / {summary['luminance_max']:.4g}")
    if summary["dynamic_range_stops"] is not None:
        table.add_row("dynamic range", f"{summary['dynamic_range_stops']:.1f} stops")
    table.add_row("mean radiance (RGB)", ", ".join(f"{c:.4g}" for c in summary["mean_rgb"]))
    table.add_row("irradiance integral ∫L dω", f"{summary['luminance_integral']:.4g}")
    for key in ("exposure_time", "provenance", "conventions_version"):
        if key in meta:
            table.add_row(key, json.dumps(meta[key], default=str))
    console.print(table)


class SunMethod(str, Enum):
    """``solidkit envmap sun --method``: see :func:`solidkit.envmap.sun.detect_sun`."""

    core = "core"
    paper = "paper"


@app.command()
def sun(
    pano: Path = typer.Argument(..., help="Equirectangular panorama (EXR, or LDR decoded to linear)."),
    as_json: bool = typer.Option(
        False, "--json", help='Print {"found", "azimuth_deg", "elevation_deg", "confidence"} only.'
    ),
    method: SunMethod = typer.Option(
        SunMethod.core, "--method", help="core: finds the sun (default); paper: the SOLID-Net paper's metric."
    ),
) -> None:
    """Find the sun: azimuth and elevation in degrees (conventions §3), or 'no sun'."""
    img, _ = load_panorama(pano)
    result = detect_sun(img, method=method.value)
    if as_json:
        echo_json(result.to_json())
    elif result.found:
        console.print(
            f"[bold]sun[/bold] azimuth {result.azimuth_deg:.2f}°, elevation {result.elevation_deg:.2f}° "
            f"(pixel {result.x:.2f}, {result.y:.2f}), confidence {result.confidence:.2f} "
            f"[dim]\\[{result.method}: {result.reason}][/dim]",
            highlight=False,
            soft_wrap=True,
        )
    else:
        console.print(
            f"[bold]no sun[/bold] [dim]\\[{result.method}: {result.reason}][/dim]", highlight=False, soft_wrap=True
        )


class Interp(str, Enum):
    """``--interp`` of ``rotate`` / ``crop``."""

    linear = "linear"
    cubic = "cubic"


def _output_writer(pano: Path, out: Path):
    """Check ``out`` before any work (known suffix, not the input file); return its writer."""
    suffix = out.suffix.lower()
    if suffix != ".exr" and suffix not in LDR_SUFFIXES:
        raise InputError(f"{out}: unknown output type '{out.suffix}' (use .exr, or .png/.jpg for a tonemapped LDR)")
    if out.exists() and pano.exists() and out.resolve() == pano.resolve():
        raise InputError(f"{out}: refusing to overwrite the input panorama")

    def write(img: np.ndarray, meta: dict, provenance: dict) -> None:
        if suffix == ".exr":
            attrs = {k: v for k, v in meta.items() if k not in ("header", "ldr", "conventions_version")}
            attrs["provenance"] = provenance if "provenance" not in attrs else [attrs["provenance"], provenance]
            write_exr(out, img, attrs)
        elif meta.get("ldr"):  # LDR in (decoded to linear): encode back to sRGB
            write_ldr(out, img, encode_srgb=True)
        else:  # HDR in: the paper's tonemap (conventions §5)
            write_ldr(out, tonemap(img))

    return write


@app.command()
def rotate(
    pano: Path = typer.Argument(..., help="Equirectangular panorama (EXR or LDR)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output: .exr (linear HDR) or .png/.jpg (tonemapped LDR)."),
    yaw: float = typer.Option(0.0, "--yaw", help="Degrees; > 0 moves the content to the right."),
    pitch: float = typer.Option(0.0, "--pitch", help="Degrees; > 0 moves the forward content up."),
    roll: float = typer.Option(0.0, "--roll", help="Degrees (conventions §4)."),
    interp: Interp = typer.Option(Interp.linear, "--interp", help="Interpolation; cubic output is clamped at 0."),
    as_json: bool = typer.Option(False, "--json", help="Print what was written as JSON."),
) -> None:
    """Rotate a panorama: content in direction d moves to R(yaw, pitch, roll) d (conventions §4)."""
    yaw, pitch, roll = (parse_angle(v, f"--{n}") for v, n in ((yaw, "yaw"), (pitch, "pitch"), (roll, "roll")))
    write = _output_writer(pano, out)
    img, meta = load_panorama(pano)
    R = rotation_from_ypr(math.radians(yaw), math.radians(pitch), math.radians(roll))
    result = rotate_pano(img, R, interp.value)
    if interp is Interp.cubic and img.min() >= 0:
        result = np.maximum(result, 0.0)  # bicubic overshoot next to the sun
    prov = {
        "op": "envmap rotate",
        "source": str(pano),
        "yaw_deg": yaw,
        "pitch_deg": pitch,
        "roll_deg": roll,
        "interp": interp.value,
    }
    write(result, meta, prov)
    if as_json:
        echo_json({**prov, "output": str(out), "size": [result.shape[1], result.shape[0]]})
        return
    console.print(
        f"rotated {pano} by yaw {yaw}°, pitch {pitch}°, roll {roll}° -> {out}", highlight=False, soft_wrap=True
    )


@app.command()
def crop(
    pano: Path = typer.Argument(..., help="Equirectangular panorama (EXR or LDR)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output: .exr (linear HDR) or .png/.jpg (tonemapped LDR)."),
    hfov_deg: float = typer.Option(..., "--hfov-deg", help="Horizontal field of view, degrees (0-180)."),
    yaw: float = typer.Option(0.0, "--yaw", help="Viewing azimuth, degrees (> 0: right)."),
    pitch: float = typer.Option(0.0, "--pitch", help="Viewing elevation, degrees (> 0: up)."),
    roll: float = typer.Option(0.0, "--roll", help="Camera roll, degrees (> 0: right axis down)."),
    size: str = typer.Option(..., "--size", help="Output size WIDTHxHEIGHT in pixels, e.g. 640x480."),
    interp: Interp = typer.Option(Interp.linear, "--interp", help="Interpolation; cubic output is clamped at 0."),
    as_json: bool = typer.Option(False, "--json", help="Print what was written as JSON."),
) -> None:
    """Perspective (pinhole) view of a panorama, camera R(yaw, pitch, roll) (conventions §1, §4)."""
    width, height = parse_size(size)
    fov = parse_angle(hfov_deg, "--hfov-deg", 0.0, 180.0, open_interval=True)
    yaw, pitch, roll = (parse_angle(v, f"--{n}") for v, n in ((yaw, "yaw"), (pitch, "pitch"), (roll, "roll")))
    K = intrinsics_from_fov(math.radians(fov), width, height)
    write = _output_writer(pano, out)
    img, meta = load_panorama(pano)
    R = rotation_from_ypr(math.radians(yaw), math.radians(pitch), math.radians(roll))
    result = perspective_crop(img, R, (width, height), K=K, interp=interp.value)
    if interp is Interp.cubic and img.min() >= 0:
        result = np.maximum(result, 0.0)
    prov = {
        "op": "envmap crop",
        "source": str(pano),
        "fov_deg": fov,
        "yaw_deg": yaw,
        "pitch_deg": pitch,
        "roll_deg": roll,
        "size": [width, height],
        "K": K.tolist(),
        "interp": interp.value,
    }
    write(result, meta, prov)
    if as_json:
        echo_json({**prov, "output": str(out)})
        return
    console.print(
        f"cropped {pano}: {width}x{height}, fov {fov}°, yaw {yaw}°, pitch {pitch}°, roll {roll}° -> {out}",
        highlight=False,
        soft_wrap=True,
    )
