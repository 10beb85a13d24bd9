"""``solidkit train CONFIG``: train SOLID-Net from a TOML configuration (:mod:`solidkit.model.trainer`).

Resumes from ``OUT/last.pt`` when it exists (same settings), so a run cut short is continued by
running the same command again. Multi-process / multi-GPU: ``torchrun --nproc_per_node N -m
solidkit.cli train CONFIG --device cuda``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

__all__ = ["train_command"]


def train_command(
    config: Path = typer.Argument(..., help="TOML training configuration (see docs and solidkit/model/trainer.py)."),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="Run folder (default: the config's 'out')."),
    device: Optional[str] = typer.Option(None, help="cpu or cuda (default: the config's 'device')."),
    max_minutes: Optional[float] = typer.Option(None, help="Stop (resumably) after this many minutes."),
    threads: Optional[int] = typer.Option(None, help="torch CPU threads (default: the config's 'threads')."),
    progress: bool = typer.Option(True, help="Show a progress bar on a terminal."),
) -> None:
    """Train I-Net then P-Net; writes last.pt (resumable state), best_*.pt, model.pt, metrics.csv, tb/."""
    # torch is imported lazily: the rest of the CLI starts without it
    from solidkit.model.trainer import Trainer, load_train_config

    cfg = load_train_config(config, out=str(out) if out else None, device=device, threads=threads)
    state = Trainer(cfg, progress=progress).run(max_minutes)
    typer.echo(json.dumps({k: v for k, v in state.items() if k != "sources"}))
