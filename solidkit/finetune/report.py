"""Evaluation reports: Markdown + HTML (rendered by markdown-it-py) with matplotlib figures.

A report is a list of sections of Markdown; :func:`write_report` writes ``report.md`` and
``report.html`` (the same content) into a folder whose ``figures/`` hold the PNGs. The building
blocks:

- :func:`metric_tables`: a table per metric, one row per method (and one column group per
  dataset when several runs are given: the sim-to-real gap in one table), median and mean each
  with its scene-bootstrap 95 % interval, ``n`` and the no-sun rate for the sun metrics;
- :func:`sun_figures`: the paper's Figure 5: the cumulative sun angular error curve (predictions
  without a sun never reach the curve's top, so the no-sun rate is visible as the gap) and violin
  plots of the azimuth and elevation errors (median as a white dot, 25-75 % as a grey bar);
- :func:`qualitative_grid`: per scene, the photo with its numbered probe pixels, the predicted and
  true global maps with the suns marked (blue: predicted, green: truth), and per probe the true
  LDR probe (saturated pixels hatched in magenta), the prediction exposed and tonemapped exactly as
  the metric compares it, and its HDR in the paper's tonemap.
"""

from __future__ import annotations

import html
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from solidkit import metrics as M
from solidkit.envmap.coords import angles_from_direction
from solidkit.envmap.io import tonemap
from solidkit.envmap.sun import luminance
from solidkit.errors import InputError
from solidkit.finetune.evaluate import (
    METRICS,
    EvalItem,
    Method,
    checked_testset,
    default_methods,
    evaluate,
    items_from_panoramas,
    items_from_synth,
    items_from_testset,
    load_model,
    save_json,
    shipped_ablations,
)
from solidkit.finetune.relight import TRUTH_KINDS, RelightSettings, RelitScene, relight_evaluation
from solidkit.fsutil import atomic_path, atomic_write_text
from solidkit.synth.panocrops import load_sources
from solidkit.threads import ensure_threads

__all__ = [
    "fmt",
    "testset_line",
    "headline_table",
    "metric_tables",
    "sun_figures",
    "qualitative_grid",
    "write_report",
    "markdown_table",
    "evaluation_report",
    "relight_table",
    "relight_figure",
    "relight_section",
]

_RELIGHT = tuple(k for k in METRICS if k.startswith("relight_"))

