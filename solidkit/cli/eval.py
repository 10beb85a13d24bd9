"""``solidkit eval``: the paper's metrics for a checkpoint and baselines, with an HTML/Markdown report."""

from __future__ import annotations

import os
from pathlib import Path
from typing import cast

import typer

from solidkit.cli.output import echo_json
from solidkit.errors import InputError

__all__ = ["eval_command", "parse_named_paths"]


def parse_named_paths(values: list[str] | None, option: str) -> dict[str, Path]:
    """``["NAME=PATH", ...]`` -> ``{NAME: PATH}``; a clear InputError otherwise."""
    out: dict[str, Path] = {}
    for v in values or []:
        name, sep, path = v.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise InputError(f"{option} expects NAME=CHECKPOINT (e.g. {option} col=ablation_col.pt), got {v!r}")
        if name in out:
            raise InputError(f"{option} {name!r} given twice")
        out[name.strip()] = Path(path.strip())
    return out


def eval_command(
    model: Path | None = typer.Option(None, "--model", help="SOLID-Net checkpoint (default: the shipped one)."),
    testset: Path | None = typer.Option(None, "--testset", help="Real test set folder (testset.json)."),
    synthetic: Path | None = typer.Option(None, "--synthetic", help="Synthetic split (solidkit synth dataset folder)."),
    out: Path = typer.Option(
        Path("eval_report"), "-o", "--out", help="Report folder (report.html, report.md, figures/, results.json)."
    ),
    baseline: list[str] | None = typer.Option(
        None, "--baseline", help="Extra checkpoint NAME=CKPT evaluated side by side (ablations; repeatable)."
    ),
    panoramas: list[Path] | None = typer.Option(
        None,
        "--panoramas",
        help="Real HDR panorama (EXR) or a folder of them: photos "
        "cropped at 8 headings, global map and sun only (repeatable).",
    ),
    shipped_panoramas: bool = typer.Option(
        False, "--shipped-panoramas", help="Add the real HDR panoramas shipped with solidkit."
    ),
    sun_crops: list[Path] | None = typer.Option(
        None,
        "--sun-crops",
        help="Folder of HDR panoramas with a known sun (real "
        "ones with catalog.json, e.g. ../shared/data/real/hdr_outdoor, or rendered "
        "sources): the sun protocol with baselines and cone coverage (repeatable).",
    ),
    sun_split: str = typer.Option("test", "--sun-split", help="Split of the --sun-crops panoramas (train, val, test)."),
    limit: int | None = typer.Option(None, min=1, help="Evaluate only the first N photos of each dataset."),
    grids: int | None = typer.Option(
        None,
        min=0,
        help="Qualitative grids per dataset (default: every scene of a real test set, 6 of the other datasets).",
    ),
    allow_invalid: bool = typer.Option(
        False, "--allow-invalid", help="Use a test set that fails 'solidkit testset validate' (with a warning)."
    ),
    relight: bool = typer.Option(
        False,
        "--relight",
        help="Also relight virtual objects at every probe (Mitsuba, CPU): figures and the re-rendering error.",
    ),
    relight_spp: int = typer.Option(
        64, "--relight-spp", min=1, help="Samples per pixel of the relit objects (rounded up to a square)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the summaries as JSON on stdout."),
) -> None:
    """Sun azimuth/elevation error, global MAE and local SSIM/MAE for the model and baselines; a report.

    With --relight, also objects relit under each method's probes and the truth's (figures, si-RMSE, SSIM,
    shading direction)."""
    extra = parse_named_paths(baseline, "--baseline")
    panos: list[Path] = []
    for p in panoramas or []:
        if p.is_dir():
            found = sorted(p.glob("*.exr"))
            if not found:
                raise InputError(f"--panoramas {p}: no .exr panorama in this folder")
            panos += found
        elif p.is_file():
            panos.append(p)
        else:
            raise InputError(f"--panoramas {p}: no such file or folder")
    if shipped_panoramas:
        from solidkit.finetune.evaluate import SHIPPED_PANORAMAS

        panos += sorted(SHIPPED_PANORAMAS.glob("*.exr"))
    if testset is None and synthetic is None and not panos and not sun_crops:
        raise InputError(
            "give a real test set (--testset DIR), a synthetic split (--synthetic DIR), HDR panoramas "
            "(--panoramas, --shipped-panoramas) and/or --sun-crops FOLDER"
        )
    for p in sun_crops or []:
        if not p.is_dir():
            raise InputError(f"--sun-crops {p}: not a folder")
    if sun_split not in ("train", "val", "test"):
        raise InputError(f"--sun-split {sun_split!r}: expected train, val or test")
    for ckpt in [model, *extra.values()]:
        if ckpt is not None and not ckpt.is_file():
            raise InputError(f"{ckpt}: no such checkpoint")
    for folder, opt in ((testset, "--testset"), (synthetic, "--synthetic")):
        if folder is not None and not folder.is_dir():
            raise InputError(f"{opt} {folder}: not a folder")
    if testset is not None and not (testset / "testset.json").is_file():
        raise InputError(f"--testset {testset}: not a test set (no testset.json; run 'solidkit testset build')")
    # torch is imported only once the arguments are known to be good (a bad call answers at once)
    from solidkit.finetune.relight import RelightSettings
    from solidkit.finetune.report import evaluation_report

    res = evaluation_report(
        out,
        model,
        testset,
        synthetic,
        cast("dict[str, str | os.PathLike]", extra),
        limit=limit,
        max_grids=grids,
        log=lambda s: typer.echo(s, err=True),
        panoramas=panos,
        sun_crops=sun_crops,
        sun_split=sun_split,
        allow_invalid=allow_invalid,
        relight=RelightSettings(spp=relight_spp) if relight else None,
    )
    if as_json:
        echo_json({ds: r["summary"] for ds, r in res["results"].items()}, indent=1, default=float)
    typer.echo(f"report: {res['report']}", err=True)
