"""The dataset card (``README.md``, Hugging Face YAML header) and the datasheet (``datasheet.md``) of a test set.

The datasheet follows the sections of Gebru et al., "Datasheets for Datasets" (CACM 64(12),
2021): motivation, composition, collection process, preprocessing / cleaning / labeling, uses,
distribution, maintenance. Every answer is computed from ``testset.json`` and, when given, the
campaign (:mod:`solidkit.testset.facts`); a question neither can answer is written as
``TODO(team): <question>`` so that nothing is invented and the open points can be found with grep.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

from solidkit.testset.facts import (
    HDR_UNITS,
    TODO,
    CampaignFacts,
    ExportInfo,
    hdr_files,
    is_virtual,
    label_provenance,
    scene_time_utc,
)
from solidkit.testset.schema import TestSet

__all__ = ["size_category", "summary", "dataset_card", "datasheet"]


def size_category(n: int) -> str:
    """Hugging Face ``size_categories`` value for ``n`` records."""
    for limit, name in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M")):
        if n < limit:
            return name
    return "n>1M"


def _fmt(v: float | None, digits: int = 2) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _counts(c: Counter[str] | dict[str, int]) -> str:
    """``"a (2), b (1)"``: each value with how often it occurs."""
    return ", ".join(f"{k} ({v})" for k, v in sorted(c.items())) or "none"


def _spread(values: list[Any], unit: str, digits: int = 2) -> str:
    """``"median 0.50 deg, max 0.70 deg (n = 3)"`` of the known values."""
    known = [float(v) for v in values if v is not None]
    if not known:
        return "not recorded"
    u = f" {unit}" if unit else ""
    return f"median {_fmt(_median(known), digits)}{u}, max {_fmt(max(known), digits)}{u} (n = {len(known)})"


def summary(ts: TestSet) -> str:
    """One paragraph: what the test set holds (the card's and the Croissant description)."""
    probes = sum(len(s.probes) for s in ts.scenes)
    hdr = sum(p.hdr is not None for s in ts.scenes for p in s.probes)
    sun = sum(s.sun.found for s in ts.scenes)
    cams = sum(s.camera is not None for s in ts.scenes)
    origin = (
        "rendered by solidkit's virtual campaign (the photos' EXIF names its virtual camera), not captured"
        if is_virtual(ts)
        else "real"
    )
    return (
        f"A test set ({origin}) for spatially-varying outdoor lighting estimation from a single photo (SOLID-Net's "
        f"protocol), built by solidkit from the campaign '{ts.inputs.campaign}': {len(ts.scenes)} scenes, each a "
        f"320x240 photo with {probes} local light probes in all ({hdr} with an HDR bracket) captured by a 360-degree "
        f"camera at points seen in the photo, aligned to the photo's gravity-aligned panorama frame; {sun} scenes "
        f"with a labeled sun direction, {cams} with a capture at the photo camera's position. "
        f"Content version {ts.dataset_version}."
    )


def _yaml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def dataset_card(ts: TestSet, facts: CampaignFacts, info: ExportInfo) -> str:
    """``README.md``: a Hugging Face dataset card (YAML header, then the campaign's summary)."""
    prov = label_provenance(ts)
    sources = set().union(*(set(c) for c in prov.values()))
    creators = []
    if "auto" in sources:
        creators.append("- machine-generated")
    if sources - {"auto"}:
        creators.append(
            f"- other  # {TODO}: field team / annotators ({', '.join(sorted(sources - {'auto'}))}): "
            "expert-generated or crowdsourced?"
        )
    lic = info.license or f"unknown  # {TODO}: choose the licence (SPDX id)"
    head = [
        "---",
        f"license: {lic}",
        f"pretty_name: {_yaml_str(f'solidkit test set {ts.inputs.campaign}')}",
        "annotations_creators:",
        *creators,
        "size_categories:",
        f"- {size_category(len(ts.scenes))}",
        "task_categories:",
        "- image-to-image",
        "tags:",
        "- lighting-estimation",
        "- hdr",
        "- light-probe",
        "- outdoor",
        "- croissant",
        "---",
        "",
    ]
    body = [
        f"# solidkit test set {ts.inputs.campaign}",
        "",
        summary(ts),
        "",
        "## Files",
        "",
        "- `croissant.json`: Croissant 1.1 metadata (record sets `scenes`, `probes`, `photos`; per-file HDR "
        "units and clipping as `solidkit:` properties, docs/dataset-export.md in solidkit).",
        "- `datasheet.md`: the datasheet (motivation, composition, collection, labeling, uses, distribution, "
        "maintenance).",
        "- `records/scenes.csv`, `records/probes.csv`: one row per scene / probe.",
        "- `data/`: the test set itself (`testset.json` and its files, byte for byte; format: docs/testset.md in "
        "solidkit).",
        "",
        "## Loading",
        "",
        "```python",
        "import mlcroissant as mlc",
        'ds = mlc.Dataset("croissant.json")',
        'for record in ds.records("probes"):',
        "    ...",
        "```",
        "",
        "## Licence and citation",
        "",
        f"- Licence: {info.license or TODO + ': which licence?'}",
        f"- Creators: {', '.join(info.creators) if info.creators else TODO + ': who to credit?'}",
        f"- Citation: {info.cite_as or TODO + ': how to cite (BibTeX)?'}",
        "",
    ]
    return "\n".join(head + body)


def _agreement_lines(facts: CampaignFacts) -> list[str]:
    lines = []
    for kind, a in facts.agreement.items():
        t = a["task"]
        for what in ("vs_others", "vs_reviewed"):
            s = t[what]
            if s["n"]:
                lines.append(
                    f"  - {kind} {what.replace('_', ' ')}: n = {s['n']}, median {_fmt(s['median'])} {a['unit']}, "
                    f"p95 {_fmt(s['p95'])} {a['unit']}, found/not-found mismatches {s['mismatch']}"
                )
    return lines


def datasheet(ts: TestSet, facts: CampaignFacts, info: ExportInfo) -> str:
    """``datasheet.md``: Gebru et al.'s sections, answered from the campaign or asked of the team."""
    probes = [(s, p) for s in ts.scenes for p in s.probes]
    prov = label_provenance(ts)
    times = [t for t in (scene_time_utc(s) for s in ts.scenes) if t is not None]
    cameras = Counter(" ".join(x for x in (s.capture.make, s.capture.model) if x) or "unknown" for s in ts.scenes)
    thetas = Counter(p.capture.camera_model or "unknown" for _, p in probes)
    L: list[str] = [f"# Datasheet: solidkit test set {ts.inputs.campaign}", ""]
    L += [
        "Generated by `solidkit testset export --format croissant` from the test set"
        + (" and its campaign" if facts.campaign_given else " alone (no --campaign: campaign facts left open)")
        + f". Content version `{ts.dataset_version}`. Lines starting with `{TODO}` are questions only the team "
        "can answer; everything else is read from the data.",
        "",
        "## Motivation",
        "",
        "- Purpose: evaluating spatially-varying outdoor lighting estimation from a single limited-FOV photo "
        "(local light probes at marked pixels, the sun direction), as in SOLID-Net's real test set.",
        f"- {TODO}: who created the dataset, on behalf of which group, and who funded it?",
        "",
        "## Composition",
        "",
        f"- {len(ts.scenes)} scenes (one photo each), {len(probes)} local probes "
        f"({sum(p.hdr is not None for _, p in probes)} with an HDR bracket), "
        f"{sum(s.camera is not None for s in ts.scenes)} captures at the photo camera's position, "
        f"{sum(s.sun.found for s in ts.scenes)} scenes with a labeled sun.",
        "- Per scene: the 320x240 photo (model input) and the original; K, pitch and roll; the sun label; per probe "
        "its pixel, the 256x128 LDR probe (sRGB) with its saturation mask and, with a bracket, the linear HDR probe; "
        "all panoramas in the photo's gravity-aligned panorama frame (docs/conventions.md).",
        "- Scenes: " + "; ".join(f"{s.id}: {s.notes}" if s.notes else s.id for s in ts.scenes) + ".",
        f"- {TODO}: is this a sample of a larger set of scenes, and how were the scenes chosen?",
        f"- {TODO}: do the photos show people, licence plates or private property that needs consent or blurring?",
        "- Splits: none (a test set).",
        "",
        "## Collection process",
        "",
        *(
            [
                "- The photos' EXIF names solidkit's virtual camera: these scenes were rendered (solidkit synth "
                "campaign), not captured; the times, places and cameras below are the renderer's."
            ]
            if is_virtual(ts)
            else []
        ),  # fmt: skip
        "- When (photo EXIF, converted to UTC): "
        + (
            "; ".join(f"{s.id} {t.isoformat()}" for s in ts.scenes if (t := scene_time_utc(s)) is not None) + "."
            if times
            else f"{TODO}: the photos carry no EXIF time with a UTC offset; when were they taken?"
        ),
        "- Where (photo GPS, degrees): "
        + (
            "; ".join(
                f"{s.id} {s.capture.gps.lat_deg:.5f}, {s.capture.gps.lon_deg:.5f}" for s in ts.scenes if s.capture.gps
            )
            + "."
            if any(s.capture.gps for s in ts.scenes)
            else f"{TODO}: the photos carry no GPS; where were they taken?"
        ),
        f"- {TODO}: who captured the scenes (the field notes record no operator)?",
        f"- Photo cameras: {_counts(cameras)}. Probe cameras: {_counts(thetas)}.",
        "- Intrinsics: " + _counts(Counter(s.K_source for s in ts.scenes)) + ".",
        "- Calibration profiles: "
        + (
            "; ".join(
                f"{r.role} {r.kind} {r.name or ''} {('sha256:' + r.sha256) if r.sha256 else ''}".strip()
                for r in ts.profiles
            )  # fmt: skip
            or "none recorded"
        )
        + ".",
        "- Field protocol: solidkit's docs/field-protocol.md asks for probes 10 cm above the surface, the LDR "
        "probe at 1/2500 s, a low-exposure frame for the sun and all shots within 10 minutes. Measured here: "
        "LDR probe exposures "
        + _counts(Counter(f"{p.capture.ldr_exposure.exposure_time_s:g} s" for _, p in probes if p.capture.ldr_exposure))
        + ".",
        f"- {TODO}: did the team follow docs/field-protocol.md (probe height, tripod, clocks)? Note any deviation.",
    ]
    if facts.campaign_given:
        L.append(
            f"- Field notes: {len(facts.fieldnotes_scenes)} of {len(ts.scenes)} scenes "
            f"({', '.join(facts.fieldnotes_scenes) or 'none'}); photo pose from: "
            + _pose_sources(facts.photo_pose_source)
            + "."
        )
    L += [
        "",
        "## Preprocessing, cleaning, labeling",
        "",
        "- Processing (solidkit): each Theta capture unwarped with its lens profile, brackets merged to HDR, "
        "levelled, and rotated into the photo's panorama frame by the alignment cues that worked ("
        + _counts(Counter(k for _, p in probes for k, c in p.alignment.cues.items() if c.ok))
        + " probes); photos centre-cropped and resized to 320x240 ("
        + _counts(Counter("resized" if s.photo_full_size != s.photo_size else "already 320x240" for s in ts.scenes))
        + ").",
        "- Who set each label (test set): "
        + "; ".join(f"{k}: {_counts(v)}" for k, v in prov.items())
        + " (auto = solidkit, field_notes = the field team, annotator / reviewed = the labeling app).",
        "- Label uncertainty: sun 1-sigma "
        + _spread([s.sun.uncertainty_deg for s in ts.scenes if s.sun.found], "deg")
        + "; probe rotation, residual of the alignment cues: "
        + _spread([p.alignment.residual_deg for _, p in probes], "deg")
        + f"; probe pixels: no uncertainty is recorded ({TODO}: how precisely were the pixels marked?).",
        f"- Open flags: scenes {sum(bool(s.flags) for s in ts.scenes)} of {len(ts.scenes)}, probes "
        f"{sum(bool(p.flags) for _, p in probes)} of {len(probes)} (listed in records/*.csv).",
    ]
    if facts.campaign_given:
        L.append(
            "- Label store (now): "
            + ("; ".join(f"{k}: {_counts(v)}" for k, v in facts.label_counts.items()) or "no labels")
            + "; human annotators: "
            + (_counts(facts.annotators) if facts.annotators else "none")
            + "."
        )
        agree = _agreement_lines(facts)
        L.append("- Agreement between annotators / with the reviewer:" if agree else "- Agreement: no item was "
                 "labeled by two annotators or reviewed, so there are no agreement figures.")  # fmt: skip
        L += agree
    else:
        L.append(f"- {TODO}: export with --campaign for the label store's counts and agreement figures.")
    L += ["", "### Radiometry", ""]
    L += [
        f"- HDR probes: {HDR_UNITS}.",
        "- Brackets: "
        + _counts(
            Counter(", ".join(f"{t:g}" for t in p.capture.bracket_exposures_s) + " s" for _, p in probes if p.hdr)
        )
        + "; reference ISO "
        + _counts(Counter(_fmt(p.capture.bracket_iso, 0) for _, p in probes if p.hdr))
        + ", f-number "
        + _counts(Counter(_fmt(p.capture.bracket_f_number, 1) for _, p in probes if p.hdr))
        + ".",
        "- LDR probes: sRGB 8-bit, clipped share (solid-angle weighted): "
        + _spread([p.images.saturated_fraction for _, p in probes], "", 4)
        + "; masks in saturation.png.",
    ]
    if facts.campaign_given:
        caps = sorted({(s.id, cid) for s in ts.scenes for cid, _, _ in hdr_files(s)})
        clip = [facts.hdr_stats.get(f"{sid}/{cid}", {}).get("saturated_in_all_frames_fraction") for sid, cid in caps]
        resp = facts.response or {}
        L += [
            "- HDR clipping of the probes and camera captures (share of pixels saturated in every frame of the "
            "bracket; per file in croissant.json): " + _spread(clip, "", 6) + ".",
            "- Response curve: "
            + (
                f"calibration file sha256:{resp.get('sha256')}"
                if resp.get("kind") == "file"
                else "estimated from each bracket (no calibration file)"
            )
            + ".",
        ]
    else:
        L.append(f"- {TODO}: export with --campaign for each HDR file's clipping and the response curve.")
    L += [
        f"- {TODO}: is an absolute radiance calibration available (the values are relative)?",
        "",
        "## Uses",
        "",
        "- Intended: measuring lighting estimation on real photos (sun direction error, probe SSIM / MAE, "
        "`solidkit eval`).",
        f"- {TODO}: uses the team wants to rule out, and known biases (places, seasons, times of day, weather).",
        "",
        "## Distribution",
        "",
        f"- Licence: {info.license or TODO + ': which licence, and are there third-party rights in the photos?'}",
        f"- Where: {info.url or TODO + ': where is it published, and under which DOI?'}",
        f"- Version: {info.version or TODO + ': release version'} (content hash {ts.dataset_version}).",
        "",
        "## Maintenance",
        "",
        f"- {TODO}: who maintains the dataset and how can they be reached?",
        f"- {TODO}: will it be updated (errata, new scenes), and how are older versions kept?",
        "- Changes between versions: `solidkit testset diff OLD NEW` lists them; the content hash changes with any "
        "file.",
        "",
    ]
    return "\n".join(L)


def _pose_sources(sources: dict[str, dict[str, str]]) -> str:
    groups: dict[str, list[str]] = {}
    for sid, src in sorted(sources.items()):
        groups.setdefault(", ".join(f"{k} {v}" for k, v in sorted(src.items())), []).append(sid)
    return "; ".join(f"{k} ({', '.join(v)})" for k, v in groups.items()) or "not recorded"


def _median(values: list[Any]) -> float | None:
    v = sorted(float(x) for x in values if x is not None)
    if not v:
        return None
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])
