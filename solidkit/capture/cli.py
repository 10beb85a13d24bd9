"""``solidkit capture ...``: Theta capture commands. Angles are degrees at this edge (conventions §6)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from solidkit.capture.metadata import read_metadata

app = typer.Typer(no_args_is_help=True)
console = Console()


@app.command()
def info(
    files: list[Path] = typer.Argument(..., help="JPEG or DNG captures."),
    as_json: bool = typer.Option(False, "--json", help="Print the metadata as JSON (one object per file)."),
) -> None:
    """Metadata of captures: EXIF exposure, GPS, GPano, Ricoh image type, zenith correction, gravity."""
    for path in files:
        meta = read_metadata(path)
        if as_json:
            typer.echo(meta.model_dump_json())
            continue
        table = Table(title=str(path), show_header=False)
        table.add_row("size", f"{meta.width} x {meta.height} ({meta.file_format})")
        table.add_row("camera", " ".join(x for x in (meta.make, meta.model, meta.serial) if x) or "-")
        table.add_row("image type", meta.image_type)
        expo = meta.exposure_time
        table.add_row(
            "exposure",
            f"{'1/%g' % round(1 / expo, 1) if expo and expo < 1 else expo} s, f/{meta.f_number}, ISO {meta.iso}",
        )
        table.add_row("taken (camera clock)", f"{meta.datetime_original} {meta.utc_offset or ''}")
        table.add_row("zenith corrected", str(meta.zenith_corrected))
        if meta.pitch_deg is not None:
            table.add_row("pitch / roll", f"{meta.pitch_deg:.2f}° / {meta.roll_deg:.2f}°  ({escape(meta.gravity_source or '')})")
        if meta.heading_deg is not None:
            table.add_row("heading", f"{meta.heading_deg:.1f}°")
        if meta.gps:
            table.add_row("gps", json.dumps(meta.gps))
        if meta.gpano:
            table.add_row("GPano", escape(", ".join(f"{k}={v}" for k, v in meta.gpano.items())))
        for w in meta.warnings:
            table.add_row("[yellow]warning[/]", escape(w))
        console.print(table)
