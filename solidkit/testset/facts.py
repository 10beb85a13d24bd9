"""What a campaign knows about its test set, gathered once for the dataset card, datasheet and Croissant file.

Everything here is read from ``testset.json`` and, when given, the campaign folder it was built
from (its ``manifest.json`` must be the one the test set records, and its label store is read as
it is now). Nothing is guessed: a fact that neither holds is ``None`` (or absent from a mapping),
and the writers turn it into a question for the team (:data:`TODO`).
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from solidkit.errors import InputError
from solidkit.fsutil import sha256_file
from solidkit.testset.schema import Probe, Scene, TestSet

__all__ = [
    "TODO",
    "HDR_UNITS",
    "ExportInfo",
    "CampaignFacts",
    "campaign_facts",
    "label_provenance",
    "scene_time_utc",
    "hdr_files",
    "is_virtual",
]

TODO = "TODO(team)"
HDR_UNITS = (
    "relative radiance: linear, scene-referred RGB (Rec. 709 primaries), camera code-linear units per second "
    "at the bracket's reference ISO and f-number (docs/conventions.md section 5); no absolute calibration"
)


VIRTUAL_CAMERA_MAKE = "SOLIDKIT"  # the EXIF make of solidkit's virtual campaign (solidkit synth campaign)


def is_virtual(ts: TestSet) -> bool:
    """The photos' EXIF names solidkit's virtual camera: the campaign was rendered, not captured."""
    return any(s.capture.make == VIRTUAL_CAMERA_MAKE for s in ts.scenes)


@dataclass(frozen=True)
class ExportInfo:
    """What only the team can say (each ``None`` is written as a :data:`TODO` question)."""

    license: str | None = None  # an SPDX id or a licence URL
    creators: tuple[str, ...] = ()
    url: str | None = None
    version: str | None = None  # MAJOR.MINOR.PATCH of the release
    cite_as: str | None = None  # a BibTeX entry
    date_published: str | None = None  # ISO 8601 date


@dataclass
class CampaignFacts:
    """Facts of the campaign beyond ``testset.json`` (all empty without ``--campaign``)."""

    campaign_given: bool = False
    fieldnotes_scenes: list[str] = field(default_factory=list)  # scenes that had a field notes file
    photo_pose_source: dict[str, dict[str, str]] = field(default_factory=dict)  # scene -> {pitch: fieldnotes, ...}
    hdr_stats: dict[str, dict[str, Any]] = field(default_factory=dict)  # "scene/probe" -> the HDR merge's stats
    response: dict[str, Any] | None = None  # the manifest's response entry ({kind: auto} or a file)
    label_counts: dict[str, dict[str, int]] = field(default_factory=dict)  # kind -> {source: n} (store, now)
    annotators: dict[str, int] = field(default_factory=dict)  # annotator -> items labelled (store history, now)
    agreement: dict[str, Any] = field(default_factory=dict)  # labeling.review.agreement, per task


def campaign_facts(campaign: str | os.PathLike | None, ts: TestSet) -> CampaignFacts:
    """Read ``campaign`` (``None``: nothing beyond the test set); refuse a campaign the set was not built from."""
    if campaign is None:
        return CampaignFacts()
    campaign = Path(campaign)
    from solidkit.capture.manifest import MANIFEST_NAME, load_manifest

    path = campaign / MANIFEST_NAME
    if not path.is_file():
        raise InputError(f"{campaign}: not a campaign (no {MANIFEST_NAME})")
    if sha256_file(path) != ts.inputs.manifest_sha256:
        raise InputError(
            f"{path}: not the manifest this test set was built from (sha256 differs from inputs.manifest_sha256)"
        )
    m = load_manifest(campaign)
    facts = CampaignFacts(campaign_given=True, response=dict(m.response))
    facts.fieldnotes_scenes = sorted({s.id for s in m.scenes if s.fieldnotes})
    facts.photo_pose_source = {s.id: dict(s.photo_pose_source) for s in m.scenes if s.photo_pose_source}
    for p in m.products:
        if p.kind == "hdr" and not p.error and f"{p.scene}/{p.probe}" not in facts.hdr_stats:
            facts.hdr_stats[f"{p.scene}/{p.probe}"] = dict(p.stats)
    _labels(campaign, facts)
    return facts


def _labels(campaign: Path, facts: CampaignFacts) -> None:
    from solidkit.labeling.store import LabelStore, store_path

    if not store_path(campaign).is_file():
        return
    from solidkit.align.schema import ALIGNMENT_FILE, load_alignment
    from solidkit.labeling.review import agreement
    from solidkit.labeling.tasks import TASKS, CampaignIndex

    store = LabelStore(campaign, readonly=True)
    counts: dict[str, Counter[str]] = {}
    for lab in store.list():
        counts.setdefault(lab.kind, Counter())[lab.source] += 1
    facts.label_counts = {k: dict(sorted(v.items())) for k, v in sorted(counts.items())}
    alignment = load_alignment(campaign).model_dump(mode="json") if (campaign / ALIGNMENT_FILE).is_file() else None
    facts.agreement = agreement(CampaignIndex(campaign, alignment), store, TASKS)
    people: Counter[str] = Counter()
    for task in facts.agreement.values():
        for name, st in task["annotators"].items():
            people[name] += int(st.get("labelled", 0))
    facts.annotators = dict(sorted(people.items()))


def label_provenance(ts: TestSet) -> dict[str, Counter[str]]:
    """Who set each label of the test set: ``{"sun" | "probe pixel" | "rotation": Counter(source)}``."""
    out: dict[str, Counter[str]] = {"sun": Counter(), "probe pixel": Counter(), "rotation": Counter()}
    for s in ts.scenes:
        out["sun"][s.sun.source] += 1
        for p in s.probes:
            out["probe pixel"][p.pixel_source] += 1
            out["rotation"][p.alignment.source] += 1
        if s.camera is not None:
            out["rotation"][s.camera.alignment.source] += 1
    return out


def scene_time_utc(scene: Scene) -> datetime | None:
    """The photo's capture time in UTC (EXIF time and offset), or ``None`` when either is missing."""
    t, off = scene.capture.time_local, scene.capture.utc_offset
    if not t or not off:
        return None
    try:
        local = datetime.fromisoformat(t)
        sign = -1 if off.startswith("-") else 1
        hh, mm = off.lstrip("+-").split(":")
        tz = timezone(sign * timedelta(hours=int(hh), minutes=int(mm)))
    except ValueError:
        return None
    return local.replace(tzinfo=tz).astimezone(timezone.utc)


def hdr_files(scene: Scene) -> list[tuple[str, Probe | Any, str]]:
    """Every HDR file of a scene: ``(capture id, probe or camera capture, path)``."""
    caps: list[Any] = list(scene.probes) + ([scene.camera] if scene.camera is not None else [])
    out = []
    for c in caps:
        for rel in (c.images.hdr, c.images.hdr_full):
            if rel:
                out.append((c.id, c, rel))
    return out