_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.6em 0 1.4em}th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}
th{background:#eee}td:first-child,th:first-child,td:last-child{text-align:left}img{max-width:100%}code{background:#f3f3f3}
h2{border-bottom:1px solid #ccc;margin-top:2em}"""


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path, dpi: int = 90) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    _plt().close(fig)
    return path


def fmt(x: float | None, digits: int = 3) -> str:
    """A number for a table cell (``—`` for missing/NaN)."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{digits}g}" if abs(x) < 1 else f"{x:.1f}" if abs(x) >= 10 else f"{x:.2f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub-style Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _cell(s: dict[str, Any] | None, stat: str) -> str:
    if not s or s.get(stat) is None:
        return "—"
    lo, hi = s.get(f"{stat}_ci", [None, None])
    return f"{fmt(s[stat])} [{fmt(lo)}, {fmt(hi)}]"


def metric_tables(
    runs: dict[str, dict[str, Any]], methods: Sequence[str] | None = None, keys: Sequence[str] | None = None
) -> str:
    """Markdown: one table per metric; rows = methods, columns = (dataset x {median, mean}) + n.

    ``keys``: the metrics (of :data:`METRICS`) to show; default every one but the relighting's
    (:func:`relight_section` shows those)."""
    names = list(methods or dict.fromkeys(m["name"] for r in runs.values() for m in r["methods"]))
    out = []
    shown = (
        {k: METRICS[k] for k in keys} if keys is not None else {k: v for k, v in METRICS.items() if k not in _RELIGHT}
    )

    def has(summary: dict[str, Any], key: str) -> bool:  # a method without any sun still shows its no-sun rate
        return key in summary or ("/" in key and f"no_sun_rate/{key.split('/')[1]}" in summary)

    for key, (label, unit, higher) in shown.items():
        if not any(has(r["summary"].get(m, {}), key) for r in runs.values() for m in names):
            continue
        header = ["method"]
        for ds in runs:
            pre = f"{ds}: " if len(runs) > 1 else ""
            header += [f"{pre}median [95% CI]", f"{pre}mean [95% CI]", f"{pre}n"]
        recipe = key.split("/")[1] if "/" in key else None
        if recipe:
            header += [f"{ds + ': ' if len(runs) > 1 else ''}no sun" for ds in runs]
        rows = []
        for m in names:
            cells = [m]
            if not any(has(r["summary"].get(m, {}), key) for r in runs.values()):
                continue
            for r in runs.values():
                s = r["summary"].get(m, {}).get(key)
                cells += [_cell(s, "median"), _cell(s, "mean"), str(s["n"]) if s else "—"]
            if recipe:
                for r in runs.values():
                    ns = r["summary"].get(m, {}).get(f"no_sun_rate/{recipe}")
                    cells.append(f"{ns['no_sun']}/{ns['n']} ({100 * ns['rate']:.0f}%)" if ns else "—")
            rows.append(cells)
        arrow = "higher is better" if higher else "lower is better"
        out.append(f"**{label}**{' (' + unit + ')' if unit else ''}, {arrow}\n\n" + markdown_table(header, rows))
    return "\n".join(out)


def headline_table(runs: dict[str, dict[str, Any]]) -> str:
    """Markdown: one row per (dataset, method) with the medians a reader looks at first."""
    cols = [
        ("azimuth_deg/paper", "azimuth °"),
        ("elevation_deg/paper", "elevation °"),
        ("angle_deg/core", "angle ° (default)"),
        ("global_mae", "global MAE"),
        ("local_ssim", "local SSIM"),
        ("local_mae", "local MAE"),
    ]
    rows = []
    for ds, r in runs.items():
        for m in [x["name"] for x in r["methods"]]:
            s = r["summary"].get(m, {})
            ns = s.get("no_sun_rate/core")
            cells = [fmt((s.get(k) or {}).get("median")) for k, _ in cols] + [
                f"{100 * ns['rate']:.0f}% of {ns['n']}" if ns else "—"
            ]
            if any(c != "—" for c in cells):  # a baseline with nothing to say on this dataset
                rows.append([ds, m] + cells)
    return (
        "Medians (sun errors: paper recipe unless marked; no sun: the default detector's no-sun rate):\n\n"
        + markdown_table(["dataset", "method"] + [c for _, c in cols] + ["no sun (default)"], rows)
    )


def _sun_values(result: dict[str, Any], method: str, recipe: str, err: str) -> list[float]:
    return [
        r[f"sun_{recipe}"][err]
        for r in result["records"]
        if r["method"] == method and r["truth_sun"] and f"sun_{recipe}" in r and r[f"sun_{recipe}"].get(err) is not None
    ]


def _n_truth_sun(result: dict[str, Any], method: str, recipe: str) -> int:
    return sum(1 for r in result["records"] if r["method"] == method and r["truth_sun"] and f"sun_{recipe}" in r)


#: The sun recipes as the figures name them (their legends and captions say the same).
RECIPE_NAMES = {"paper": "paper recipe", "core": "default detector"}
#: Fewest values a violin is drawn from; fewer are shown as points.
MIN_VIOLIN_POINTS = 10


def sun_figures(result: dict[str, Any], folder: Path, prefix: str = "", title: str = "") -> list[Path]:
    """The cumulative sun angular error curve and the azimuth / elevation violins (paper Fig. 5)."""
    methods = [m["name"] for m in result["methods"] if any(_n_truth_sun(result, m["name"], r) for r in M.SUN_METHODS)]
    if not methods:
        return []
    return [
        _save(cumulative_figure(result, methods, title), folder / f"{prefix}sun_cumulative.png"),
        _save(violin_figure(result, methods, title), folder / f"{prefix}sun_violins.png"),
    ]


def cumulative_figure(result: dict[str, Any], methods: list[str], title: str = "") -> Any:
    """The cumulative sun angular error curve of ``methods``, both recipes (a matplotlib figure)."""
    plt = _plt()
    colours = plt.get_cmap("tab10")
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    x = np.linspace(0, 180, 361)
    for i, m in enumerate(methods):
        for recipe, ls in (("paper", "-"), ("core", "--")):
            n = _n_truth_sun(result, m, recipe)
            if not n:
                continue
            v = np.sort(_sun_values(result, m, recipe, "angle_deg"))
            ax.plot(
                x, np.searchsorted(v, x, side="right") / n, ls, color=colours(i), label=f"{m} ({RECIPE_NAMES[recipe]})"
            )
    ax.set(
        xlabel="sun angular error [°]",
        ylabel="fraction of photos with a true sun",
        xlim=(0, 180),
        ylim=(0, 1.02),
        title=(title + ": " if title else "") + "cumulative sun angular error",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.text(
        0.01,
        0.98,
        f"solid: {RECIPE_NAMES['paper']}; dashed: {RECIPE_NAMES['core']}\n(no sun found = never reaches the curve)",
        transform=ax.transAxes,
        fontsize=7,
        va="top",
    )
    return fig


def violin_figure(result: dict[str, Any], methods: list[str], title: str = "") -> Any:
    """Azimuth and elevation sun errors of ``methods``, both recipes: a violin from :data:`MIN_VIOLIN_POINTS` values
    on, the values themselves below that; quartile bar and median on each (a matplotlib figure)."""
    plt = _plt()
    colours = plt.get_cmap("tab10")
    fig, axes = plt.subplots(1, 2, figsize=(max(6.4, 1.6 * len(methods) + 3), 4.0))
    for ax, err, label in ((axes[0], "azimuth_deg", "azimuth"), (axes[1], "elevation_deg", "elevation")):
        for i, m in enumerate(methods):
            for j, recipe in enumerate(("paper", "core")):
                v = np.asarray(_sun_values(result, m, recipe, err))
                pos = i + (j - 0.5) * 0.4
                alpha = 0.45 if recipe == "paper" else 0.2
                if v.size >= MIN_VIOLIN_POINTS and np.ptp(v) > 0:
                    parts = ax.violinplot(v, [pos], widths=0.38, showextrema=False)
                    for b in parts["bodies"]:
                        b.set_facecolor(colours(i))
                        b.set_alpha(alpha)
                elif v.size:
                    jitter = (np.arange(v.size) % 5 - 2) * 0.03  # deterministic: equal values stay apart
                    ax.scatter(pos + jitter, v, s=12, color=colours(i), alpha=min(1.0, 2 * alpha), zorder=2)
                if v.size:
                    q1, med, q3 = np.percentile(v, [25, 50, 75])
                    ax.vlines(pos, q1, q3, color="0.4", lw=4)
                    ax.plot(pos, med, "o", mfc="white", mec="k", ms=5)
        ax.set_xticks(range(len(methods)), methods, rotation=20, fontsize=8)
        ax.set(ylabel=f"sun {label} error [°]", title=f"{label} error")
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle(
        (title + ": " if title else "")
        + f"per method, left = {RECIPE_NAMES['paper']}, right (lighter) = {RECIPE_NAMES['core']};\n"
        f"white dot = median, bar = 25-75 %; the values themselves where fewer than {MIN_VIOLIN_POINTS}",
        fontsize=9,
    )
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.9))
    return fig


def _display(hdr: np.ndarray) -> np.ndarray:
    """An HDR map for display: mean luminance to 0.18, clipped, sRGB (the units of the two sides differ)."""
    y = float(luminance(np.clip(hdr, 0, None)).mean())
    return M.ldr_from_hdr(np.clip(hdr, 0, None), 0.18 / y if y > 0 else 1.0)


def _mark_sun(ax: Any, direction: np.ndarray | None, colour: str, label: str) -> None:
    if direction is None:
        return
    phi, th = angles_from_direction(np.asarray(direction, dtype=np.float64))
    ax.plot(math.degrees(float(phi)), math.degrees(float(th)), "*", ms=13, mfc="none", mec=colour, mew=1.6, label=label)


def qualitative_grid(item: EvalItem, method: Method, path: Path, title: str = "") -> Path:
    """One scene: photo + probe pixels, predicted / true global maps with suns, predicted / true probes."""
    plt = _plt()
    pred = method.predict(item)
    n = len(item.probe_ids)
    rows = 1 + n
    fig, axes = plt.subplots(rows, 3, figsize=(12, 2.3 * rows + 0.4), squeeze=False)
    ext = (-180, 180, -90, 90)
    ax = axes[0, 0]
    ax.imshow(np.clip(item.image, 0, 1))
    for k, (x, y) in enumerate(item.pixels):
        ax.plot(x, y, "o", ms=9, mfc="none", mec="yellow", mew=1.5)
        ax.text(x + 6, y - 6, str(k + 1), color="yellow", fontsize=9, weight="bold")
    ax.set(title=f"photo {item.id}", xticks=[], yticks=[])
    sun_p = M.find_sun(pred.sky, "core") if pred.sky is not None else None
    sun_paper = M.find_sun(pred.sky, "paper") if pred.sky is not None else None
    for ax, sky, name in (
        (axes[0, 1], pred.sky, f"predicted global ({method.name}), auto-exposed"),
        (
            axes[0, 2],
            item.global_hdr,
            "true global ("
            + ("the panorama" if item.source == "real-hdr-crops" else "camera position HDR")
            + "), auto-exposed",
        ),
    ):
        if sky is None:
            ax.text(0.5, 0.5, "no HDR global map", ha="center", va="center", transform=ax.transAxes)
            ax.set_axis_off()
            continue
        ax.imshow(_display(sky), extent=ext)
        _mark_sun(ax, item.sun, "lime", "true sun")
        if sky is pred.sky and sun_p is not None:
            assert sun_paper is not None  # found on the same predicted sky
            _mark_sun(ax, sun_p.direction if sun_p.found else None, "deepskyblue", "predicted (default)")
            _mark_sun(ax, sun_paper.direction if sun_paper.found else None, "magenta", "predicted (paper recipe)")
        ax.set(title=name, xticks=[-180, -90, 0, 90, 180], yticks=[-90, 0, 90])
        ax.title.set_fontsize(9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6, loc="lower left")
    for k in range(n):
        truth = item.probes_ldr[k]
        sat = M.saturation_mask(truth, item.probes_saturated[k])
        shown = truth.copy()
        shown[sat] = 0.5 * shown[sat] + 0.5 * np.array([1.0, 0.0, 1.0])
        axes[k + 1, 0].imshow(shown, extent=ext)
        axes[k + 1, 0].set_title(
            f"probe {k + 1} ({item.probe_ids[k]}): true LDR, {100 * sat.mean():.1f}% saturated", fontsize=8
        )
        if pred.local is not None:
            local = pred.local[k]
            r = M.local_ldr_metrics(local, truth, item.probes_saturated[k])
            axes[k + 1, 1].imshow(M.ldr_from_hdr(local, r["scale"]), extent=ext)
            axes[k + 1, 1].set_title(
                f"predicted, exposed x{r['scale']:.3g}: SSIM {r['ssim']:.3f}, MAE {r['mae']:.3f}", fontsize=8
            )
            axes[k + 1, 2].imshow(tonemap(local), extent=ext)
            axes[k + 1, 2].set_title("predicted HDR (paper tonemap)", fontsize=8)
        for a in axes[k + 1]:
            a.set(xticks=[], yticks=[])
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path, dpi=72)


def relight_table(result: dict[str, Any]) -> str:
    """Markdown: one row per method with relit objects; the shading-direction error and, per object, the
    si-RMSE and SSIM of its renders: median [scene-bootstrap 95 % interval]; ``n`` probes."""
    objects = result.get("relight", {}).get("objects", [])
    header = ["method", "lit by", "shading direction ° (median [95% CI])"]
    for obj in objects:
        header += [f"{obj.replace('_', ' ')}: si-RMSE", f"{obj.replace('_', ' ')}: SSIM"]
    header.append("n")
    rows = []
    for m in [x["name"] for x in result["methods"]]:
        s = result["summary"].get(m, {})
        if "relight_angle_deg" not in s and f"relight_si_rmse/{objects[0] if objects else ''}" not in s:
            continue
        lit = sorted({e["lit_by"] for r in result["records"] if r["method"] == m for e in r.get("relight", [])})
        cells = [m, ", ".join(lit), _cell(s.get("relight_angle_deg"), "median")]
        for obj in objects:
            cells += [_cell(s.get(f"relight_si_rmse/{obj}"), "median"), _cell(s.get(f"relight_ssim/{obj}"), "median")]
        n = (s.get(f"relight_si_rmse/{objects[0]}") or {}).get("n") if objects else None
        cells.append(str(n) if n is not None else "—")
        rows.append(cells)
    floor = result.get("relight", {}).get("noise_floor")
    if floor:
        cells = ["*noise floor*", "the truth, another seed", "0"]
        for obj in objects:
            cells += [_cell(floor.get(f"si_rmse/{obj}"), "median"), _cell(floor.get(f"ssim/{obj}"), "median")]
        cells.append(str((floor.get(f"si_rmse/{objects[0]}") or {}).get("n", "—")))
        rows.append(cells)
    return markdown_table(header, rows)


def _render_strip(scene: RelitScene, k: int, columns: Sequence[str]) -> np.ndarray:
    """The object renders of probe ``k`` side by side (per object: the columns), each exposed like the
    truth's (its mean luminance over the object and plane to 0.18) after the least-squares scale."""
    tiles = []
    for j in range(len(scene.objects)):
        t = scene.renders["truth"][k][j]
        mask = t.hit_mask
        y = float(luminance(t.with_object)[mask].mean()) if mask.any() else 0.0
        e = 0.18 / y if y > 0 else 1.0
        for c in columns:
            r = scene.renders[c][k][j]
            a = 1.0 if c == "truth" else M.si_scale(r.with_object, t.with_object, mask)
            tiles.append(M.ldr_from_hdr(r.with_object, a * e))
            tiles.append(np.ones((t.with_object.shape[0], 2, 3), np.float32))
        tiles.append(np.ones((t.with_object.shape[0], 10, 3), np.float32))
    return np.concatenate(tiles[:-2], axis=1)


def relight_figure(scene: RelitScene, path: Path, title: str = "") -> Path:
    """One photo relit: rows = objects; columns = the photo (probe pixels marked), relit with the model's
    local probes, with the truth, with the model's global map as the probe; below, per probe, the object
    renders themselves, magnified (per object: prediction, truth, global map)."""
    plt = _plt()
    item = scene.item
    columns = [c for c in ("prediction", "truth", "global") if c in scene.panels]
    names = list(scene.objects)
    rows = len(names)
    strips = [k for k in range(len(item.probe_ids)) if all(c in scene.renders for c in columns)]
    h, w = item.image.shape[:2]
    panel_h = 3.2 * h / w + 0.55
    strip_h = 3.2 * (1 + len(columns)) * 64 / (len(names) * (64 * len(columns) + 2 * len(columns)) + 10) + 0.35
    fig = plt.figure(figsize=(3.2 * (1 + len(columns)), panel_h * rows + strip_h * len(strips) + 0.5))
    gs = fig.add_gridspec(
        rows + len(strips), 1 + len(columns), height_ratios=[panel_h] * rows + [strip_h] * len(strips)
    )
    for j in range(rows):
        ax = fig.add_subplot(gs[j, 0])
        ax.imshow(np.clip(item.image, 0, 1))
        for k, (x, y) in enumerate(item.pixels):
            ax.plot(x, y, "o", ms=7, mfc="none", mec="yellow", mew=1.2)
            ax.text(x + 5, y - 5, str(k + 1), color="yellow", fontsize=8, weight="bold")
        ax.set_title(f"photo; {names[j].replace('_', ' ')}", fontsize=8)
        ax.set(xticks=[], yticks=[])
        for c, column in enumerate(columns, start=1):
            ax = fig.add_subplot(gs[j, c])
            ax.imshow(scene.panels[column][j])
            if column == "truth":
                sub = "si-RMSE 0, angle 0°"
            else:
                errs = scene.si_rmse.get(column, [])
                sub = "si-RMSE, angle per probe: " + "; ".join(
                    f"{k + 1}: {fmt(e.get(names[j]))}, {fmt(a)}°"
                    for k, (e, a) in enumerate(zip(errs, scene.angles.get(column, [])))
                )
            ax.set_title(f"{scene.names.get(column, column)}\n{sub}", fontsize=7)
            ax.set(xticks=[], yticks=[])
    labels = {"prediction": "prediction", "truth": "truth", "global": "global map"}
    for i, k in enumerate(strips):
        ax = fig.add_subplot(gs[rows + i, :])
        ax.imshow(_render_strip(scene, k, columns), interpolation="nearest")
        ax.set_title(
            f"probe {k + 1}: the renders, per object {' | '.join(labels[c] for c in columns)} "
            "(each exposed like the truth after the least-squares scale)",
            fontsize=8,
        )
        ax.set_axis_off()
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path, dpi=90)


