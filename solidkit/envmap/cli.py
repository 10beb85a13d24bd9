"""``solidkit envmap ...``: panorama commands. Angles are degrees at this edge (conventions §6)."""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from solidkit.envmap.coords import solid_angle
from solidkit.envmap.io import read_image, validate_panorama

app = typer.Typer(no_args_is_help=True)
console = Console()


def load_panorama(path: Path) -> tuple[np.ndarray, dict]:
    """Read and validate a panorama file (EXR or LDR); errors are one-line SolidkitErrors."""
    img, meta = read_image(path)
    return validate_panorama(img, str(path)), meta


@app.command()
def info(pano: Path = typer.Argument(..., help="Equirectangular panorama (EXR or LDR).")) -> None:
    """Size, dynamic range and radiometric summary of a panorama."""
    img, meta = load_panorama(pano)
    h, w = img.shape[:2]
    lum = img @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    omega = solid_angle(h)
    positive = lum[lum > 0]
    table = Table(title=str(pano), show_header=False)
    table.add_row("size", f"{w} x {h} ({img.shape[2]} channels used)")
    table.add_row("kind", "LDR (sRGB decoded to linear)" if meta.get("ldr") else "HDR (linear)")
    table.add_row("min / max luminance", f"{lum.min():.4g} / {lum.max():.4g}")
    if positive.size:
        table.add_row("dynamic range", f"{np.log2(positive.max() / max(positive.min(), 1e-12)):.1f} stops")
    table.add_row("mean radiance (RGB)", ", ".join(f"{c:.4g}" for c in img.reshape(-1, 3).mean(0)))
    table.add_row("irradiance integral ∫L dω", f"{float((lum * omega).sum()):.4g}")
    for key in ("exposure_time", "provenance", "conventions_version"):
        if key in meta:
            table.add_row(key, json.dumps(meta[key]))
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
    from solidkit.envmap.sun import detect_sun

    img, _ = load_panorama(pano)
    result = detect_sun(img, method=method.value)
    if as_json:
        typer.echo(json.dumps(result.to_json()))
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
