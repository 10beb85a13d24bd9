"""``solidkit testset export --format croissant``: a test set as a publishable dataset folder.

Writes ``OUT`` (absent, empty or an earlier export; outside the test set)::

    croissant.json        Croissant 1.1 metadata (:mod:`solidkit.testset.croissant`)
    README.md             the dataset card, Hugging Face YAML header (:mod:`solidkit.testset.datasheet`)
    datasheet.md          Gebru et al.'s datasheet, answered from the campaign or asked of the team
    records/scenes.csv    one row per scene
    records/probes.csv    one row per probe
    data/                 the test set, byte for byte (hard links where the file system allows)

The test set must validate (flags still open for review are allowed, and listed). With
``campaign`` (the folder it was built from: its manifest must be the one recorded in
``inputs.manifest_sha256``) the card, datasheet and metadata also state the field notes, the HDR
clipping per file, the response curve and the label store's counts and agreement. The folder is
assembled beside ``OUT`` and renamed in, so ``OUT`` is either the old or the new export.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from solidkit.errors import InputError
from solidkit.testset.build import MANIFEST_FILE, _swap, load_testset
from solidkit.testset.croissant import croissant_metadata, records
from solidkit.testset.datasheet import dataset_card, datasheet, summary
from solidkit.testset.facts import ExportInfo, campaign_facts

__all__ = ["CROISSANT_FILE", "export_croissant"]

CROISSANT_FILE = "croissant.json"


def _csv(rows: list[list[str]]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return buf.getvalue()


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def _check_out(root: Path, out: Path) -> None:
    o, r = out.resolve(), root.resolve()
    if o == r or r in o.parents or o in r.parents:
        raise InputError(f"{out}: write the export outside the test set (its files are checksummed)")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / CROISSANT_FILE).is_file():
        raise InputError(f"{out}: exists and is not an earlier export (no {CROISSANT_FILE}); refusing to write there")


def export_croissant(
    root: str | os.PathLike,
    out: str | os.PathLike,
    *,
    campaign: str | os.PathLike | None = None,
    info: ExportInfo | None = None,
) -> dict[str, Any]:
    """Write the dataset folder of the test set ``root`` at ``out`` (module docstring); returns what was written."""
    from solidkit.testset.validate import validate_testset

    root, out = Path(root), Path(out)
    info = info or ExportInfo()
    ts = load_testset(root)
    _check_out(root, out)
    problems = [p for p in validate_testset(root) if p.check != "flags"]
    if problems:
        head = "; ".join(str(p) for p in problems[:3])
        raise InputError(f"{root}: the test set fails validation ({len(problems)} problem(s): {head}); fix it first")
    facts = campaign_facts(campaign, ts)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.export-", dir=out.parent))
    try:
        for rel in [MANIFEST_FILE, *ts.files]:
            _link_or_copy(root / rel, staging / "data" / rel)
        scenes, probes = records(ts)
        texts = {"records/scenes.csv": _csv(scenes), "records/probes.csv": _csv(probes)}
        checksums = {"data/" + MANIFEST_FILE: hashlib.sha256((root / MANIFEST_FILE).read_bytes()).hexdigest()}
        checksums.update({rel: hashlib.sha256(t.encode("utf-8")).hexdigest() for rel, t in texts.items()})
        doc = croissant_metadata(ts, facts, info, checksums, summary(ts))
        texts[CROISSANT_FILE] = json.dumps(doc, indent=1, ensure_ascii=False) + "\n"
        texts["README.md"] = dataset_card(ts, facts, info)
        texts["datasheet.md"] = datasheet(ts, facts, info)
        for rel, text in texts.items():
            (staging / rel).parent.mkdir(parents=True, exist_ok=True)
            (staging / rel).write_text(text, encoding="utf-8")
        _swap(staging, out)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return {
        "output": str(out),
        "dataset_version": ts.dataset_version,
        "files": sorted(texts),
        "data_files": len(ts.files) + 1,
        "campaign": facts.campaign_given,
        "open_questions": doc["solidkit:openQuestions"],
    }
