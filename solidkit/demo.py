"""``solidkit demo``: the main job, the whole chain on a small virtual field campaign.

From an SD card to a report, with the steps a field team runs (docs/walkthrough.md):

1. **card**: the mini campaign shipped with the package (``solidkit/assets/campaign_mini``:
   what a team brings home, rendered by ``solidkit synth campaign``) or ``card=DIR``;
2. **ingest**: originals copied read-only, manifest, unwarped panoramas and merged HDR brackets
   (:func:`solidkit.capture.campaign.ingest`);
3. **label sun**: automatic sun labels into the campaign's label store (ALIGN);
4. **align**: every probe rotated into the photo's panorama frame (ALIGN);
5. **test set**: build and validate a versioned test set (:mod:`solidkit.testset`);
6. **evaluate**: the shipped checkpoint and the baselines with the paper's metrics
   (:mod:`solidkit.finetune.evaluate`) on the test set, and on photos cropped from the real HDR
   panoramas shipped with the package (Poly Haven, CC0: the real-lighting sun error; this was
   the whole demo before the chain existed);
7. **fine-tune**: brief scene-level k-fold fine-tuning (:mod:`solidkit.finetune.finetune`);
8. **truth check**: the chain held against the campaign's hidden truth (sun labels, probe pixels,
   probe rotations), read only here, after every step above has run;
9. **report**: ``OUT/report.html`` and ``OUT/report.md`` (summary table, truth check,
   evaluation, fine-tuning), with ``summary.json``.

Every step logs its progress and time; the summary table lists them at the end. Re-running
resumes (ingest, labels and alignment are idempotent; the test set is rebuilt byte-identically).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from solidkit.align.pipeline import AlignSettings, align_campaign
from solidkit.capture.campaign import ingest
from solidkit.envmap.coords import angular_distance, direction_from_angles
from solidkit.errors import InputError
from solidkit.finetune.evaluate import (
    SHIPPED_PANORAMAS,
    default_methods,
    evaluate,
    items_from_panoramas,
    items_from_testset,
    load_model,
    save_json,
    shipped_ablations,
)
from solidkit.finetune.relight import relight_evaluation
from solidkit.finetune.report import evaluation_sections, finetune_sections, fmt, markdown_table, write_report
from solidkit.fsutil import atomic_write_text
from solidkit.synth.campaign import load_truth
from solidkit.testset.build import build_testset, load_testset
from solidkit.testset.show import show_testset
from solidkit.testset.validate import validate_testset
from solidkit.threads import ensure_threads

__all__ = ["MINI_CAMPAIGN", "DemoConfig", "run_demo", "truth_check"]

MINI_CAMPAIGN = Path(__file__).parent / "assets" / "campaign_mini"
"""The shipped mini campaign: ``card/`` (what the field team brings home) and ``truth/``."""


@dataclass
class DemoConfig:
    """What the demo runs on and how long it fine-tunes (the defaults fit 10 minutes on 2 CPU cores)."""

    card: Path | None = None
    truth: Path | None = None
    model: Path | None = None
    folds: int = 3
    epochs: int = 3
    grids: int | None = None  # qualitative grids per dataset (None: every scene of the test set)
    crop_yaws: int = 8
    jobs: int = 1
    seed: int = 0
    relight: bool = False  # also relight virtual objects at every probe (solidkit.finetune.relight)


@dataclass
class StepRecord:
    name: str
    status: str = "pending"
    seconds: float = 0.0
    note: str = ""
    data: dict[str, Any] = field(default_factory=dict)


def _locate_card(cfg: DemoConfig) -> tuple[Path, Path | None]:
    if cfg.card is not None:
        card = Path(cfg.card)
        if not card.is_dir():
            raise InputError(f"{card}: card folder not found")
        truth = Path(cfg.truth) if cfg.truth is not None else None
        if truth is None and (card.parent / "truth" / "truth.json").is_file():
            truth = card.parent / "truth"
        return card, truth
    card = MINI_CAMPAIGN / "card"
    if not card.is_dir():
        raise InputError(
            f"{MINI_CAMPAIGN}: the shipped mini campaign is missing (reinstall solidkit, or pass --card DIR)"
        )
    return card, MINI_CAMPAIGN / "truth"


# ----------------------------------------------------------------------------------------- steps


def _ingest(card: Path, campaign: Path, cfg: DemoConfig, log: Callable[[str], Any]) -> dict[str, Any]:
    rep = ingest(card, campaign, jobs=cfg.jobs)
    manifest = json.loads((campaign / "manifest.json").read_text())
    scenes = manifest.get("scenes", [])
    n_probes = sum(len(s.get("probes", [])) for s in scenes)
    problems = getattr(rep, "problems", None) or getattr(rep, "errors", None) or []
    return {
        "scenes": len(scenes),
        "positions": n_probes,
        "problems": len(problems),
        "note": f"{len(scenes)} scenes, {n_probes} Theta positions, {len(problems)} bad files",
    }


def _label_sun(campaign: Path, cfg: DemoConfig, log: Callable[[str], Any]) -> dict[str, Any]:
    """``solidkit label sun``: sun labels only (no products, no alignment.json), as the CLI runs it."""
    import inspect

    if "label_kinds" not in inspect.signature(align_campaign).parameters:  # an align without the sun-only pass
        return {"note": "done by the alignment pass (next step)"}
    al = align_campaign(
        campaign,
        settings=AlignSettings(products=False),
        report=False,
        label_kinds=("sun", "sun_scene"),
        write=False,
        log=lambda s: log(f"    {s}"),
    )
    caps = [c for sc in al.scenes for c in sc.sun.captures]
    found = sum(1 for c in caps if c.found)
    flagged = sum(1 for c in caps if c.flags) + sum(1 for sc in al.scenes if sc.sun.flags)
    scenes = sum(1 for sc in al.scenes if sc.sun.found)
    return {
        "captures": len(caps),
        "found": found,
        "flagged": flagged,
        "note": (
            f"sun in {found}/{len(caps)} sun frames, {scenes}/{len(al.scenes)} scenes; {flagged} flagged for review"
        ),
    }


def _align(campaign: Path, cfg: DemoConfig, log: Callable[[str], Any]) -> dict[str, Any]:
    import importlib.util

    report = importlib.util.find_spec("solidkit.align.report") is not None  # the alignment report, once ALIGN ships it
    al = align_campaign(campaign, report=report, log=lambda s: log(f"    {s}"))
    probes = [p for sc in al.scenes for p in sc.probes]
    flagged = sum(1 for p in probes if p.flags) + sum(1 for sc in al.scenes if sc.sun.flags)
    suns = sum(1 for sc in al.scenes if sc.sun.found)
    return {
        "scenes": len(al.scenes),
        "captures": len(probes),
        "flagged": flagged,
        "suns": suns,
        "note": f"{len(al.scenes)} scenes, {len(probes)} captures aligned, sun found in {suns}, "
        f"{flagged} items flagged for review",
    }


def _as_dict(res: Any, what: str) -> dict[str, Any]:
    if isinstance(res, dict):
        return {**res, "note": res.get("note", what)}
    data = getattr(res, "__dict__", {})
    return {k: v for k, v in data.items() if isinstance(v, (int, float, str, bool))} | {
        "note": str(getattr(res, "summary", what))
    }


def _testset(campaign: Path, out: Path, log: Callable[[str], Any]) -> dict[str, Any]:
    build_testset(campaign, out)
    problems = validate_testset(out, allow_flagged=True)
    show_testset(out, out.parent / "contact_sheets")  # what an annotator checks before using it
    ts = json.loads((out / "testset.json").read_text())
    n_probes = sum(len(s["probes"]) for s in ts["scenes"])
    for p in problems:
        log(f"    validate: {p}")
    return {
        "scenes": len(ts["scenes"]),
        "probes": n_probes,
        "problems": len(problems),
        "version": ts.get("dataset_version"),
        "note": f"{len(ts['scenes'])} scenes, {n_probes} probes, version {ts.get('dataset_version')}, "
        f"{len(problems)} validation problems",
    }


# ----------------------------------------------------------------------------------- truth check


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(float(angular_distance(np.asarray(a, float), np.asarray(b, float))))


def truth_check(testset: Path, truth_dir: Path) -> dict[str, Any]:
    """The test set against the campaign truth: sun label, probe pixels and probe rotations.

    Per scene: the angle between the test set's sun and the true sun (photo panorama frame); per
    probe: the full-resolution pixel error (px) and the rotation error (degrees, the angle of
    ``R_est^T R_true``). The truth is read here only, after the chain has run.
    """
    truth = load_truth(Path(truth_dir) / "truth.json")
    ts = load_testset(testset)
    by_id = {s.id: s for s in truth.scenes}
    rows, sun_err, pix_err, rot_err = [], [], [], []
    for sc in ts.scenes:
        st = by_id.get(sc.id)
        if st is None:
            continue
        visible = any(c.sun_visible for c in st.captures)  # a sun hidden from every position cannot be labelled
        row: dict[str, Any] = {
            "scene": sc.id,
            "truth_sun": st.sun_found and st.sun_azimuth_deg is not None,
            "sun_visible": visible,
            "label_sun": sc.sun.found,
        }
        if row["truth_sun"] and sc.sun.found:
            assert sc.sun.azimuth_deg is not None and sc.sun.elevation_deg is not None  # a found sun has both
            assert st.sun_azimuth_deg is not None and st.sun_elevation_deg is not None  # truth_sun
            e = _angle_deg(
                direction_from_angles(math.radians(sc.sun.azimuth_deg), math.radians(sc.sun.elevation_deg)),
                direction_from_angles(math.radians(st.sun_azimuth_deg), math.radians(st.sun_elevation_deg)),
            )
            row["sun_error_deg"] = e
            sun_err.append(e)
        caps = {c.id: c for c in st.captures}
        probes = []
        for p in sc.probes:
            c = caps.get(p.id)
            if c is None or c.probe is None:
                continue
            pe = float(np.hypot(*(np.asarray(p.pixel_full) - np.asarray(c.probe.pixel))))
            re = math.degrees(
                float(
                    np.linalg.norm(
                        Rotation.from_matrix(np.asarray(p.rotation).T @ np.asarray(c.R_pano_from_body)).as_rotvec()
                    )
                )
            )
            probes.append({"probe": p.id, "pixel_error_px": pe, "rotation_error_deg": re, "flagged": bool(p.flags)})
            pix_err.append(pe)
            rot_err.append(re)
        row["probes"] = probes
        rows.append(row)

    def stat(v: list[float]) -> dict[str, Any]:
        return {
            "n": len(v),
            "median": float(np.median(v)) if v else None,
            "p95": float(np.percentile(v, 95)) if v else None,
            "max": float(max(v)) if v else None,
        }

    missed = sum(1 for r in rows if r["truth_sun"] and r["sun_visible"] and not r["label_sun"])
    hidden = sum(1 for r in rows if r["truth_sun"] and not r["sun_visible"])
    false = sum(1 for r in rows if not r["truth_sun"] and r["label_sun"])
    return {
        "scenes": rows,
        "sun_error_deg": stat(sun_err),
        "pixel_error_px": stat(pix_err),
        "rotation_error_deg": stat(rot_err),
        "sun_missed": missed,
        "sun_false": false,
        "sun_hidden": hidden,
        "probes_over_5deg": sum(1 for e in rot_err if e > 5.0),
        "probes_over_5deg_unflagged": sum(
            1 for r in rows for p in r["probes"] if p["rotation_error_deg"] > 5.0 and not p["flagged"]
        ),
    }


def _truth_section(tc: dict[str, Any]) -> str:
    rows = [
        [name, str(s["n"]), fmt(s["median"]), fmt(s["p95"]), fmt(s["max"])]
        for name, s in (
            ("sun label error (°)", tc["sun_error_deg"]),
            ("probe pixel error (full-res px)", tc["pixel_error_px"]),
            ("probe rotation error (°)", tc["rotation_error_deg"]),
        )
    ]
    text = (
        "The campaign's hidden truth, read only now: how far the automatic chain (ingest, sun labels, alignment, "
        "test set) is from it.\n\n"
        + markdown_table(["quantity", "n", "median", "95th percentile", "max"], rows)
        + f"\nSuns missed (visible from a position, label says none): {tc['sun_missed']}; false suns (label where the "
        f"truth has none): {tc['sun_false']}; suns hidden from every position (correctly 'no sun'): "
        f"{tc['sun_hidden']}. Probes rotated more than 5° off: {tc['probes_over_5deg']}, of which not flagged for "
        f"review: {tc['probes_over_5deg_unflagged']}.\n"
    )
    per = [
        [
            r["scene"],
            fmt(r.get("sun_error_deg"))
            if r["truth_sun"] and r["label_sun"]
            else (
                "no sun in truth"
                if not r["truth_sun"]
                else "hidden from every position"
                if not r["sun_visible"]
                else "MISSED"
            ),
            ", ".join(
                f"{p['probe']}: {p['rotation_error_deg']:.2f}° / {p['pixel_error_px']:.1f} px"
                + (" (flagged for review)" if p["flagged"] else "")
                for p in r["probes"]
            ),
        ]
        for r in tc["scenes"]
    ]
    return text + "\n" + markdown_table(["scene", "sun error (°)", "probes: rotation error / pixel error"], per)


# -------------------------------------------------------------------------------------------- run


def run_demo(out: str | Path, cfg: DemoConfig | None = None, log: Callable[[str], Any] = print) -> dict[str, Any]:
    """Run the whole chain into ``out``; returns the summary (also ``out/summary.json``)."""
    cfg = cfg or DemoConfig()
    ensure_threads()
    out = Path(out)
    card, truth = _locate_card(cfg)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    campaign, testset = out / "campaign", out / "testset"
    steps: list[StepRecord] = []
    sections: list[tuple[str, str]] = []
    state: dict[str, Any] = {}
    t_start = time.perf_counter()

    def step(name: str, fn: Callable[[], dict[str, Any]]) -> dict[str, Any] | None:
        rec = StepRecord(name)
        steps.append(rec)
        log(f"[{len(steps)}/{len(plan)}] {name} ...")
        t0 = time.perf_counter()
        try:
            data = fn() or {}
        except Exception as exc:  # a failed step is reported; later steps that need it are skipped
            rec.status, rec.note = "failed", f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
            rec.seconds = time.perf_counter() - t0
            log(f"    FAILED after {rec.seconds:.1f} s: {rec.note}")
            return None
        rec.status, rec.seconds = "ok", time.perf_counter() - t0
        rec.note = str(data.pop("note", ""))
        rec.data = data
        log(f"    done in {rec.seconds:.1f} s: {rec.note}")
        return data

    def evaluate_step() -> dict[str, Any]:
        items = items_from_testset(testset)
        state["items"] = items
        net = load_model(cfg.model)
        state["net"] = net
        ablations = {f"ablation: {k}": load_model(v) for k, v in shipped_ablations().items()}
        methods = default_methods(net, extra=ablations)
        res = evaluate(items, methods, log=log)
        relit = None
        if cfg.relight:
            relit = {"virtual campaign": relight_evaluation(res, items, methods, figures=cfg.grids, log=log)}
        # the old demo's real lighting, kept as a dataset: photos cropped from the shipped real HDR panoramas
        crops = items_from_panoramas(sorted(SHIPPED_PANORAMAS.glob("*.exr")), yaws=cfg.crop_yaws)
        log(f"    real HDR panorama crops: {len(crops)} photos")
        crop_methods = default_methods(net, extra=ablations)
        res_crops = evaluate(crops, crop_methods)
        (out / "eval").mkdir(exist_ok=True)
        save_json(out / "eval" / "results.json", {"virtual campaign": res, "real HDR crops": res_crops})
        sections.extend(
            evaluation_sections(
                {"virtual campaign": res, "real HDR crops": res_crops},
                out,
                {
                    "virtual campaign": (items, methods[0]),
                    "real HDR crops": (crops[:: max(1, len(crops) // 2)], crop_methods[0]),
                },
                max_grids=cfg.grids,
                relit=relit,
            )
        )
        s = res["summary"]["solidnet"]
        med = lambda k: (s.get(k) or {}).get("median")  # noqa: E731
        state["eval"] = s
        c = res_crops["summary"]["solidnet"]
        crop_sun = (c.get("angle_deg/paper") or {}).get("median")
        return {
            "note": f"{len(items)} photos: sun azimuth/elevation {fmt(med('azimuth_deg/paper'))}°/"
            f"{fmt(med('elevation_deg/paper'))}° (paper recipe), local SSIM {fmt(med('local_ssim'))}, "
            f"MAE {fmt(med('local_mae'))}; {fmt(res['timing']['seconds_per_scene_median'])} s/scene; "
            f"{len(crops)} real HDR crops: sun angle {fmt(crop_sun)}° (paper recipe)",
            "seconds_per_scene": res["timing"]["seconds_per_scene_median"],
        }

    def finetune_step() -> dict[str, Any]:
        from solidkit.finetune.finetune import FineTuneConfig, run_finetune  # lazy: pulls in kornia, torch

        items = state["items"]
        n_scenes = len({i.scene for i in items})
        if n_scenes < 2:
            raise InputError(f"k-fold fine-tuning needs 2 scenes or more, the test set has {n_scenes}")
        ftc = FineTuneConfig(folds=min(cfg.folds, n_scenes), epochs=cfg.epochs, seed=cfg.seed)
        res = run_finetune(state["net"], items, ftc, log=log)
        models = res.pop("models")
        (out / "finetune").mkdir(exist_ok=True)
        for i, m in enumerate(models):
            m.save(
                out / "finetune" / f"fold_{i + 1}.pt",
                {
                    "what": f"demo: fine-tuned on real scenes, fold {i + 1}",
                    "split": res["folds"][i]["split"],
                    "config": ftc.to_json(),
                },
            )
        save_json(out / "finetune" / "finetune.json", res)
        sections.extend(finetune_sections(res, out))
        eff = res["effect"]
        return {
            "note": f"{len(res['folds'])} folds, {fmt(float(np.mean(res['seconds_per_fold'])))} s/fold; local SSIM "
            f"{eff['local_ssim']['verdict']}, sun (paper) {eff['sun_angle/paper']['verdict']}",
            "seconds_per_fold": res["seconds_per_fold"],
            "effect": eff,
        }

    def truth_step() -> dict[str, Any]:
        if truth is None or not (truth / "truth.json").is_file():
            raise InputError("no truth for this card (a real campaign): nothing to check against")
        tc = truth_check(testset, truth)
        state["truth"] = tc
        return {
            "note": f"sun label median {fmt(tc['sun_error_deg']['median'])}°, probe rotation median "
            f"{fmt(tc['rotation_error_deg']['median'])}° (p95 {fmt(tc['rotation_error_deg']['p95'])}°), "
            f"pixel median {fmt(tc['pixel_error_px']['median'])} px",
            **tc,
        }

    plan = [
        ("ingest (copy, unwarp, merge brackets)", lambda: _ingest(card, campaign, cfg, log)),
        ("label sun", lambda: _label_sun(campaign, cfg, log)),
        ("align probes", lambda: _align(campaign, cfg, log)),
        ("build + validate test set", lambda: _testset(campaign, testset, log)),
        ("evaluate shipped checkpoint", evaluate_step),
        ("fine-tune (k-fold)", finetune_step),
        ("truth check", truth_step),
    ]
    log(f"solidkit demo: card {card} -> {out}")
    for i, (name, fn) in enumerate(plan):
        needs = {1: 0, 2: 0, 3: 2, 4: 3, 5: 4, 6: 3}.get(i)  # the step whose product this one reads
        if needs is not None and steps[needs].status != "ok":
            steps.append(StepRecord(name, "skipped", 0.0, f"needs '{plan[needs][0]}'"))
            log(f"[{len(steps)}/{len(plan)}] {name}: skipped (needs '{plan[needs][0]}')")
            continue
        step(name, fn)
    total = time.perf_counter() - t_start
    rows = [[s.name, s.status, f"{s.seconds:.1f}", s.note.replace("|", "/")] for s in steps]
    head = (
        f"Card: `{card}`. Total {total:.0f} s. Outputs: `campaign/` (ingested campaign, labels, alignment; its report "
        "[campaign/align/report.html](campaign/align/report.html)), `testset/` (the versioned test set), "
        "`contact_sheets/` (one per scene), `eval/results.json`, `finetune/` (per-fold checkpoints and results), "
        "`figures/`.\n\n" + markdown_table(["step", "status", "s", "result"], rows)
    )
    report_sections = [("Pipeline", head)]
    if "truth" in state:
        report_sections.append(("The chain against the truth", _truth_section(state["truth"])))
    report_sections += sections
    md, page = write_report(out, "solidkit demo: SD card to report", report_sections)
    summary = {
        "card": str(card),
        "out": str(out),
        "seconds": total,
        "report": str(page),
        "steps": [{"name": s.name, "status": s.status, "seconds": s.seconds, "note": s.note, **s.data} for s in steps],
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, default=float))
    log(f"report: {page}")
    return summary
