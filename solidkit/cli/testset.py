"""``solidkit testset``: build, validate, inspect, export and version a real test set."""

from __future__ import annotations

from pathlib import Path

import typer

from solidkit.cli.output import echo_json, json_option

app = typer.Typer(no_args_is_help=True, help="Build, validate, inspect and export a real test set (testset.json).")


@app.command("build")
def build_command(
    campaign: Path = typer.Argument(
        ..., help="Campaign folder (ingested, aligned; its label store is used when present)."
    ),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Test set folder to create (absent, empty, or an earlier test set)."
    ),
    wait: bool = typer.Option(
        False, "--wait", help="Wait for a step running on the campaign (ingest, align, label sun) instead of refusing."
    ),
    json_out: bool = json_option("the build report"),
) -> None:
    """Assemble a versioned test set (photos, probes, sun, metadata) from an aligned campaign."""
    import time

    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from solidkit.testset.build import build_testset

    console = Console(stderr=True)
    t0 = time.perf_counter()
    report = build_testset(campaign, out, log=lambda m: console.print(f"[dim]{escape(m)}[/dim]"), wait=wait)
    seconds = time.perf_counter() - t0
    if json_out:
        echo_json({**report.to_json(), "seconds": round(seconds, 2)}, indent=1)
        return
    table = Table(title=f"solidkit testset build -> {escape(str(out))}", show_header=False)
    table.add_row(
        "dataset version", report.dataset_version + ("" if report.changed else "  (unchanged: nothing written)")
    )
    table.add_row("scenes / probes (HDR)", f"{report.scenes} / {report.probes} ({report.hdr_probes})")
    table.add_row("scenes with a sun", str(report.sun_found))
    table.add_row("labels used", str(report.labels_used))
    table.add_row("seconds", f"{seconds:.1f}")
    console.print(table)
    for line in report.overrides:
        console.print(f"override: {escape(line)}")
    for line in report.excluded:
        console.print(f"[yellow]excluded[/yellow]: {escape(line)}")


@app.command("validate")
def validate_command(
    root: Path = typer.Argument(..., help="Test set folder (holding testset.json)."),
    allow_flagged: bool = typer.Option(
        False, "--allow-flagged", help="Do not count labels still flagged for review as problems."
    ),
    json_out: bool = json_option("the problems"),
) -> None:
    """Check schema, files, checksums, geometry, exposures and flags; exit 1 when any problem is found."""
    from rich.markup import escape

    from solidkit.cli.output import line_console
    from solidkit.testset.validate import validate_testset

    if not root.is_dir():
        from solidkit.errors import InputError

        raise InputError(f"{root}: not a folder")
    problems = validate_testset(root, allow_flagged=allow_flagged)
    if json_out:
        echo_json({"valid": not problems, "problems": [p.to_json() for p in problems]}, indent=1)
    else:
        console = line_console(stderr=True)
        for p in problems:
            console.print(f"[red]problem[/red] {escape(str(p))}")
        console.print(
            f"{root}: " + ("[green]valid[/green]" if not problems else f"[red]{len(problems)} problem(s)[/red]")
        )
    if problems:
        raise typer.Exit(1)


@app.command("show")
def show_command(
    root: Path = typer.Argument(..., help="Test set folder (holding testset.json)."),
    out: Path | None = typer.Option(
        None, "-o", "--out", help="Folder for the sheets and index.html (default: ROOT-sheets beside it)."
    ),
    json_out: bool = json_option("what was written"),
) -> None:
    """Contact sheets per scene (PNG) and an HTML index: probe pixels, aligned probes with the photo's FOV, the sun."""
    from solidkit.testset.show import show_testset

    out = out or root.with_name(root.name + "-sheets")
    sheets: list[str] = []

    def wrote(path: str) -> None:
        sheets.append(str(path))
        typer.echo(f"wrote {path}", err=True)

    index = show_testset(root, out, log=wrote)
    if json_out:
        echo_json({"output": str(out), "index": str(index), "sheets": sheets}, indent=1)
        return
    typer.echo(str(index))