_RELIGHT_NOTES = """\
At every probe, a diffuse sphere, a glossy sphere and a procedural bunny (`solidkit.synth.relight`) stand on a
grey shadow-catching plane and are path-traced with Mitsuba 3 under each method's probe (its local probe, or
its global map where it predicts none: column *lit by*) and under the truth, seen from the direction the
photo's camera sees the probe's pixel from. The figures composite them into the photo at the probe's pixel by
differential rendering (the object's pixels from the render, elsewhere the photo plus the render with the
object minus the render of the plane alone: its shadow), each exposed so that its virtual ground matches the
photo's ground there. The numbers (`solidkit.metrics.relight`) compare the method's render with the truth's
over the pixels that see the object or the plane: **si-RMSE** `||aP - T|| / ||T||` with the least-squares
scale `a` (0 = perfect, 1 = no better than black), **SSIM** of the two renders exposed alike; **shading
direction**: the angle between the probes' luminance-weighted mean directions over the hemisphere above the
plane (their first-order spherical harmonics: the side a diffuse object is lit from). Medians with
scene-bootstrap 95 % intervals, one value per probe. The *noise floor* row scores the truth's renders
against the truth re-rendered with another seed: the Monte Carlo noise alone (every method is rendered with
the truth's seed, so part of its noise is shared with the truth's: the floor bounds the noise's share from
above).
"""


