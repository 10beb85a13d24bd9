"""``solidkit train CONFIG``: train SOLID-Net from a TOML configuration (:mod:`solidkit.model.trainer`).

Resumes from ``OUT/last.pt`` when it exists (same settings), so a run cut short is continued by
running the same command again. Multi-process / multi-GPU: ``torchrun --nproc_per_node N -m
solidkit.cli train CONFIG --device cuda``.
"""

from __future__ import annotations

from pathlib import Path

import typer

from solidkit.cli.output import echo_json, json_option

__all__ = ["train_command"]


def train_command(
    config: Path = typer.Argument(..., help="TOML training configuration (see docs and solidkit/model/trainer.py)."),
    out: Path | None = typer.Option(None, "-o", "--out", help="Run folder (default: the config's 'out')."),
    device: str | None = typer.Option(None, help="cpu or cuda (default: the config's 'device')."),
    max_minutes: float | None = typer.Option(None, help="Stop (resumably) after this many minutes."),
    threads: int | None = typer.Option(None, help="torch CPU threads (default: the config's 'threads')."),
    progress: bool = typer.Option(True, help="Show a progress bar on a terminal."),
    as_json: bool = json_option("the run's final state"),
) -> None:
    """Train I-Net then P-Net; writes last.pt (resumable state), best_*.pt, model.pt, metrics.csv, tb/."""
    # torch is imported lazily: the rest of the CLI starts without it
    from solidkit.model.trainer import Trainer, load_train_config

    cfg = load_train_config(config, out=str(out) if out else None, device=device, threads=threads)
    state = Trainer(cfg, progress=progress).run(max_minutes)
    if as_json:
        echo_json({k: v for k, v in state.items() if k != "sources"})
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"solidkit train -> {cfg.out}", show_header=False)
    table.add_row("stage / step", f"{state['stage']} / {state['step']}")
    table.add_row("status", "done" if state.get("done") else "stopped (run the same command again to resume)")
    table.add_row("best validation score", "-" if state.get("best") is None else f"{state['best']:.4g}")
    table.add_row("samples / seconds", f"{state['samples']} / {state['seconds']:.0f}")
    Console().print(table)