@app.command("export")
def export_command(
    root: Path = typer.Argument(..., help="Test set folder (holding testset.json)."),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Folder to write, outside the test set (absent, empty, or an earlier export)."
    ),
    fmt: str = typer.Option(
        ...,
        "--format",
        help="Target: sold-net (SOLD-Net's real-set folder) or croissant (a dataset folder: Croissant 1.1 "
        "metadata, dataset card, datasheet, the test set under data/).",
    ),
    campaign: Path | None = typer.Option(
        None,
        "--campaign",
        help="croissant: the campaign the test set was built from (field notes, HDR clipping, label agreement).",
    ),
    license_: str | None = typer.Option(None, "--license", help="croissant: the licence (SPDX id or URL)."),
    creator: list[str] | None = typer.Option(None, "--creator", help="croissant: a creator to credit (repeatable)."),
    url: str | None = typer.Option(None, "--url", help="croissant: where the dataset is published."),
    version: str | None = typer.Option(None, "--version", help="croissant: release version (MAJOR.MINOR.PATCH)."),
    cite_as: str | None = typer.Option(None, "--cite-as", help="croissant: citation (BibTeX)."),
    date_published: str | None = typer.Option(None, "--date-published", help="croissant: ISO 8601 date."),
    json_out: bool = json_option("the exported items"),
) -> None:
    """Export a test set in another project's layout (sold-net: <XXX>_persp.JPG, ...; croissant: a dataset folder)."""
    from solidkit.errors import InputError

    if fmt == "croissant":
        from solidkit.testset.facts import ExportInfo
        from solidkit.testset.publish import export_croissant

        info = ExportInfo(
            license=license_,
            creators=tuple(creator or ()),
            url=url,
            version=version,
            cite_as=cite_as,
            date_published=date_published,
        )
        res = export_croissant(root, out, campaign=campaign, info=info)
        typer.echo(f"wrote {out}: croissant.json, README.md, datasheet.md, records/, data/", err=True)
        for q in res["open_questions"]:
            typer.echo(f"open: {q}", err=True)
        if json_out:
            echo_json(res, indent=1)
        return
    if fmt != "sold-net":
        raise InputError(f"--format {fmt!r}: supported formats: sold-net, croissant")
    given = [name for name, v in (("--campaign", campaign), ("--license", license_), ("--url", url)) if v] + (
        ["--creator"] if creator else []
    )
    if given or version or cite_as or date_published:
        raise InputError(f"{', '.join(given) or 'the dataset options'}: only for --format croissant")
    from solidkit.testset.sold_net import export_sold_net

    doc = export_sold_net(root, out)
    typer.echo(f"wrote {len(doc['items'])} items to {out}", err=True)
    if doc["skipped_by_sold_net_loader"]:
        typer.echo(
            "note: SOLD-Net's loader skips items with fewer than 2 probes: "
            f"{', '.join(doc['skipped_by_sold_net_loader'])}",
            err=True,
        )
    if json_out:
        echo_json({"output": str(out), **doc}, indent=1)


@app.command("import")
def import_command(
    folder: Path = typer.Argument(..., help="Folder in another project's layout (sold-net: <XXX>_persp.jpg, ...)."),
    out: Path = typer.Argument(..., help="Test set folder to create (absent, empty, or an earlier test set)."),
    fmt: str = typer.Option(..., "--format", help="Source layout: sold-net (SOLD-Net's real-set folder)."),
    hfov_deg: float | None = typer.Option(
        None, "--hfov-deg", help="Horizontal FOV of the photos (degrees; their layout has none). Default: the model's."
    ),
    json_out: bool = json_option("the import report"),
) -> None:
    """Import a test set from another project's layout (sold-net: frames and units converted, assumptions flagged)."""
    from solidkit.errors import InputError

    if fmt != "sold-net":
        raise InputError(f"--format {fmt!r}: supported formats: sold-net")
    from solidkit.testset.sold_net_import import import_sold_net

    report = import_sold_net(folder, out, hfov_deg=hfov_deg)
    if json_out:
        echo_json({"output": str(out), **report.to_json()}, indent=1)
        return
    typer.echo(
        f"wrote {out}: {report.scenes} scenes, {report.probes} probes, {report.sun_found} with a sun "
        f"({report.dataset_version}; ids from {report.ids_from})",
        err=True,
    )
    for line in report.excluded:
        typer.echo(f"excluded: {line}", err=True)
    if report.skipped_by_sold_net_loader:
        typer.echo(
            "note: imported although SOLD-Net's loader skips them (fewer than 2 local maps): "
            + ", ".join(report.skipped_by_sold_net_loader),
            err=True,
        )


@app.command("diff")
def diff_command(
    old: Path = typer.Argument(..., help="Earlier test set folder."),
    new: Path = typer.Argument(..., help="Later test set folder."),
    json_out: bool = json_option("the differences"),
) -> None:
    """What changed between two test set versions: scenes, probes, sun, pixels, rotations, flags, files."""
    from solidkit.testset.diff import diff_testsets

    d = diff_testsets(old, new)
    if json_out:
        echo_json(d.to_json(), indent=1)
    else:
        for line in d.lines():
            typer.echo(line)


@app.command("schema")
def schema_command(
    out: Path | None = typer.Option(None, "-o", "--out", help="Write the JSON Schema here instead of stdout."),
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