def relight_section(
    results: dict[str, dict[str, Any]], relit: Mapping[str, Sequence[RelitScene]], folder: Path, prefix: str = ""
) -> str:
    """Markdown of the relighting: settings, render time, one table per dataset, the figures."""
    parts = [_RELIGHT_NOTES]
    figs = folder / "figures"
    for ds, res in results.items():
        info = res.get("relight")
        if not info:
            continue
        truth = info["truth"]
        kinds = ", ".join(f"{n} with the {TRUTH_KINDS[k]}" for k, n in truth.items() if n)
        objects = ", ".join(o.replace("_", " ") for o in info["objects"])
        sat = info.get("truth_with_saturated_pixels")
        if sat:
            kinds += (
                f"; {sat} of the LDR truths have clipped pixels (where the sun is among them, the truth "
                "lights with too little sun and casts soft shadows)"
            )
        parts.append(
            f"**{ds}**: {sum(truth.values())} probes ({kinds}); {objects}; "
            f"{info['size'][0]}x{info['size'][1]} pixels, {info['spp']} samples per pixel, "
            f"Mitsuba `{info['renderer']}`. "
            f"Render time per object: median {fmt(info['seconds_per_object_median'])} s (max "
            f"{fmt(info['seconds_per_object_max'])} s, the first renders compile their kernels) over "
            f"{info['renders']} renders; {fmt(info['seconds_total'])} s in all.\n\n" + relight_table(res)
        )
        for sc in relit.get(ds, []):
            p = relight_figure(
                sc, figs / f"{prefix}{_slug(ds)}_{_slug(sc.item.scene)}_relit.png", f"{ds}: {sc.item.scene}"
            )
            parts.append(f"![{sc.item.scene} relit]({p.relative_to(folder).as_posix()})")
    return "\n\n".join(parts)


