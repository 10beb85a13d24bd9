"""``solidkit testset``: build, validate, inspect, export and version a real test set."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(no_args_is_help=True, help="Build, validate, inspect and export a real test set (testset.json).")


@app.command("schema")
def schema_command(
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="Write the JSON Schema here instead of stdout."),
) -> None:
    """Print (or write) the JSON Schema of testset.json."""
    from solidkit.fsutil import atomic_write_text
    from solidkit.testset.schema import canonical_json, json_schema

    text = canonical_json(json_schema())
    if out is None:
        typer.echo(text, nl=False)
    else:
        atomic_write_text(out, text)
        typer.echo(f"wrote {out}", err=True)
