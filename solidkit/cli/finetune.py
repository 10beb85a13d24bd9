"""``solidkit finetune``: scene-level k-fold fine-tuning on a real test set, with a before/after report."""

from __future__ import annotations

from pathlib import Path

import typer

from solidkit.cli.output import echo_json
from solidkit.errors import InputError

__all__ = ["finetune_command"]

TRAINABLE_CHOICES = ("pnet+sky", "pnet", "sky", "all")  # solidkit.finetune.finetune.TRAINABLE


def finetune_command(
    model: Path | None = typer.Option(None, "--model", help="SOLID-Net checkpoint (default: the shipped one)."),
    testset: list[Path] = typer.Option(
        ..., "--testset", help="Real test set folder (testset.json); repeat to pool several."
    ),
    out: Path = typer.Option(
        Path("finetune_out"), "-o", "--out", help="Output folder (report, finetune.json, fold_<i>.pt)."
    ),
    folds: int = typer.Option(3, min=2, help="Number of scene-level folds (at most the number of scenes)."),
    epochs: int = typer.Option(8, min=1, help="Most epochs per fold (early stopping on held-out training scenes)."),
    patience: int = typer.Option(2, min=1, help="Epochs without validation improvement before stopping."),
    lr: float = typer.Option(1e-4, min=0.0, help="Adam learning rate."),
    trainable: str = typer.Option("pnet+sky", help="What to train: pnet+sky (default), pnet, sky or all."),
    sun_weight: float = typer.Option(1.0, min=0.0, help="Weight of the sun-direction term."),
    mix_synthetic: Path | None = typer.Option(
        None, "--mix-synthetic", help="Synthetic dataset to mix in (one batch per real step)."
    ),
    synthetic: Path | None = typer.Option(
        None, "--synthetic", help="Synthetic split for the forgetting check (8 samples)."
    ),
    seed: int = typer.Option(0, help="Seed of the split, the order and torch."),
    allow_invalid: bool = typer.Option(
        False, "--allow-invalid", help="Use a test set that fails 'solidkit testset validate' (with a warning)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the per-fold and pooled summary as JSON on stdout."),
) -> None:
    """Fine-tune per fold on the other scenes' LDR probes and sun labels; before/after per fold and pooled."""
    if trainable not in TRAINABLE_CHOICES:
        raise InputError(f"--trainable must be one of {', '.join(TRAINABLE_CHOICES)}, got {trainable!r}")
    if model is not None and not model.is_file():
        raise InputError(f"{model}: no such checkpoint")
    for p, opt in [
        *((t, "--testset") for t in testset),
        (mix_synthetic, "--mix-synthetic"),
        (synthetic, "--synthetic"),
    ]:
        if p is not None and not p.is_dir():
            raise InputError(f"{opt} {p}: not a folder")
    for t in testset:
        if not (t / "testset.json").is_file():
            raise InputError(f"--testset {t}: not a test set (no testset.json; run 'solidkit testset build')")
    if len({t.name for t in testset}) < len(testset):
        raise InputError("--testset: pooled test sets need distinct folder names (they prefix the scene ids)")
    # torch is imported only once the arguments are known to be good (a bad call answers at once)
    from solidkit.finetune.finetune import FineTuneConfig, finetune_report

    cfg = FineTuneConfig(
        folds=folds, epochs=epochs, patience=patience, lr=lr, trainable=trainable, sun_weight=sun_weight, seed=seed
    )
    res = finetune_report(
        out,
        model,
        testset,
        cfg,
        mix_synthetic,
        synthetic,
        log=lambda s: typer.echo(s, err=True),
        allow_invalid=allow_invalid,
    )
    if as_json:
        echo_json(
            {
                "folds": [
                    {k: f[k] for k in ("fold", "split", "best_epoch", "seconds", "before", "after")}
                    for f in res["folds"]
                ],
                "effect": res["effect"],
            },
            indent=1,
            default=float,
        )
    typer.echo(f"report: {res['report']}", err=True)
