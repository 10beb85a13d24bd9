"""``solidkit verify CAMPAIGN``: the command around :func:`solidkit.capture.verify.verify_campaign`."""

from __future__ import annotations

from pathlib import Path

import typer

from solidkit.cli.output import echo_json, json_option
from solidkit.errors import InputError


def verify_cli(
    campaign: Path = typer.Argument(..., help="An ingested campaign directory (solidkit ingest)."),
    full: bool = typer.Option(
        False, "--full", help="Hash every original and product (default: sizes and times; hashed only when off)."
    ),
    wait: bool = typer.Option(
        False, "--wait", help="Wait for a step running on the campaign (ingest, align, ...) instead of refusing."
    ),
    as_json: bool = json_option("the findings"),
) -> None:
    """Check a campaign's stored originals, profiles and products against its manifest; exit 1 on damage.

    Every original present, read-only and matching its sha256 (cheap: size and time; --full hashes
    all), every product's inputs present. Each damaged file is listed with what repairs it:
    products are rebuilt by the next ingest, a lost original must be re-ingested from its card.
    Refused while ingest, align, label sun or testset build runs on the campaign (or --wait).
    """
    from rich.console import Console
    from rich.markup import escape

    from solidkit.capture.lock import campaign_lock
    from solidkit.capture.manifest import MANIFEST_NAME, load_manifest
    from solidkit.capture.verify import verify_campaign

    if not (campaign / MANIFEST_NAME).is_file():
        raise InputError(f"{campaign}: not an ingested campaign (no {MANIFEST_NAME})")
    err = Console(stderr=True)
    with campaign_lock(campaign, "verify", wait=wait, log=lambda s: err.print(escape(s))):  # files not changing
        report = verify_campaign(campaign, load_manifest(campaign), full=full)
    if as_json:
        echo_json({**report.model_dump(mode="json"), "ok": report.ok}, indent=1)
    else:
        out = Console(soft_wrap=True)
        for d in report.damage:
            colour = "yellow" if d.rebuildable else "red"
            out.print(f"[{colour}]damaged {d.what}[/] {escape(d.path)}: {escape(d.problem)}; {escape(d.remedy)}")
        counts = ", ".join(f"{n} {k}" for k, n in report.checked.items())
        how = "hashed in full" if full else f"by size and time, {report.hashed} hashed"
        if report.ok:
            out.print(f"{escape(str(campaign))}: [green]intact[/] ({counts}; {how})")
        else:
            lost = sum(not d.rebuildable for d in report.damage)
            out.print(
                f"{escape(str(campaign))}: [red]{len(report.damage)} damaged file(s)[/], {lost} not rebuildable "
                f"({counts}; {how})"
            )
    if not report.ok:
        raise typer.Exit(1)
