"""``solidkit align CAMPAIGN`` and ``solidkit label sun CAMPAIGN``: the commands around
:mod:`solidkit.align.pipeline`."""

from __future__ import annotations

from pathlib import Path

import typer

from solidkit.cli.output import echo_json, json_option
from solidkit.errors import InputError


def _run(
    campaign: Path,
    scenes: list[str] | None,
    products: bool,
    report: bool,
    only_sun: bool,
    as_json: bool,
    wait: bool = False,
) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from solidkit.align.pipeline import AlignSettings, align_campaign
    from solidkit.align.schema import alignment_summary
    from solidkit.flags import flag_codes

    if not campaign.is_dir():
        raise InputError(f"{campaign}: campaign directory not found")
    err = Console(stderr=True)
    settings = AlignSettings(products=products and not only_sun)
    al = align_campaign(
        campaign,
        settings=settings,
        scenes=scenes or None,
        report=report and not only_sun,
        label_kinds=("sun", "sun_scene") if only_sun else None,
        write=not only_sun,
        log=lambda s: err.print(f"[dim]{escape(s)}[/]"),
        wait=wait,
    )
    if as_json:
        echo_json(alignment_summary(al), indent=1)
        return
    out = Console()
    t = Table(title=f"{'label sun' if only_sun else 'align'} {escape(str(campaign))}")
    for col in ("scene", "capture", "sun (az, el) deg", "yaw deg", "cues agreeing", "flags"):
        t.add_column(col)
    for sa in al.scenes:
        suns = {c.probe: c for c in sa.sun.captures}
        for p in sa.probes:
            cs = suns.get(p.id)
            sun = "-" if cs is None or not cs.found else f"{cs.azimuth_deg:+.2f}, {cs.elevation_deg:.2f}"
            yaw = (
                "-"
                if p.yaw_deg is None
                else f"{p.yaw_deg:+.2f}" + ("" if p.yaw_source == "auto" else f" ({p.yaw_source})")
            )
            flags = flag_codes(p.flags + (cs.flags if cs else []))
            t.add_row(
                sa.id,
                p.id + (" (camera)" if p.role == "camera" else ""),
                sun,
                yaw,
                ", ".join(sorted(k for k, c in p.cues.items() if c.ok)),
                escape(", ".join(flags)),
            )
        s = sa.sun
        scene_sun = (
            "no sun"
            if not s.found or s.azimuth_deg is None
            else f"{s.azimuth_deg:+.2f}, {s.elevation_deg:.2f} (photo frame)"
        )
        t.add_row(sa.id, "[b]scene[/]", scene_sun, "", "", escape(", ".join(flag_codes(sa.flags + s.flags))))
    out.print(t)
    if not only_sun:
        out.print(
            f"wrote {escape(str(campaign / 'align' / 'alignment.json'))}"
            + (f" and the report {escape(str(campaign / 'align' / 'report.html'))}" if report else "")
        )


def align_cli(
    campaign: Path = typer.Argument(..., help="An ingested campaign directory (solidkit ingest)."),
    scene: list[str] = typer.Option(
        None, "--scene", "-s", help="Align only these scenes (repeatable); the others keep their previous alignment."
    ),
    products: bool = typer.Option(
        True, "--products/--no-products", help="Write the aligned probes (LDR, HDR, saturation masks)."
    ),
    report: bool = typer.Option(
        True, "--report/--no-report", help="Write align/report.md, report.html and a PNG per scene."
    ),
    wait: bool = typer.Option(
        False, "--wait", help="Wait for another step running on the campaign (ingest, ...) instead of refusing."
    ),
    as_json: bool = json_option(),
) -> None:
    """Sun labels, every capture's yaw in the photo's view frame, probe pixels and aligned probes.

    Writes CAMPAIGN/align/alignment.json, the aligned products under CAMPAIGN/align/<scene>/<probe>/,
    automatic labels (source "auto") into the campaign's label store, and a report. Idempotent:
    human labels in the store win and are recorded as such.
    """
    _run(campaign, scene, products, report, False, as_json, wait)


def label_sun(
    campaign: Path = typer.Argument(..., help="An ingested campaign directory (solidkit ingest)."),
    scene: list[str] = typer.Option(None, "--scene", "-s", help="Only these scenes (repeatable)."),
    wait: bool = typer.Option(
        False, "--wait", help="Wait for another step running on the campaign (ingest, align) instead of refusing."
    ),
    as_json: bool = json_option(),
) -> None:
    """Automatic sun labels: every saturated blob of each sun frame is a candidate; physics chooses.

    Writes `sun` (per capture, its level frame) and `sun_scene` (photo panorama frame) labels with
    source "auto" into the campaign's label store, with the rejected candidates and their reasons;
    human labels are never replaced. Uses the features between the captures for the
    cross-position test; writes no products and no alignment.json.
    """
    _run(campaign, scene, False, False, True, as_json, wait)