def write_report(folder: str | os.PathLike, title: str, sections: Sequence[tuple[str, str]]) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.html`` (same content) from ``(heading, markdown)`` sections."""
    from markdown_it import MarkdownIt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    md = f"# {title}\n\n" + "\n".join(f"## {h}\n\n{body}\n" for h, body in sections)
    body = MarkdownIt("commonmark").enable("table").render(md)
    page = (
        f"<!doctype html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{_CSS}</style></head><body>\n{body}</body></html>\n"
    )
    atomic_write_text(folder / "report.md", md)
    atomic_write_text(folder / "report.html", page)
    return folder / "report.md", folder / "report.html"


_METRIC_NOTES = """\
How the numbers are made (`solidkit.metrics`): the sun of a predicted global map is found
with the paper's recipe (brightest 2 %, largest component, centroid; always answers) and with the
package's default detector (which may say "no sun": its rate is reported, never hidden); errors
are in degrees against the labelled sun, over the photos whose truth has a sun. Global MAE: over
the upper hemisphere (the sky map), the HDR maps each divided by their solid-angle mean there,
then the mean absolute difference (saturated truth pixels excluded). Local SSIM /
MAE on LDR probes: the HDR prediction is exposed by the median log-luminance ratio to the probe
over its unsaturated pixels, clipped and sRGB-encoded like the camera, and compared on the
unsaturated pixels only (SSIM: kornia, 11x11 Gaussian window). Synthetic probes are made LDR by
the same simulated camera (mean luminance to 0.18, clip, 8-bit sRGB); the HDR columns use the
paper's tonemap. Brackets: 95 % percentile-bootstrap intervals resampling whole scenes.
Paper reference (real set, 29 scenes / 67 probes): SOLID-Net 28.9° / 6.8° azimuth / elevation,
local SSIM / MAE 0.235 / 0.203; synthetic: 12.6° / 8.5°.
"""


def evaluation_sections(
    results: dict[str, dict[str, Any]],
    folder: Path,
    qualitative: dict[str, tuple[Sequence[EvalItem], Method]] | None = None,
    max_grids: int | None = None,
    prefix: str = "",
    relit: Mapping[str, Sequence[RelitScene]] | None = None,
) -> list[tuple[str, str]]:
    """The report sections of one or more evaluation results (one per dataset name); with ``relit``
    (:func:`solidkit.finetune.relight.relight_evaluation`'s scenes per dataset) also the relighting."""
    figs = folder / "figures"
    sections = [("Headline", headline_table(results)), ("Metrics", _METRIC_NOTES + "\n" + metric_tables(results))]
    body = []
    for ds, res in results.items():
        for p in sun_figures(res, figs, prefix=f"{prefix}{_slug(ds)}_", title=ds):
            body.append(f"![{ds}: {p.stem}]({p.relative_to(folder).as_posix()})")
    if body:
        sections.append(("Sun position (paper Fig. 5)", "\n\n".join(body)))
    if qualitative:
        body = []
        for ds, (items, method) in qualitative.items():
            # a real test set gets a grid for every scene unless limited; other datasets 6
            cap = max_grids if max_grids is not None else (len(items) if items and items[0].source == "real" else 6)
            shown = list(items)[:cap]
            body.append(f"**{ds}**: {len(shown)} of {len(items)} scenes, {method.name}.\n")
            for it in shown:
                p = qualitative_grid(
                    it, method, figs / f"{prefix}{_slug(ds)}_{_slug(it.scene)}.png", f"{ds}: {it.scene}"
                )
                body.append(f"![{it.scene}]({p.relative_to(folder).as_posix()})")
        sections.append(("Qualitative results", "\n\n".join(body)))
    if relit is not None and any(r.get("relight") for r in results.values()):
        sections.append(("Relit objects", relight_section(results, relit, folder, prefix)))
    rows = [
        [
            ds,
            str(r["timing"]["scenes"]),
            str(r["timing"]["methods"]),
            fmt(r["timing"]["seconds_per_scene_median"]),
            fmt(r["timing"]["seconds_total"]),
        ]
        for ds, r in results.items()
    ]
    sections.append(("Timing", markdown_table(["dataset", "scenes", "methods", "s / scene (median)", "s total"], rows)))
    return sections


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in text).strip("-") or "x"


