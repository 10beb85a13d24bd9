"""``solidkit synth ...``: synthetic SOLID-Img-style data and the virtual field campaign (Mitsuba 3)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from solidkit.cli.output import echo_json, json_option
from solidkit.cli.parsing import output_folder, parse_exposures
from solidkit.errors import InputError

app = typer.Typer(no_args_is_help=True)
console = Console(stderr=True)  # progress and logs
summary = Console()  # results (stdout)


def _progress() -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
    )


@app.command()
def dataset(
    n: int = typer.Option(..., "--n", min=1, help="Total number of samples of the dataset (all shards)."),
    out: Path = typer.Option(..., "-o", "--out", help="Dataset folder (created; re-running resumes)."),
    shard: str | None = typer.Option(None, "--shard", help="Render only shard i/N (contiguous index range)."),
    spp: int = typer.Option(64, "--spp", min=1, help="Samples per pixel of the photo."),
    probe_spp: int = typer.Option(32, "--probe-spp", min=1, help="Samples per pixel of the local probes."),
    seed: int = typer.Option(0, "--seed", help="Master seed (blocks, views, lighting, noise)."),
    width: int = typer.Option(320, "--width", min=8),
    height: int = typer.Option(240, "--height", min=6),
    hfov_deg: float = typer.Option(
        60.0, "--hfov-deg", min=10.0, max=150.0, help="Horizontal field of view of the photo, degrees."
    ),
    candidates: int = typer.Option(12, "--candidates", min=1, help="Candidate cameras per 60° sector."),
    exclude_hdr: list[str] = typer.Option(
        [], "--exclude-hdr", help="HDR lighting maps to leave out (e.g. a held-out real test)."
    ),
    denoise: bool = typer.Option(
        False,
        "--denoise",
        help="Denoise the path-traced renders with Intel Open Image Denoise (albedo and normal guides; "
        "needs the 'denoise' extra, pyoidn).",
    ),
    reference: Path | None = typer.Option(None, "--reference", help="Folder of real LDR photos for the colour filter."),
    threshold: float = typer.Option(0.7, "--threshold", min=0.0, max=1.0, help="Histogram-intersection threshold."),
    variant: str | None = typer.Option(
        None, "--variant", help="Force a Mitsuba variant (default: cuda > llvm > scalar)."
    ),
    as_json: bool = json_option("the counts"),
) -> None:
    """Render SOLID-Img-style samples: photo (HDR+LDR), buffers, global map, 4 local probes, JSON."""
    from solidkit.synth.dataset import generate, parse_shard
    from solidkit.synth.filter import ReferenceSet
    from solidkit.synth.mitsuba_variant import select_variant
    from solidkit.synth.sample import SampleConfig

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    output_folder(out)
    sh = parse_shard(shard)
    used = select_variant(variant)
    ref = ReferenceSet.from_dir(reference) if reference is not None else None
    if denoise:
        from solidkit.synth.denoise import require

        require()
    cfg = SampleConfig(
        width=width,
        height=height,
        hfov_deg=hfov_deg,
        spp=spp,
        probe_spp=probe_spp,
        candidates=candidates,
        exclude_hdr=tuple(exclude_hdr),
        denoise=denoise,
    )
    t0 = time.perf_counter()
    with _progress() as bar:
        task = bar.add_task(f"synth {sh[0]}/{sh[1]} [{used}]", total=None)

        def report(done: int, total: int, record: dict | None) -> None:
            bar.update(task, completed=done, total=total)

        counts = generate(out, n, seed=seed, shard=sh, config=cfg, reference=ref, threshold=threshold, progress=report)
    dt = time.perf_counter() - t0
    if as_json:
        echo_json({"output": str(out), "variant": used, "shard": list(sh), **counts, "seconds": dt})
        return
    table = Table(title=f"solidkit synth dataset -> {out}", show_header=False)
    table.add_row("variant", used)
    table.add_row("shard", f"{sh[0]}/{sh[1]}")
    table.add_row("rendered / skipped", f"{counts['rendered']} / {counts['skipped']}")
    if ref is not None:
        table.add_row("kept by colour filter", f"{counts['kept']} / {counts['rendered']} (threshold {threshold})")
    if counts["rendered"]:
        table.add_row("seconds per sample", f"{dt / counts['rendered']:.1f}")
    summary.print(table)


@app.command()
def sources(
    n: int = typer.Option(..., "--n", min=1, help="Total number of panoramas (all shards)."),
    out: Path = typer.Option(..., "-o", "--out", help="Folder (created; re-running resumes)."),
    shard: str | None = typer.Option(None, "--shard", help="Render only shard i/N (contiguous index range)."),
    seed: int = typer.Option(0, "--seed", help="Master seed (blocks, positions, lighting, noise)."),
    height: int = typer.Option(768, "--height", min=64, help="Panorama height (width twice that)."),
    spp: int = typer.Option(12, "--spp", min=1, help="Samples per pixel."),
    exclude_hdr: list[str] = typer.Option(
        [], "--exclude-hdr", help="HDR lighting maps to leave out (e.g. a held-out real test)."
    ),
    variant: str | None = typer.Option(
        None, "--variant", help="Force a Mitsuba variant (default: cuda > llvm > scalar)."
    ),
    positions_per_block: int = typer.Option(
        8,
        "--positions-per-block",
        min=1,
        help="Consecutive panoramas that share one city block (1: every panorama a new block).",
    ),
    denoise: bool = typer.Option(
        False,
        "--denoise",
        help="Denoise the path-traced renders with Intel Open Image Denoise (albedo and normal guides; "
        "needs the 'denoise' extra, pyoidn).",
    ),
    real_lighting: list[Path] = typer.Option(
        [],
        "--real-lighting",
        help="A folder of real HDR panoramas (e.g. ../shared/data/real/hdr_outdoor) whose maps join the "
        "lighting pool (repeatable); each source lit by one takes the sun from its catalog.json.",
    ),
    real_lighting_split: str = typer.Option(
        "train",
        "--real-lighting-split",
        help="Which split (train, val, test) of the shipped split by whole panorama those maps come from.",
    ),
    as_json: bool = json_option("the counts"),
) -> None:
    """Render city-block HDR panoramas + their lighting: sources of the crop path of I-Net training."""
    from solidkit.synth.dataset import parse_shard
    from solidkit.synth.mitsuba_variant import select_variant
    from solidkit.synth.panocrops import SourceConfig, render_sources

    output_folder(out)
    sh = parse_shard(shard)
    used = select_variant(variant)
    if denoise:
        from solidkit.synth.denoise import require

        require()
    cfg = SourceConfig(
        height=height,
        spp=spp,
        exclude_hdr=tuple(exclude_hdr),
        positions_per_block=positions_per_block,
        denoise=denoise,
        real_lighting=tuple(str(f) for f in real_lighting),
        real_lighting_split=real_lighting_split,
    )
    if real_lighting:
        from solidkit.synth.panocrops import lighting_files

        pool, suns = lighting_files(cfg)
        sunny = sum(s.visible for s in suns.values())
        summary.print(
            f"lighting pool: {len(pool)} HDR maps, {len(suns)} with a catalogued sun "
            f"({sunny} visible, {len(suns) - sunny} none) from the '{real_lighting_split}' split"
        )
    t0 = time.perf_counter()
    with _progress() as bar:
        task = bar.add_task(f"sources {sh[0]}/{sh[1]} [{used}]", total=None)
        counts = render_sources(
            out,
            n,
            seed=seed,
            shard=sh,
            config=cfg,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    dt = time.perf_counter() - t0
    if as_json:
        echo_json({"output": str(out), "variant": used, "shard": list(sh), **counts, "seconds": dt})
        return
    summary.print(
        f"rendered {counts['rendered']}, skipped {counts['skipped']}"
        + (f", {dt / counts['rendered']:.1f} s each" if counts["rendered"] else "")
        + f" -> {out}"
    )


@app.command(name="filter")
def filter_cmd(
    dataset: Path = typer.Argument(..., help="Dataset folder of 'solidkit synth dataset' (updated in place)."),
    reference: Path = typer.Option(..., "--reference", help="Folder of real LDR photos."),
    threshold: float = typer.Option(0.7, "--threshold", min=0.0, max=1.0, help="Histogram-intersection threshold."),
    as_json: bool = json_option("the counts"),
) -> None:
    """Re-score every sample of a dataset against real photos, in place: each sample's filter record and the index."""
    from solidkit.synth.dataset import rescore

    counts = rescore(dataset, reference, threshold)
    if as_json:
        echo_json({"dataset": str(dataset), "threshold": threshold, **counts})
        return
    summary.print(
        f"kept {counts['kept']} / {counts['samples']} samples (threshold {threshold}, "
        f"{counts['references']} reference images)"
    )


