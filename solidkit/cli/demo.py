"""``solidkit demo``: the main job (SD card -> ingest -> sun labels -> alignment -> test set -> evaluation ->
k-fold fine-tuning -> report) on the shipped mini campaign, with a summary table at the end."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from solidkit.cli.output import echo_json, json_option

__all__ = ["demo_command"]


def demo_command(
    out: Path = typer.Option(
        Path("demo_out"), "-o", "--out", help="Output folder (report.html, campaign/, testset/, ...)."
    ),
    card: Path | None = typer.Option(
        None, "--card", help="A card folder to run on instead of the shipped mini campaign."
    ),
    truth: Path | None = typer.Option(
        None, "--truth", help="The card's truth folder (virtual campaigns), for the truth check."
    ),
    model: Path | None = typer.Option(None, "--model", help="SOLID-Net checkpoint (default: the shipped one)."),
    folds: int = typer.Option(3, min=2, help="Scene-level folds of the fine-tuning."),
    epochs: int = typer.Option(3, min=1, help="Most fine-tuning epochs per fold."),
    jobs: int = typer.Option(1, min=1, help="Ingest worker processes."),
    relight: bool = typer.Option(
        False, "--relight", help="Also relight virtual objects at every probe of the test set (about 20 s more)."
    ),
    as_json: bool = json_option("the summary (OUT/summary.json)"),
) -> None:
    """The whole chain on a small virtual field campaign, into OUT/report.html."""
    from solidkit.demo import DemoConfig, run_demo
    from solidkit.errors import InputError

    if model is not None and not model.is_file():
        raise InputError(f"{model}: no such checkpoint")
    if truth is not None and not (truth / "truth.json").is_file():
        raise InputError(f"--truth {truth}: no truth.json there (the truth folder of a 'solidkit synth campaign')")

    err = Console(stderr=True)
    cfg = DemoConfig(card=card, truth=truth, model=model, folds=folds, epochs=epochs, jobs=jobs, relight=relight)
    summary = run_demo(out, cfg, log=lambda s: err.print(s, markup=False, highlight=False))
    if as_json:
        echo_json(summary, indent=1, default=float)
    else:
        table = Table(title=f"solidkit demo: {summary['seconds']:.0f} s")
        for col in ("step", "status", "s", "result"):
            table.add_column(col, overflow="fold")
        for s in summary["steps"]:
            colour = {"ok": "green", "failed": "red", "skipped": "yellow"}.get(s["status"], "white")
            table.add_row(s["name"], f"[{colour}]{s['status']}[/]", f"{s['seconds']:.1f}", s["note"])
        err.print(table)
        typer.echo(f"report: {summary['report']}")
    if any(s["status"] != "ok" for s in summary["steps"]):
        raise SystemExit(1)