def evaluation_report(
    out: str | os.PathLike,
    model: str | os.PathLike | None = None,
    testset: str | os.PathLike | None = None,
    synthetic: str | os.PathLike | None = None,
    baselines: dict[str, str | os.PathLike] | None = None,
    limit: int | None = None,
    max_grids: int | None = None,
    log: Any = None,
    ablations: bool = True,
    panoramas: Sequence[str | os.PathLike] | None = None,
    sun_crops: Sequence[str | os.PathLike] | None = None,
    sun_split: str = "test",
    allow_invalid: bool = False,
    relight: RelightSettings | None = None,
) -> dict[str, Any]:
    """``solidkit eval``: evaluate ``model`` (default: the shipped checkpoint) and the baselines on a
    real test set and/or a synthetic split and/or photos cropped from real HDR ``panoramas`` (with ``ablations``,
    also every checkpoint shipped beside the default one); write ``results.json``, ``report.md``, ``report.html``
    and ``figures/`` into ``out``. ``sun_crops``: folders of HDR panoramas (real ones with a ``catalog.json``, or
    rendered sources) whose ``sun_split`` is seen by the sun protocol (:mod:`solidkit.model.suneval`: the model,
    its network alone, the constant and brightest-column baselines, with the cones' coverage).
    A test set that fails validation is refused unless ``allow_invalid`` (:func:`checked_testset`); its path
    and ``dataset_version`` go into ``results.json`` and the report. ``relight``: also relight objects at
    every probe (:mod:`solidkit.finetune.relight`), with its figures (as many as the qualitative grids).
    Returns ``{"results": {dataset: result}, "report": path}``."""
    log = log or (lambda s: None)
    if testset is None and synthetic is None and not panoramas and not sun_crops:
        raise InputError(
            "give a real test set (--testset DIR), a synthetic split (--synthetic DIR), HDR panoramas "
            "and/or sun-crop folders"
        )
    ensure_threads()
    datasets: dict[str, Any] = {}
    record = None
    if testset is not None:
        record = checked_testset(testset, allow_invalid=allow_invalid, log=log)
        datasets["real"] = items_from_testset(testset)
    if synthetic is not None:
        datasets["synthetic"] = items_from_synth(synthetic, limit=limit)
    if panoramas:
        datasets["real HDR crops"] = items_from_panoramas(panoramas)
    if limit is not None and "real" in datasets:
        datasets["real"] = datasets["real"][:limit]
    net = load_model(model)
    named = dict(baselines or {})
    if ablations:
        named = {**{f"ablation: {k}": v for k, v in shipped_ablations().items()}, **named}
    extra = {name: load_model(path) for name, path in named.items()}
    out = Path(out)
    results, qual, relit = {}, {}, {}
    for ds, items in datasets.items():
        n_probes = sum(len(i.probe_ids) for i in items)
        log(f"evaluating on {ds}: {len(items)} photos, {n_probes} probes")
        methods = default_methods(net, extra=extra)
        results[ds] = evaluate(items, methods, log=log)
        qual[ds] = (items, methods[0])
        if relight is not None and n_probes:
            log(f"relighting on {ds}: {n_probes} probes, {len(methods) + 1} lightings, {len(relight.objects)} objects")
            cap = max_grids if max_grids is not None else (len(items) if items[0].source == "real" else 6)
            relit[ds] = relight_evaluation(results[ds], items, methods, relight, figures=cap, log=log)
    sun_results = {}
    if sun_crops:
        from solidkit.model.suneval import evaluate_sun_crops, protocol_crops  # lazy: pulls in torch

        for folder in sun_crops:
            crops = protocol_crops(load_sources(folder, split=sun_split))
            log(f"sun protocol on {folder} ({sun_split}): {len(crops)} crops")
            sun_results[f"{Path(folder).name} ({sun_split})"] = {
                "crops": len(crops),
                "figures": evaluate_sun_crops(net, crops),
            }
    card = getattr(net, "card", {}) or {}
    intro = [
        f"Model: `{model or 'shipped checkpoint'}` ({net.config.name}, {net.num_parameters / 1e6:.2f} M parameters)"
        + (f": {card['what']}" if card.get("what") else "")
        + ".",
        "",
        *([testset_line(record), ""] if record is not None else []),
        markdown_table(
            ["dataset", "photos", "probes", "photos with a true sun", "with a true global HDR map"],
            [
                [
                    ds,
                    str(len(it)),
                    str(sum(len(i.probe_ids) for i in it)),
                    str(sum(i.sun is not None for i in it)),
                    str(sum(i.global_hdr is not None for i in it)),
                ]
                for ds, it in datasets.items()
            ],
        ),
        (
            "Methods: "
            + "; ".join(f"**{m['name']}**: {m['description']}" for m in next(iter(results.values()))["methods"])
            + "."
        )
        if results
        else "",
    ]
    if not results:
        intro = intro[:1] + ([testset_line(record)] if record is not None else [])
    sections = [("What was evaluated", "\n".join(intro))]
    sections += evaluation_sections(results, out, qual, max_grids=max_grids, relit=relit) if results else []
    if sun_results:
        sections.append(("The sun on crops with a known sun", sun_crop_section(sun_results, net.config)))
    out.mkdir(parents=True, exist_ok=True)
    save_json(
        out / "results.json",
        {
            "model": str(model) if model else "shipped",
            **({"testset": record} if record is not None else {}),
            "results": results,
            "sun_crops": sun_results,
        },
    )
    md, page = write_report(out, "SOLID-Net evaluation", sections)
    return {"results": results, "report": str(page), "markdown": str(md)}


