"""Is a campaign whole? ``solidkit verify CAMPAIGN`` and the check at the start of every ingest.

Checked against the manifest (:mod:`solidkit.capture.manifest`):

- every stored original (captures and field notes, ``originals/``): present, a regular file,
  read-only, its recorded size and the content its sha256 name promises. Cheap by default: an
  original whose size and modification time are those of its card file (ingest gives the copy the
  card file's time) is trusted; any other is hashed. ``full=True`` hashes every one;
- every profile the products were made with (``profiles/``): present and unmodified (hashed);
- every product: its file present (``full``: its sha256), its recipe's inputs in the manifest
  and their originals undamaged.

Each finding is a :class:`Damage` saying whether the next ingest rebuilds it (products, a
writable original) or not (a missing or corrupted original: re-ingest it from its card).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field

from solidkit.capture.manifest import Manifest, Shot
from solidkit.fsutil import sha256_file

__all__ = ["Damage", "VerifyReport", "check_original", "verify_campaign", "REBUILT", "REINGEST"]

REBUILT = "rebuilt by the next ingest"
REINGEST = "re-ingest from the card"


class Damage(BaseModel):
    """One damaged file of a campaign and what can be done about it."""

    path: str = Field(description="relative to the campaign directory")
    what: Literal["original", "fieldnotes", "profile", "product"]
    problem: str
    rebuildable: bool = Field(description="the next ingest repairs it by itself")
    remedy: str
    source: str | None = Field(None, description="an original's card file (CARD/PATH), where it can be copied again")


class VerifyReport(BaseModel):
    """What :func:`verify_campaign` checked and found."""

    campaign: str
    full: bool
    checked: dict[str, int] = Field(default_factory=dict, description="files checked, per kind")
    hashed: int = Field(0, description="files whose content was hashed")
    damage: list[Damage] = Field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.damage


def check_original(campaign: Path, shot: Shot, *, full: bool = False) -> tuple[str | None, bool]:
    """``(problem or None, hashed)`` of one stored capture (module doc). ``problem`` is one of
    ``missing``, ``not a regular file``, ``size ...``, ``content differs ...`` or ``writable ...``
    (only the last one leaves the content intact)."""
    path = campaign / shot.original
    try:
        st = path.lstat()
    except FileNotFoundError:
        return "missing", False
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file", False
    if st.st_size != shot.size:
        return f"size {st.st_size} B, recorded {shot.size} B (truncated or overwritten)", False
    hashed = full or st.st_mtime_ns not in {r.mtime_ns for r in shot.sources}
    if hashed and sha256_file(path) != shot.sha256:
        return "content differs from its sha256 (corrupted)", True
    if st.st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
        return "writable (originals are kept read-only)", hashed
    return None, hashed


def _source(shot: Shot) -> str | None:
    return f"{shot.sources[0].card}/{shot.sources[0].path}" if shot.sources else None


def verify_campaign(campaign_dir: str | os.PathLike, manifest: Manifest, *, full: bool = False) -> VerifyReport:
    """Check ``campaign_dir`` against its ``manifest`` (module doc); nothing is written."""
    campaign = Path(campaign_dir)
    rep = VerifyReport(campaign=str(campaign_dir), full=full)
    damaged: set[str] = set()  # sha256 of originals whose content is gone or wrong
    for shot in manifest.shots:
        problem, hashed = check_original(campaign, shot, full=full)
        rep.hashed += hashed
        if problem is None:
            continue
        writable = problem.startswith("writable")
        if not writable:
            damaged.add(shot.sha256)
        src = _source(shot)
        rep.damage.append(
            Damage(
                path=shot.original,
                what="original",
                problem=problem,
                rebuildable=writable,
                remedy="made read-only again by the next ingest"
                if writable
                else f"{REINGEST}{f' ({src})' if src else ''}",
                source=src,
            )
        )
    rep.checked["originals"] = len(manifest.shots)

    notes = [r for r in manifest.fieldnotes if r.original]
    for note in notes:
        assert note.original is not None
        path = campaign / note.original
        problem = None
        if not path.is_file():
            problem = "missing"
        else:
            rep.hashed += 1
            if sha256_file(path) != note.sha256:
                problem = "content differs from its sha256 (corrupted)"
        if problem:
            src = f"{note.card}/{note.path}"
            rep.damage.append(
                Damage(
                    path=note.original,
                    what="fieldnotes",
                    problem=problem,
                    rebuildable=False,
                    remedy=f"{REINGEST} ({src})",
                    source=src,
                )
            )
    rep.checked["fieldnotes"] = len(notes)

    profiles = {}
    for option, rec in (
        ("--response", manifest.response),
        ("--profile", manifest.lens_profile),
        ("--vignetting", manifest.vignetting),
    ):
        if rec and rec.get("kind") == "file":
            profiles[rec["path"]] = (option, rec)
    for p in manifest.products:
        for key, option in (("response", "--response"), ("lens_profile", "--profile"), ("vignetting", "--vignetting")):
            rec = p.recipe.get(key)
            if isinstance(rec, dict) and rec.get("kind") == "file":
                profiles.setdefault(rec["path"], (option, rec))
    for rel, (option, rec) in sorted(profiles.items()):
        path = campaign / rel
        problem = None
        if not path.is_file():
            problem = "missing"
        else:
            rep.hashed += 1
            if sha256_file(path) != rec["sha256"]:
                problem = "content differs from its sha256 (modified)"
        if problem:
            rep.damage.append(
                Damage(
                    path=rel,
                    what="profile",
                    problem=problem,
                    rebuildable=False,
                    remedy=f"give the profile again to the next ingest ({option} FILE)",
                )
            )
    rep.checked["profiles"] = len(profiles)

    shas = {s.sha256: s for s in manifest.shots}
    built = [p for p in manifest.products if p.path]
    for p in built:
        assert p.path is not None
        lost = [sha for sha in p.inputs if sha not in shas]
        bad = [shas[sha].original for sha in p.inputs if sha in damaged]
        problem = None
        if lost:
            problem = f"recipe input {lost[0][:12]}... is not in the manifest"
        elif bad:
            problem = f"its input original {bad[0]} is damaged"
        elif not p.path.startswith("originals/"):  # a referenced original is checked above
            path = campaign / p.path
            if not path.is_file():
                problem = "missing"
            elif full:
                rep.hashed += 1
                if sha256_file(path) != p.sha256:
                    problem = "content differs from its sha256 (corrupted)"
        if problem:
            rep.damage.append(
                Damage(
                    path=p.path,
                    what="product",
                    problem=problem,
                    rebuildable=True,
                    remedy=REBUILT + (" once its originals are re-ingested" if lost or bad else ""),
                )
            )
    rep.checked["products"] = len(built)
    return rep