@app.command()
def campaign(
    scenes: int = typer.Option(29, "--scenes", min=1, help="Number of scenes (the paper's real set: 29)."),
    probes: int = typer.Option(67, "--probes", min=0, help="Number of probe positions in all (the paper: 67)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output folder: card/ (what the field team brings) and truth/."),
    seed: int = typer.Option(0, "--seed", help="Master seed."),
    photo_spp: int | None = typer.Option(
        None, "--photo-spp", min=1, help="Samples per pixel of the photo (default 32)."
    ),
    pano_height: int | None = typer.Option(
        None, "--pano-height", min=8, help="Height of the HDR panorama behind each Theta shot (default 512)."
    ),
    pano_spp: int | None = typer.Option(
        None, "--pano-spp", min=1, help="Samples per pixel of that panorama (default 16)."
    ),
    probe_spp: int | None = typer.Option(
        None,
        "--probe-spp",
        min=1,
        help="Samples per pixel of the truth probes (glass scenes: x4; default 256); see 'campaign-truth'.",
    ),
    fisheye_width: int | None = typer.Option(
        None, "--fisheye-width", min=64, help="Width of the dual-fisheye JPEGs (default 1920)."
    ),
    brackets: str | None = typer.Option(
        None,
        "--brackets",
        help="Exposures (s) after the 1/25000 s sun frame and the 1/2500 s probe "
        "shot, same bracket; default '1/640,1/160,1/40'; 'none': no more.",
    ),
    preset: str = typer.Option(
        "default",
        "--preset",
        help="Settings preset: 'default', 'mini' (the small campaign "
        "shipped in solidkit/assets/campaign_mini) or 'glass-mini' (mini, every scene with glass facades); "
        "options given override it.",
    ),
    glass_every: int | None = typer.Option(
        None,
        "--glass-every",
        min=0,
        help="Every n-th scene (scene02, scene05, ...) has glass facades that glint; 0: none (default 3).",
    ),
    photo_width: int | None = typer.Option(None, "--photo-width", min=16, help="Photo width (px); height at 4:3."),
    denoise: bool = typer.Option(
        False,
        "--denoise",
        help="Denoise the photo and the Theta panoramas with Intel Open Image Denoise (albedo and normal guides; "
        "the truth probes never are; needs the 'denoise' extra, pyoidn).",
    ),
    variant: str | None = typer.Option(None, "--variant", help="Force a Mitsuba variant."),
    as_json: bool = json_option(),
) -> None:
    """A virtual field campaign: photos, Theta dual-fisheye shots (card layout) and a separate truth file."""
    from solidkit.synth.campaign import PRESETS, CampaignConfig, generate_campaign
    from solidkit.synth.mitsuba_variant import select_variant

    if preset not in PRESETS:
        raise InputError(f"--preset: expected one of {', '.join(PRESETS)}, got '{preset}'")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    output_folder(out)
    used = select_variant(variant)
    given: dict[str, object] = {}
    if brackets is not None:
        given["brackets_s"] = [] if brackets.strip().lower() == "none" else parse_exposures(brackets, "--brackets")
    for name, value in (
        ("photo_spp", photo_spp),
        ("pano_height", pano_height),
        ("pano_spp", pano_spp),
        ("probe_spp", probe_spp),
        ("fisheye_width", fisheye_width),
    ):
        if value is not None:  # else the preset's value, or CampaignConfig's default
            given[name] = value
    if glass_every is not None:
        given["glass_every"] = glass_every
    if photo_width is not None:
        given.update(photo_width=photo_width, photo_height=photo_width * 3 // 4)
    if denoise:
        from solidkit.synth.denoise import require

        require()
        given["denoise"] = True
    cfg = CampaignConfig(**{**PRESETS[preset], **given})
    t0 = time.perf_counter()
    with _progress() as bar:
        task = bar.add_task(f"campaign [{used}]", total=scenes + probes)

        def report(sid: str, cid: str) -> None:
            bar.advance(task)

        truth = generate_campaign(out, scenes, probes, seed=seed, config=cfg, progress=report)
    if as_json:
        echo_json(
            {
                "output": str(out),
                "variant": used,
                "scenes": len(truth.scenes),
                "captures": sum(len(s.captures) for s in truth.scenes),
                "card": str(out / "card"),
                "truth": str(out / "truth" / "truth.json"),
                "seconds": time.perf_counter() - t0,
            }
        )
        return
    table = Table(title=f"solidkit synth campaign -> {out}", show_header=False)
    table.add_row("scenes / captures", f"{len(truth.scenes)} / {sum(len(s.captures) for s in truth.scenes)}")
    table.add_row("card", str(out / "card"))
    table.add_row("truth (keep apart)", str(out / "truth" / "truth.json"))
    table.add_row("seconds", f"{time.perf_counter() - t0:.1f}")
    summary.print(table)


@app.command(name="campaign-truth")
def campaign_truth(
    campaign: Path = typer.Argument(..., help="A folder of 'solidkit synth campaign' (card/ and truth/)."),
    spp: int | None = typer.Option(
        None,
        "--spp",
        min=1,
        help="Samples per pixel of a truth probe's first render "
        "(glass scenes: x the campaign's glass factor); "
        "default 256.",
    ),
    noise_db: float | None = typer.Option(
        None,
        "--noise-db",
        min=0.0,
        help="Noise target (PSNR dB, paper tonemap): probes whose first render is "
        "noisier get a fresh render with more samples; 0: none; default 40.",
    ),
    max_spp: int | None = typer.Option(
        None, "--max-spp", min=1, help="Most samples per pixel for the noise target (default 2048)."
    ),
    scene: list[str] = typer.Option([], "--scene", help="Only this scene (repeatable); default: all."),
    variant: str | None = typer.Option(None, "--variant", help="Force a Mitsuba variant."),
    as_json: bool = json_option(),
) -> None:
    """Re-render only the truth probes of a virtual campaign (the card is not touched); idempotent, resumable.

    The scene is rebuilt from the campaign's seed and settings and checked against the truth before
    anything is written; the spp and recipe version are recorded per probe and in truth.json.
    """
    from solidkit.synth.mitsuba_variant import select_variant
    from solidkit.synth.truth_rerender import read_campaign, rerender_truth

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not campaign.is_dir():
        raise InputError(f"{campaign}: no such folder")
    _, truth = read_campaign(campaign)  # a one-line error before Mitsuba loads
    total = sum(c.probe is not None for st in truth.scenes if not scene or st.id in scene for c in st.captures)
    used = select_variant(variant)
    t0 = time.perf_counter()
    with _progress() as bar:
        task = bar.add_task(f"truth probes [{used}]", total=total)
        res = rerender_truth(
            campaign,
            spp=spp,
            noise_db=noise_db,
            max_spp=max_spp,
            scenes=scene or None,
            progress=lambda sid, cid, what: bar.advance(task),
        )
    res["seconds"] = time.perf_counter() - t0
    if as_json:
        echo_json(res)
        return
    table = Table(title=f"solidkit synth campaign-truth {campaign}", show_header=False)
    table.add_row("truth probes rendered / kept / up to date", f"{res['rendered']} / {res['kept']} / {res['skipped']}")
    table.add_row(
        "first render spp (non-glass) / noise target / max spp",
        f"{res['spp']} / {res['noise_db']:g} dB / {res['max_spp']}",
    )
    if res["probes"]:
        noise = [p["noise_psnr_db"] for p in res["probes"] if p["noise_psnr_db"] is not None]
        if noise:
            table.add_row(
                "noise of these probes (min / median)", f"{min(noise):.1f} / {sorted(noise)[len(noise) // 2]:.1f} dB"
            )
    if res["rendered"]:
        table.add_row("seconds per rendered probe", f"{res['seconds_per_probe']:.1f}")
        table.add_row(
            "new vs stored probe at 1/4 size (min)",
            f"{min(p['check_psnr_db'] for p in res['probes'] if p['what'] == 'rendered'):.1f} dB",
        )
    table.add_row("all probes done with this recipe", "yes" if res["complete"] else "no")
    summary.print(table)