def testset_line(record: dict[str, Any]) -> str:
    """One Markdown line naming the test set results were computed on (:func:`checked_testset`'s record)."""
    state = (
        "valid"
        if record["valid"]
        else f"**fails validation** ({len(record['problems'])} problem(s), used with --allow-invalid)"
    )
    flagged = f"; {record['flagged']} item(s) still flagged for review" if record.get("flagged") else ""
    return f"Test set: `{record['path']}`, dataset version `{record['dataset_version']}`, {state}{flagged}."


def _num(v: Any, nd: int = 1) -> str:
    if v is None:
        return "–"
    if isinstance(v, (list, tuple)):
        return " / ".join(_num(x, nd) for x in v)
    return f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def sun_crop_section(results: dict[str, Any], config: Any) -> str:
    """Markdown of :func:`solidkit.model.suneval.evaluate_sun_crops` results, one table per crop set."""
    head = [
        "method",
        "sun found",
        "median angular ° (found)",
        "az / el °",
        "in view ° (n; max)",
        "beside °",
        "behind °",
        "suns put in sunless crops",
        "68 / 90 % cone coverage",
        "cone median °",
    ]
    cones = (
        "calibrated (scales " + _num(list(config.sun_cone_scale), 2) + ")" if config.sun_cone_scale else "uncalibrated"
    )
    parts = [
        "Crops at pitch +5°, 60° hfov, the sun at relative azimuths 0, ±30, ±90, 150° (panoramas without a sun "
        "at the same yaws), metered exposure (`solidkit.model.suneval`). The model: visibility threshold "
        f"{config.sun_visibility_threshold:.2f}, in-image sun {'on' if config.sun_in_image else 'off'}, cones "
        f"{cones}."
    ]
    for name, r in results.items():
        rows = []
        for m, f in r["figures"].items():
            cov = " / ".join(f"{round(100 * c)} %" for c in f["cone_coverage"]) if "cone_coverage" in f else "–"
            rows.append(
                [
                    m,
                    f"{f['found']}/{f['suns']}",
                    _num(f["angular_deg"]),
                    f"{_num(f['azimuth_deg'])} / {_num(f['elevation_deg'])}",
                    f"{_num(f['in_view_deg'])} ({f['in_view_n']}; {_num(f['in_view_max_deg'])})",
                    _num(f["beside_deg"]),
                    _num(f["behind_deg"]),
                    f"{f['false_suns']}/{f['sunless']}",
                    cov,
                    _num(f.get("cone_median_deg")),
                ]
            )
        parts.append(f"**{name}**: {r['crops']} crops\n\n" + markdown_table(head, rows))
    return "\n\n".join(parts)


