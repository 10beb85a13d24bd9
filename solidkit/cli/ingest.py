"""``solidkit ingest CARD_DIR -o CAMPAIGN_DIR``: the command around :func:`solidkit.capture.campaign.ingest`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from solidkit.capture.campaign import IngestReport, ingest, load_manifest, summary_rows
from solidkit.capture.fieldnotes import card_notes_template
from solidkit.capture.products import tilt_warning
from solidkit.cli.output import echo_json, json_option, line_console
from solidkit.cli.parsing import parse_exposure
from solidkit.errors import InputError


def ingest_command(
    card_dir: Path,
    campaign_dir: Path,
    jobs: int = 1,
    response: Path | None = None,
    products: bool = True,
    scene_gap: float | None = None,
    probe_gap: float | None = None,
    bracket_gap: float | None = None,
    low_exposure_max: float | None = None,
    lens_profile: str | None = None,
    vignetting: Path | None = None,
    quiet: bool = False,
    retry_failed: bool = False,
    wait: bool = False,
) -> IngestReport:
    """Run :func:`ingest` with a rich progress bar (stderr) and print the summary (stdout; not when ``quiet``)."""
    console = Console(stderr=True)
    given = {
        "scene_gap_s": scene_gap,
        "probe_gap_s": probe_gap,
        "bracket_gap_s": bracket_gap,
        "low_exposure_max_s": low_exposure_max,
    }
    grouping = {k: v for k, v in given.items() if v is not None}  # others: the campaign's stored values
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        ids: dict[str, Any] = {}

        def progress(phase: str, done: int, total: int) -> None:
            if phase not in ids:
                ids[phase] = bar.add_task("copying originals" if phase == "files" else "building products", total=total)
            bar.update(ids[phase], completed=done, total=total)

        report = ingest(
            card_dir,
            campaign_dir,
            jobs=jobs,
            grouping=grouping,
            response_path=response,
            products=products,
            progress=progress,
            lens_profile=lens_profile,
            vignetting_path=vignetting,
            retry_failed=retry_failed,
            wait=wait,
            log=lambda s: console.print(escape(s)),
        )
    manifest = load_manifest(campaign_dir)
    if quiet:
        return report
    out = line_console()  # one line per bad file or warning, unbroken into a pipe or log
    if report.nothing_done:
        out.print(
            f"[green]nothing to do:[/] {escape(str(campaign_dir))} is up to date with {escape(str(card_dir))} "
            f"({report.unchanged} captures already ingested, {report.products_up_to_date} products up to date)"
        )
    table = Table(title=f"ingest {escape(str(card_dir))} -> {escape(str(campaign_dir))}", show_header=False)
    table.add_row("captures on the card", str(report.files_seen))
    table.add_row(
        "copied / already present / unchanged", f"{report.copied} / {report.already_present} / {report.unchanged}"
    )
    table.add_row("unrelated files skipped", str(len(report.unrelated)))
    for label, value in summary_rows(manifest):
        table.add_row(label, value)
    table.add_row(
        "products built / up to date / removed",
        f"{report.products_built} / {report.products_up_to_date} / {report.products_removed}",
    )
    out.print(table)
    for msg in report.notes_errors:
        out.print(f"[red]field notes refused[/] {escape(msg)}")
    for sc in manifest.scenes:
        for w in sc.warnings:
            out.print(f"[yellow]warning[/] {escape(sc.id)}: {escape(w)}")
        for pr in sc.probes:
            for w in pr.warnings:
                out.print(f"[yellow]warning[/] {escape(sc.id)}/{escape(pr.id)}: {escape(w)}")
    bare = {
        sc.id: (sc.camera_probe, [p.id for p in sc.probes])
        for sc in manifest.scenes
        if sc.fieldnotes is None and (sc.camera_probe is None or any(p.role == "probe" for p in sc.probes))
    }
    if bare:
        where = escape(str(Path(card_dir) / "fieldnotes.toml"))
        out.print(
            f"[yellow]field notes[/] {len(bare)} scene(s) have none: write {where} (docs/field-protocol.md), "
            "fill in and uncomment, then run ingest again:"
        )
        for line in card_notes_template(bare).splitlines():
            out.print(f"  {escape(line)}", soft_wrap=True)
    for i, name in enumerate(report.unrelated):
        if i == 20:
            out.print(
                f"  ... and {len(report.unrelated) - 20} more unrelated file(s) (listed in the manifest's 'skipped')"
            )
            break
        why = report.skip_reasons.get(name, "not a capture (.jpg/.jpeg/.dng)")
        out.print(f"[dim]skipped[/] {escape(name)}: {why}")
    for prod in manifest.products:
        for w in [*prod.stats.get("warnings", []), tilt_warning(prod)]:
            if w:
                out.print(f"[yellow]warning[/] {escape(prod.id)}: {escape(w)}")
    for msg in report.product_errors:
        out.print(f"[yellow]product not built[/] {escape(msg)}")
    if report.product_errors_transient:
        out.print(
            f"  {report.product_errors_transient} of them failed for the environment (disk full, I/O, permissions) "
            "or a damaged input, not their data: fix it and run ingest again, they will be built"
        )
    for name in report.originals_restored:
        out.print(
            f"[yellow]restored[/] {escape(name)}: was missing or corrupted, copied again from the card", soft_wrap=True
        )
    if report.originals_repaired:
        out.print(f"[yellow]repaired[/] {report.originals_repaired} stored original(s) were writable: read-only again")
    for d in report.damaged:
        out.print(f"[red]damaged original[/] {escape(d.path)}: {escape(d.problem)}; {escape(d.remedy)}", soft_wrap=True)
    if report.manifest_error:
        out.print(f"[red]manifest not saved[/] {escape(report.manifest_error)}", soft_wrap=True)
    if report.transient_errors:
        out.print(
            f"[red]{len(report.transient_errors)} file(s) could not be copied[/] (the environment, not the file: "
            "fix it and run ingest again, they will be retried):"
        )
        for e in report.transient_errors:
            out.print(f"  [red]error[/] {escape(e.path)}: {escape(e.message)}")
    errors = [e for e in manifest.errors if e.card == str(Path(card_dir).resolve())]
    if errors:
        out.print(f"[red]{len(errors)} file(s) could not be ingested[/] (the rest was):")
        for e in errors:
            out.print(f"  [red]error[/] {escape(e.path)}: {escape(e.message)}")
    return report


def ingest_cli(
    card_dir: Path = typer.Argument(..., help="The card (or a copy of it): DCIM/... or <scene>/<probe>/... folders."),
    out: Path = typer.Option(
        ..., "-o", "--out", help="The campaign folder to write (created; ingest more cards into it later)."
    ),
    jobs: int = typer.Option(1, "--jobs", "-j", min=1, help="Worker processes."),
    response: Path | None = typer.Option(
        None, "--response", help="Inverse response curve for HDR products (default sRGB inverse)."
    ),
    products: bool = typer.Option(
        True, "--products/--no-products", help="Build the derived products (HDR merges, sun frames)."
    ),
    scene_gap: float | None = typer.Option(
        None,
        help="Seconds between shots that start a new scene (automatic layout; default 600, then the campaign's value).",
    ),
    probe_gap: float | None = typer.Option(
        None,
        help="Seconds between Theta shots that start a new probe position (automatic layout). Default 45: split by "
        "the scene's shooting rhythm, 45 s where it is unclear; any other value: a fixed split.",
    ),
    bracket_gap: float | None = typer.Option(None, help="Seconds between shots that end a bracket (default 10)."),
    low_exposure_max: str | None = typer.Option(
        None, help="Longest exposure (s) of a sun frame, e.g. 1/4000 (the default)."
    ),
    profile: str | None = typer.Option(
        None,
        "--profile",
        help=(
            "Per-unit lens profile (unit.json from 'solidkit calibrate overlap', or a shipped name) overriding the "
            "camera model's default; recorded in the campaign."
        ),
    ),
    vignetting: Path | None = typer.Option(
        None,
        "--vignetting",
        help=(
            "Vignetting profile ('solidkit calibrate vignetting'): each lens divided by its falloff before the lenses "
            "are blended; recorded in the campaign."
        ),
    ),
    retry_failed: bool = typer.Option(
        False, "--retry-failed", help="Build again the products recorded with an error (after a fix or an upgrade)."
    ),
    wait: bool = typer.Option(
        False, "--wait", help="Wait for another step running on the campaign (align, ...) instead of refusing."
    ),
    as_json: bool = json_option("what this run did"),
) -> None:
    """Copy a card's captures into a checksummed campaign, group scenes/probes/brackets, build products.

    Idempotent and resumable (re-run after an interruption); when some files could not be
    ingested they are listed, everything else is processed, and the exit code is 2.
    """
    low = parse_exposure(low_exposure_max, "--low-exposure-max") if low_exposure_max is not None else None
    report = ingest_command(
        card_dir,
        out,
        jobs,
        response,
        products,
        scene_gap,
        probe_gap,
        bracket_gap,
        low,
        lens_profile=profile,
        vignetting=vignetting,
        quiet=as_json,
        retry_failed=retry_failed,
        wait=wait,
    )
    if as_json:
        echo_json({"card": str(card_dir), "campaign": str(out), **report.model_dump(mode="json")})
    if report.manifest_error:
        raise InputError(
            f"{report.manifest_error}; free space and run ingest again (everything written so far is kept)"
        )
    if report.damaged:
        raise InputError(
            f"{len(report.damaged)} stored original(s) damaged and not on {card_dir} (listed above): "
            "re-ingest them from their card"
        )
    if report.errors or report.known_errors or report.transient_errors:
        n = len(report.errors) + report.known_errors + len(report.transient_errors)
        raise InputError(
            f"{n} file(s) on {card_dir} could not be ingested (listed above); everything else was ingested"
        )
    if report.product_errors:
        raise InputError(
            f"{len(report.product_errors)} product(s) could not be built (listed above); everything else was built"
        )
    if report.notes_errors:
        raise InputError(
            f"{len(report.notes_errors)} field notes file(s) on {card_dir} refused (listed above); "
            "everything else was ingested"
        )