def loss_curves(result: dict[str, Any], path: Path) -> Path:
    """Training and validation loss per epoch, one colour per fold."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    cm = plt.get_cmap("tab10")
    for f in result["folds"]:
        h = f["history"]
        e = [r["epoch"] for r in h]
        tr = [r for r in h if r["train"] is not None]
        ax.plot(
            [r["epoch"] for r in tr],
            [r["train"] for r in tr],
            "-o",
            ms=3,
            color=cm(f["fold"]),
            label=f"fold {f['fold'] + 1} train",
        )
        if f["early_stopping"]:
            ax.plot(
                e, [r["val"] for r in h], "--s", ms=3, color=cm(f["fold"]), label=f"fold {f['fold'] + 1} validation"
            )
            ax.axvline(f["best_epoch"], color=cm(f["fold"]), alpha=0.3, lw=3)
    ax.set(
        xlabel="epoch (0 = before fine-tuning)", ylabel="real-label loss", title="fine-tuning loss (bars: kept epoch)"
    )
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return _save(fig, path)


def finetune_sections(result: dict[str, Any], folder: Path, prefix: str = "finetune_") -> list[tuple[str, str]]:
    """Report sections of :func:`solidkit.finetune.finetune.run_finetune`'s result."""
    cfg = result["config"]
    figs = folder / "figures"
    n_par = result["folds"][0]["trainable_parameters"] if result["folds"] else 0
    mix = (
        f"one synthetic batch after every {cfg['synthetic_every']} real steps"
        if cfg["synthetic_every"]
        else "none (real labels only)"
    )
    proto = (
        f"Scene-level {len(result['folds'])}-fold cross-validation (seed {cfg['seed']}): each fold tests on its scenes "
        "and trains on the others; one training scene per fold (20 % of them for larger sets) is held out for early "
        f"stopping (patience {cfg['patience']}, at most {cfg['epochs']} epochs), so test scenes never choose the "
        f"epoch. Trainable: `{cfg['trainable']}` ({n_par / 1e3:.0f} k parameters), Adam lr {cfg['lr']:g}. Loss: LDR "
        "local probes (exposure-invariant log-L1 + 1-SSIM on unsaturated pixels) + the labelled sun direction (weight "
        f"{cfg['sun_weight']:g}). Synthetic mixing: {mix}.\n\n"
    )
    rows = []
    for f in result["folds"]:
        b, a = f["before"], f["after"]
        cell = lambda s, k: fmt((s.get(k) or {}).get("median"))  # noqa: E731
        rows.append(
            [
                str(f["fold"] + 1),
                ", ".join(f["split"]["train"]),
                ", ".join(f["split"]["val"]) or "—",
                ", ".join(f["split"]["test"]),
                f"{f['best_epoch']}/{f['epochs_run']}",
                fmt(f["seconds"]),
                f"{cell(b, 'local_ssim')} → {cell(a, 'local_ssim')}",
                f"{cell(b, 'local_mae')} → {cell(a, 'local_mae')}",
                f"{cell(b, 'angle_deg/paper')} → {cell(a, 'angle_deg/paper')}",
                f"{cell(b, 'angle_deg/core')} → {cell(a, 'angle_deg/core')}",
            ]
        )
    table = markdown_table(
        [
            "fold",
            "train scenes",
            "validation",
            "test scenes",
            "kept epoch",
            "s",
            "local SSIM (median)",
            "local MAE (median)",
            "sun angle paper (°)",
            "sun angle default (°)",
        ],
        rows,
    )
    eff_rows = [
        [
            k,
            str(v["n"]),
            fmt(v.get("mean")),
            f"[{fmt((v.get('mean_ci') or [None])[0])}, {fmt((v.get('mean_ci') or [None, None])[1])}]",
            f"**{v['verdict']}**",
        ]
        for k, v in result["effect"].items()
    ]
    effect = markdown_table(
        ["paired difference (after - before)", "n", "mean", "95% CI (scene bootstrap)", "verdict"], eff_rows
    )
    curves = loss_curves(result, figs / f"{prefix}loss.png")
    sections = [
        ("Fine-tuning: protocol and folds", proto + table + f"\n![loss]({curves.relative_to(folder).as_posix()})\n"),
        (
            "Fine-tuning: does it help?",
            effect
            + "\nPooled over the folds' test scenes (every scene once):\n\n"
            + metric_tables({"pooled": result["pooled"]}),
        ),
    ]
    body = [
        f"![{p.stem}]({p.relative_to(folder).as_posix()})"
        for p in sun_figures(result["pooled"], figs, prefix=prefix, title="before / after fine-tuning")
    ]
    if body:
        sections.append(("Fine-tuning: sun position before / after", "\n\n".join(body)))
    if "synthetic" in result:
        sections.append(
            (
                "Fine-tuning: forgetting (synthetic split)",
                "Each fold's fine-tuned model on the synthetic split, against the synthetic-only model.\n\n"
                + metric_tables({"synthetic": result["synthetic"]}),
            )
        )
    return sections
